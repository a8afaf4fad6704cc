"""Error-budgeted precision (``--quality``, 0..100): the quality scale's public face, and the
Gaussians too faint to store below 100.

Sans-I/O. A quality sets each Gaussian's error budgets (``budgets``), within which its codes
lose low bits (``coarsen``); every SOG/TSOG reader decodes the chunk unchanged. What a quality
guarantees: docs/spec.md, Appendix A.2; its measurements: docs/design/chunk-codec.md.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..model import Scene
from ..opacity import logit_to_alpha
from .budgets import QUALITY_MAX, budget_fraction

DEFAULT_QUALITY = 90
"""``tsog encode`` and ``tsog segment``'s default: within about 0.1 dB of quality 100's
rendered PSNR on the real scenes measured, for fewer bytes."""
ALPHA_BYTE_ZERO = 0.5 / 255.0
"""Alphas up to this are stored as byte 0 (SOG's opacity byte): drawn by no reader."""
FAINT_AT_ZERO = 0.2
"""At quality 0 a Gaussian of alpha up to this is left out (``f`` times it at quality q):
twice the opacity's slack."""


def faint_at(scene: Scene, quality: int) -> npt.NDArray[np.bool_]:
    """The Gaussians too faint to store below quality 100: an alpha within ``f *
    FAINT_AT_ZERO``, or one its byte would store as zero (ALPHA_BYTE_ZERO), at every time.
    None at 100, none whose opacity moves, and none when every one is (a chunk holds at
    least one). Why: such a Gaussian changes the picture less than its position's error
    would, and costs as many bytes as any other (spec, Appendix A.2)."""
    none = np.zeros(len(scene), np.bool_)
    f = budget_fraction(quality)
    if f <= 0.0 or len(scene) == 0 or "opacity" in scene.temporal:
        return none
    logits = np.asarray(scene.gaussians.opacities, np.float64).reshape(len(scene))
    # NaN compares False: kept, and refused by the encoder
    faint = logit_to_alpha(logits) <= max(f * FAINT_AT_ZERO, ALPHA_BYTE_ZERO)
    return none if faint.all() else faint


def without_faint(scene: Scene, quality: int) -> Scene:
    """``scene`` less the Gaussians :func:`faint_at` ``quality`` (itself when there are none):
    what ``tsog encode`` and ``tsog segment`` store."""
    faint = faint_at(scene, quality)
    if not faint.any():
        return scene
    kept = np.flatnonzero(~faint)
    del faint
    return scene.subset(kept)


__all__ = [
    "ALPHA_BYTE_ZERO",
    "DEFAULT_QUALITY",
    "FAINT_AT_ZERO",
    "QUALITY_MAX",
    "budget_fraction",
    "faint_at",
    "without_faint",
]
