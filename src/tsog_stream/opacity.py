"""Opacity in its two domains: alpha in [0, 1] and the logit the 3DGS model stores.

One clamp for every reader and decoder: alpha is kept in [ALPHA_EPS, 1 - ALPHA_EPS] before
the logit (about +-13.8), so fully transparent or opaque inputs give finite logits whose
sigmoid still rounds to the same 8-bit alpha.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .constants import ALPHA_EPS


def alpha_to_logit(alpha: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """logit(alpha) with alpha clamped to [ALPHA_EPS, 1 - ALPHA_EPS] (splat-transform's formula)."""
    a = np.clip(np.asarray(alpha, np.float64), ALPHA_EPS, 1.0 - ALPHA_EPS)
    return (-np.log(1.0 / a - 1.0)).astype(np.float32)


def logit_to_alpha(logits: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """sigmoid(logits) in float64; +inf -> 1, -inf -> 0."""
    with np.errstate(over="ignore"):
        return np.asarray(1.0 / (1.0 + np.exp(-np.asarray(logits, np.float64))), np.float64)
