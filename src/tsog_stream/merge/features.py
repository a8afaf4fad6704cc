"""Attribute columns in the spaces a SOG quantises, and how far each may move (the tolerance).

The tolerance bounds how far a merged Gaussian may be from each frame it stands for, in the
steps of a per-frame SOG: 16-bit log-position steps (they grow with 1 + |x|), 256-entry
codebook steps over the reference frame, 8-bit alpha steps, smallest-three byte steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..codec.positions import log_transform
from ..codec.rotations import SQRT2, canonical_quats
from ..columns import down
from ..constants import CODEBOOK_SIZE, U16_MAX
from ..errors import InputError
from ..model import Gaussians
from ..opacity import logit_to_alpha

F64 = npt.NDArray[np.float64]
BYTE_STEPS = 255.0
QUAT_STEP = SQRT2 / BYTE_STEPS
"""One smallest-three byte step of a quaternion component (range [-1/sqrt 2, 1/sqrt 2])."""
ALPHA_STEP = 1.0 / BYTE_STEPS
MEANS, SCALES, SH0, ALPHA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 10)
SH_REST = 10
"""First column of the f_rest coefficients."""
COLUMN_GROUPS = {
    "means": MEANS,
    "scales": SCALES,
    "sh0": SH0,
    "alpha": ALPHA,
    "shN": slice(SH_REST, None),
}


@dataclass(frozen=True, slots=True)
class Tolerance:
    """How far a merged or fitted Gaussian may be from each frame it stands for."""

    position: float | None = None
    """Scene units; None: ``steps`` times the per-frame SOG position step at each Gaussian."""
    steps: float = 0.5
    """Quantisation steps for the other attributes (and positions when ``position`` is None);
    0.5: as close as a per-frame SOG's rounding."""

    def __post_init__(self) -> None:
        if self.position is not None and not (np.isfinite(self.position) and self.position >= 0):
            raise InputError(f"expected >= 0 scene units, got {self.position}", where="tolerance")
        if not (np.isfinite(self.steps) and self.steps >= 0):
            raise InputError(f"expected >= 0 steps, got {self.steps}", where="tolerance-steps")


@dataclass(frozen=True, slots=True)
class Steps:
    """One quantisation step per attribute of a per-frame SOG, measured on a reference frame."""

    log_position: F64
    """Per axis: the 16-bit step of sign(x) ln(1 + |x|) over the frame's bounds."""
    scale: float
    sh0: float
    sh_rest: float

    @classmethod
    def of(cls, g: Gaussians) -> Steps:
        """The steps a SOG of ``g`` would quantise with (uniform spacing of its codebooks)."""
        if len(g) == 0:
            return cls(np.zeros(3), 0.0, 0.0, 0.0)
        logs = log_transform(g.means)
        return cls(
            (down(np.max, logs) - down(np.min, logs)) / U16_MAX,
            _codebook_step(g.scales),
            _codebook_step(g.sh0),
            _codebook_step(g.shN),
        )


def _codebook_step(values: npt.NDArray[np.float32]) -> float:
    """Spacing of a 256-entry codebook spread evenly over ``values``' range."""
    if values.size == 0:
        return 0.0
    return float(values.max() - values.min()) / (CODEBOOK_SIZE - 1)


EXTENT_QUANTILES = (0.05, 0.95)
FLOATER_MARGIN = 3.0
"""Search reaches come from an extent at most this many times the 5th-95th percentile spread
(real content: 1.11-2.16, docs/design/temporal-merge.md)."""


def robust_extent(means: npt.ArrayLike) -> F64:
    """Per-axis extent of the finite positions for search reaches: max - min, at most
    FLOATER_MARGIN times the 5th-95th percentile spread, so floaters do not make matching
    quadratic."""
    points = np.asarray(means, np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) == 0:
        return np.zeros(3)
    lo, hi = np.quantile(points, EXTENT_QUANTILES, axis=0)
    spread = down(np.max, points) - down(np.min, points)
    return np.asarray(np.minimum(spread, FLOATER_MARGIN * (hi - lo)), np.float64)


def columns(g: Gaussians) -> F64:
    """(N, 10 + 3K) float64: means, log-scales, f_dc, alpha, then f_rest."""
    n = len(g)
    return np.concatenate(
        [
            g.means.astype(np.float64),
            g.scales.astype(np.float64),
            g.sh0.astype(np.float64),
            logit_to_alpha(g.opacities)[:, None],
            g.shN.reshape(n, -1).astype(np.float64),
        ],
        axis=1,
    )


def unit_quats(g: Gaussians) -> F64:
    """Unit quaternions, largest component positive (zero ones become the identity)."""
    return canonical_quats(g.quats)[0]


def tolerances(cols: F64, steps: Steps, tol: Tolerance) -> F64:
    """Allowed deviation of every column of every row of ``cols``."""
    out = np.empty_like(cols)
    if tol.position is None:
        out[:, MEANS] = tol.steps * steps.log_position * (1.0 + np.abs(cols[:, MEANS]))
    else:
        out[:, MEANS] = tol.position
    out[:, SCALES] = tol.steps * steps.scale
    out[:, SH0] = tol.steps * steps.sh0
    out[:, ALPHA] = tol.steps * ALPHA_STEP
    out[:, SH_REST:] = tol.steps * steps.sh_rest
    return out


def quat_tolerance(tol: Tolerance) -> float:
    """Allowed deviation of each component of a sign-aligned unit quaternion."""
    return tol.steps * QUAT_STEP


def align_signs(quats: F64, reference: F64) -> F64:
    """``quats`` negated where they point away from ``reference`` (q and -q: one rotation)."""
    dots = np.einsum("ij,ij->i", quats, reference)
    return np.where(dots[:, None] < 0, -quats, quats)


def gaussians_from(cols: F64, quats: F64, sh_coeffs: int) -> Gaussians:
    """Gaussians from columns and (not necessarily unit) quaternions."""
    n = cols.shape[0]
    alpha = np.clip(cols[:, ALPHA][:, 0], 0.0, 1.0)
    with np.errstate(divide="ignore"):
        logits = np.log(alpha) - np.log1p(-alpha)
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    unit = np.divide(quats, norm, out=np.tile([1.0, 0, 0, 0], (n, 1)), where=norm > 0)
    return Gaussians.from_arrays(
        cols[:, MEANS],
        cols[:, SCALES],
        unit,
        logits,
        cols[:, SH0],
        shN=cols[:, SH_REST:].reshape(n, sh_coeffs, 3),
    )
