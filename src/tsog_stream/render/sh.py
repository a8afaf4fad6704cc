"""View-dependent colour from spherical harmonics, degree 0-3, as the 3DGS reference computes it.

The basis constants and signs are those of 3DGS (``computeColorFromSH``): real SH with the
Condon-Shortley phase folded in, the direction running from the camera centre to the Gaussian.
The colour is ``0.5 + sum(basis * coefficients)`` clamped below at 0 (not above).
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from ..columns import rows_per_block
from ..constants import SH_C0

F64 = npt.NDArray[np.float64]

SH_C1: Final = 0.4886025119029199
SH_C2: Final = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3: Final = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: F64, coeffs: int) -> F64:
    """The first ``coeffs`` (1, 4, 9 or 16) SH basis values of unit directions (N, 3)."""
    x, y, z = np.ascontiguousarray(dirs.T)  # contiguous components: faster arithmetic
    out = np.empty((coeffs, dirs.shape[0]), np.float64).T  # column-major: fast column writes
    out[:, 0] = SH_C0
    if coeffs > 1:
        out[:, 1] = -SH_C1 * y
        out[:, 2] = SH_C1 * z
        out[:, 3] = -SH_C1 * x
    if coeffs > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[:, 4] = SH_C2[0] * x * y
        out[:, 5] = SH_C2[1] * y * z
        out[:, 6] = SH_C2[2] * (2 * zz - xx - yy)
        out[:, 7] = SH_C2[3] * x * z
        out[:, 8] = SH_C2[4] * (xx - yy)
    if coeffs > 9:
        out[:, 9] = SH_C3[0] * y * (3 * xx - yy)
        out[:, 10] = SH_C3[1] * x * y * z
        out[:, 11] = SH_C3[2] * y * (4 * zz - xx - yy)
        out[:, 12] = SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy)
        out[:, 13] = SH_C3[4] * x * (4 * zz - xx - yy)
        out[:, 14] = SH_C3[5] * z * (xx - yy)
        out[:, 15] = SH_C3[6] * x * (xx - 3 * yy)
    return out


def sh_colors(
    means: npt.NDArray[np.floating],
    sh0: npt.NDArray[np.floating],
    shN: npt.NDArray[np.floating],
    camera_position: F64,
) -> F64:
    """RGB (N, 3) of Gaussians at ``means`` seen from ``camera_position``, clamped at 0.

    ``sh0`` is (N, 3) f_dc, ``shN`` (N, K, 3) with K in 0/3/8/15 (all available bands are used).
    Evaluated a block at a time (a row's basis: a float64 per coefficient) so the temporaries
    stay in cache.
    """
    out = np.empty((means.shape[0], 3), np.float64)
    block = rows_per_block(8 * (1 + shN.shape[1]))
    for lo in range(0, means.shape[0], block):
        hi = lo + block
        out[lo:hi] = _block_colors(means[lo:hi], sh0[lo:hi], shN[lo:hi], camera_position)
    return out


def _block_colors(
    means: npt.NDArray[np.floating],
    sh0: npt.NDArray[np.floating],
    shN: npt.NDArray[np.floating],
    camera_position: F64,
) -> F64:
    """:func:`sh_colors` of one block."""
    coeffs = 1 + shN.shape[1]
    dirs = means.astype(np.float64) - camera_position
    norms = np.sqrt(np.einsum("ni,ni->n", dirs, dirs))[:, None]
    dirs = dirs / np.where(norms > 0, norms, 1.0)
    basis = sh_basis(dirs, coeffs)
    rgb = basis[:, :1] * sh0
    if coeffs > 1:
        rgb += np.einsum("nk,nkc->nc", basis[:, 1:], shN)
    return np.maximum(rgb + 0.5, 0.0)
