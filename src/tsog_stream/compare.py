"""Per-attribute differences between two index-aligned sets of Gaussians.

Units: positions in scene units, rotations in degrees, scales and SH in their stored domains
(log sigma, f_dc, f_rest), opacity in alpha (0..1) so an 8-bit step is 1/255.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .errors import InputError
from .model import Gaussians
from .opacity import logit_to_alpha

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class AttributeErrors:
    """Worst and mean absolute differences per attribute (see module docstring for units)."""

    count: int
    means_max: float
    means_mean: float
    rotation_deg_max: float
    rotation_deg_mean: float
    scales_max: float
    scales_mean: float
    sh0_max: float
    sh0_mean: float
    opacity_max: float
    opacity_mean: float
    shN_rms: float
    shN_max: float

    def as_dict(self) -> dict[str, float]:
        """Plain dict for JSON reports."""
        return {k: float(v) for k, v in asdict(self).items()}


def _abs_stats(
    a: npt.NDArray[np.floating[Any]], b: npt.NDArray[np.floating[Any]]
) -> tuple[float, float]:
    """(max, mean) of |a - b| over finite entries; zeros for empty input."""
    d = np.abs(a.astype(np.float64) - b.astype(np.float64))
    d = d[np.isfinite(d)]
    return (float(d.max()), float(d.mean())) if d.size else (0.0, 0.0)


def rotation_angles_deg(qa: npt.ArrayLike, qb: npt.ArrayLike) -> F64:
    """Angle in degrees of the rotation between quaternion pairs (sign-insensitive)."""
    a = np.asarray(qa, np.float64)
    b = np.asarray(qb, np.float64)
    a = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-30)
    b = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-30)
    dot = np.clip(np.abs(np.sum(a * b, axis=1)), 0.0, 1.0)
    return np.asarray(np.degrees(2.0 * np.arccos(dot)), np.float64)


def attribute_errors(reference: Gaussians, candidate: Gaussians) -> AttributeErrors:
    """Differences of ``candidate`` from ``reference``, Gaussian i against Gaussian i."""
    if len(reference) != len(candidate):
        raise InputError(f"cannot compare {len(reference)} Gaussians with {len(candidate)}")
    if reference.shN.shape[1] != candidate.shN.shape[1]:
        raise InputError("cannot compare scenes with different SH bands")
    angles = rotation_angles_deg(reference.quats, candidate.quats)
    sh_diff = (reference.shN.astype(np.float64) - candidate.shN).reshape(-1)
    return AttributeErrors(
        len(reference),
        *_abs_stats(reference.means, candidate.means),
        *((float(angles.max()), float(angles.mean())) if angles.size else (0.0, 0.0)),
        *_abs_stats(reference.scales, candidate.scales),
        *_abs_stats(reference.sh0, candidate.sh0),
        *_abs_stats(logit_to_alpha(reference.opacities), logit_to_alpha(candidate.opacities)),
        float(np.sqrt(np.mean(sh_diff**2))) if sh_diff.size else 0.0,
        float(np.abs(sh_diff).max()) if sh_diff.size else 0.0,
    )
