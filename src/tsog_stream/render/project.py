"""EWA projection of 3D Gaussians to screen-space conics, as in 3DGS (Kerbl et al. 2023).

Vectorised numpy, float64. For each Gaussian: Sigma = R S S^T R^T, the view transform W, the
Jacobian J of the perspective projection at the mean (its x/z, y/z clamped to 1.3x the frustum
like the reference), cov2d = J W Sigma W^T J^T + 0.3 I, the conic (its inverse), a 3-sigma
radius and the 16x16 tiles it touches. The "antialiased" variant scales opacity by
sqrt(det(cov2d - 0.3 I) / det(cov2d)) (Mip-Splatting's 2D filter compensation).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import numpy.typing as npt

from ..columns import rows_per_block
from ..framing import rotation, world_to_camera
from ..model import Gaussians
from ..opacity import logit_to_alpha
from ..schemas.cameras import Camera
from .camera import check_drawable
from .sh import sh_colors

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

TILE = 16
"""Tile side in pixels (the reference's BLOCK_X = BLOCK_Y)."""
NEAR = 0.2
"""Gaussians with view depth z <= NEAR are culled."""
LOW_PASS = 0.3
"""Added to the diagonal of every screen covariance (a one-pixel-ish low-pass filter)."""
GUARD_BAND = 1.3
"""The Jacobian is evaluated at x/z, y/z clamped to this multiple of the half frustum."""
ROW_BYTES = 64
"""Bytes of float64 temporaries one Gaussian's projection holds at once (about eight values):
``columns.rows_per_block`` of them are projected together."""


@dataclass(frozen=True, slots=True)
class Projected:
    """The Gaussians that survive culling, in screen space (M rows each).

    ``index`` points back into the input, ``xy`` are pixel coordinates of the means (pixel
    index convention), ``conic`` the inverse screen covariance (a, b, c) with
    power = -0.5 (a dx^2 + c dy^2) - b dx dy, ``rect`` the tile rectangle [x0, x1) x [y0, y1).
    """

    index: I64
    xy: F64
    conic: F64
    opacity: F64
    color: F64
    depth: F64
    radius: I64
    rect: I64


def quat_to_rotmat(quats: npt.NDArray[np.floating]) -> F64:
    """Rotation matrices (N, 3, 3) of (w, x, y, z) quaternions, normalised first."""
    q = quats.astype(np.float64)
    norms = np.sqrt(np.einsum("ni,ni->n", q, q))[:, None]
    w, x, y, z = (q / np.where(norms > 0, norms, 1.0)).T
    r = np.empty((q.shape[0], 3, 3), np.float64)
    r[:, 0, 0], r[:, 0, 1], r[:, 0, 2] = (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
    )
    r[:, 1, 0], r[:, 1, 1], r[:, 1, 2] = (
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
    )
    r[:, 2, 0], r[:, 2, 1], r[:, 2, 2] = (
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )
    return r


def _screen_rows(p_view: F64, camera: Camera) -> tuple[F64, F64]:
    """The two rows (N, 3) of T = J W: the guard-banded projection Jacobian times the view."""
    z = p_view[:, 2]
    view = rotation(camera).T
    cx, cy = camera.principal_point
    rows = []
    for axis, (f, c, size) in enumerate(
        ((camera.fx, cx, camera.width), (camera.fy, cy, camera.height))
    ):
        centre, half = (size / 2 - c) / f, size / (2 * f)
        lo, hi = centre - GUARD_BAND * half, centre + GUARD_BAND * half
        t = np.clip(p_view[:, axis] / z, lo, hi) * z
        rows.append((f / z)[:, None] * view[axis] - (f * t / (z * z))[:, None] * view[2])
    return rows[0], rows[1]


def screen_covariances(
    p_view: F64, scales: npt.NDArray[np.floating], quats: npt.NDArray[np.floating], camera: Camera
) -> tuple[F64, F64, F64]:
    """(a, b, c) of J W Sigma W^T J^T, without the low-pass, via U = J W R S: cov2d = U U^T."""
    m = quat_to_rotmat(quats) * np.exp(scales.astype(np.float64))[:, None, :]
    t0, t1 = _screen_rows(p_view, camera)
    u0 = np.einsum("ni,nij->nj", t0, m)
    u1 = np.einsum("ni,nij->nj", t1, m)
    return (
        np.einsum("ni,ni->n", u0, u0),
        np.einsum("ni,ni->n", u0, u1),
        np.einsum("ni,ni->n", u1, u1),
    )


def _tile_rects(xy: F64, radius: I64, camera: Camera) -> I64:
    """Tile rectangles (N, 4) = x0, x1, y0, y1 (exclusive ends), as the reference's getRect."""
    gx, gy = -(-camera.width // TILE), -(-camera.height // TILE)
    r = radius.astype(np.float64)
    rect = np.empty((xy.shape[0], 4), np.int64)
    edges = (
        (xy[:, 0], gx, -r),
        (xy[:, 0], gx, r + TILE - 1),
        (xy[:, 1], gy, -r),
        (xy[:, 1], gy, r + TILE - 1),
    )
    for col, (v, grid, shift) in enumerate(edges):
        edge = np.trunc(v + shift)  # C's (int) cast truncates towards zero
        edge = np.clip(edge, -1.0, 1e9).astype(np.int64) // TILE
        rect[:, col] = np.clip(edge, 0, grid)
    return rect


def project(gaussians: Gaussians, camera: Camera, *, antialiased: bool = False) -> Projected:
    """Cull and project ``gaussians`` for ``camera``; see the module docstring for the maths.

    Works a block of Gaussians at a time (temporaries stay in cache; same results); a
    camera :func:`~tsog_stream.render.camera.check_drawable` refuses raises InputError.
    """
    check_drawable(camera)
    n, step = len(gaussians), rows_per_block(ROW_BYTES)
    if n <= step:
        return _project_block(gaussians, camera, antialiased)
    parts = []
    g = gaussians
    for lo in range(0, n, step):
        r = slice(lo, lo + step)  # views, no copies
        part = Gaussians(g.means[r], g.scales[r], g.quats[r], g.opacities[r], g.sh0[r], g.shN[r])
        block = _project_block(part, camera, antialiased)
        parts.append(replace(block, index=block.index + lo))
    columns = (np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Projected))
    return Projected(*columns)


def _project_block(gaussians: Gaussians, camera: Camera, antialiased: bool) -> Projected:
    """:func:`project` of one block of Gaussians."""
    w2c = world_to_camera(camera)
    view = w2c[:3, :3]
    p_view = gaussians.means.astype(np.float64) @ view.T + w2c[:3, 3]
    keep = np.flatnonzero(p_view[:, 2] > NEAR)
    p_view = p_view[keep]
    z = p_view[:, 2]
    a0, b, c0 = screen_covariances(p_view, gaussians.scales[keep], gaussians.quats[keep], camera)
    a, c = a0 + LOW_PASS, c0 + LOW_PASS
    det = a * c - b * b
    opacity = logit_to_alpha(gaussians.opacities[keep])
    if antialiased:
        with np.errstate(divide="ignore", invalid="ignore"):
            opacity = opacity * np.sqrt(np.maximum(0.0, (a0 * c0 - b * b) / det))
    with np.errstate(divide="ignore", invalid="ignore"):
        conic = np.stack([c / det, -b / det, a / det], axis=1)
        mid = 0.5 * (a + c)
        lambda1 = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
        radius_f = np.ceil(3.0 * np.sqrt(lambda1))
    cx, cy = camera.principal_point
    xy = np.stack(
        [
            camera.fx * p_view[:, 0] / z + cx - 0.5,
            camera.fy * p_view[:, 1] / z + cy - 0.5,
        ],
        axis=1,
    )
    ok = (det > 0) & np.isfinite(radius_f) & np.all(np.isfinite(xy), axis=1)
    ok &= np.all(np.isfinite(conic), axis=1) & np.isfinite(opacity)
    radius = np.where(ok, radius_f, 0.0).astype(np.int64)
    rect = _tile_rects(np.where(ok[:, None], xy, 0.0), radius, camera)
    ok &= (rect[:, 1] > rect[:, 0]) & (rect[:, 3] > rect[:, 2])
    sel = keep[ok]
    eye = np.array(camera.position, dtype=np.float64)
    if sel.shape[0] == len(gaussians):  # everything visible: skip copying the SH arrays
        color = sh_colors(gaussians.means, gaussians.sh0, gaussians.shN, eye)
    else:
        color = sh_colors(gaussians.means[sel], gaussians.sh0[sel], gaussians.shN[sel], eye)
    return Projected(sel, xy[ok], conic[ok], opacity[ok], color, z[ok], radius[ok], rect[ok])
