"""Tile binning and the numpy front-to-back compositor (the reference path of the renderer).

Each projected Gaussian is duplicated into every 16x16 tile its 3-sigma rectangle touches;
the pairs are ordered by tile, then by view depth (ties by input order, like the reference's
stable radix sort). A tile's pixels are then composited front to back in batches: per batch the
alphas of all (Gaussian, pixel) pairs, the transmittance by a cumulative product seeded with
the pixel's current transmittance (the same multiplications, in the same order, as the
sequential loop), and the early-termination rule applied exactly (see docs/design/renderer.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .project import TILE, Projected

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

ALPHA_MAX = 0.99
"""Alpha is clamped to this so one Gaussian never makes a pixel fully opaque."""
ALPHA_MIN = 1.0 / 255.0
"""Contributions below this alpha are skipped."""
T_MIN = 1e-4
"""A pixel stops as soon as T * (1 - alpha) would fall below this (that Gaussian is dropped)."""
BATCH = 64
"""Gaussians composited together by the numpy path (any value gives the same image)."""


@dataclass(frozen=True, slots=True)
class TileBins:
    """Gaussians per tile: ``ids[starts[k]:starts[k + 1]]`` index ``Projected`` rows of tile k."""

    grid_x: int
    grid_y: int
    ids: I64
    starts: I64


def bin_tiles(proj: Projected, width: int, height: int, only: I64 | None = None) -> TileBins:
    """Duplicate each Gaussian into its tiles and sort the pairs by (tile, depth, input order);
    ``only``: just those rows, as if the projection held no others, in that input order (rows
    already in drawing order sort at once)."""
    gx, gy = -(-width // TILE), -(-height // TILE)
    if only is None:
        by_depth = np.argsort(proj.depth, kind="stable")
    else:
        by_depth = only[np.argsort(proj.depth[only], kind="stable")]
    rect = proj.rect[by_depth]
    w = rect[:, 1] - rect[:, 0]
    counts = w * (rect[:, 3] - rect[:, 2])
    total = int(counts.sum())
    owner = np.repeat(np.arange(by_depth.shape[0]), counts)
    local = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    tiles = (rect[owner, 2] + local // w[owner]) * gx + rect[owner, 0] + local % w[owner]
    key = tiles.astype(np.uint16) if gx * gy <= 1 << 16 else tiles
    order = np.argsort(key, kind="stable")  # radix sort for 16-bit keys
    ids = by_depth[owner[order]]
    starts = np.zeros(gx * gy + 1, np.int64)
    np.cumsum(np.bincount(tiles, minlength=gx * gy), out=starts[1:])
    return TileBins(gx, gy, ids.astype(np.int64), starts)


def _composite_tile(proj: Projected, ids: I64, px: F64, py: F64) -> tuple[F64, F64]:
    """Colour (P, 3) and final transmittance (P,) of pixels (px, py) over Gaussians ``ids``."""
    n_pix = px.shape[0]
    color = np.zeros((n_pix, 3), np.float64)
    trans = np.ones(n_pix, np.float64)
    live = np.arange(n_pix)
    for start in range(0, ids.shape[0], BATCH):
        g = ids[start : start + BATCH]
        dx = proj.xy[g, 0][:, None] - px[live][None, :]
        dy = proj.xy[g, 1][:, None] - py[live][None, :]
        a, b, c = proj.conic[g, 0][:, None], proj.conic[g, 1][:, None], proj.conic[g, 2][:, None]
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = np.minimum(ALPHA_MAX, proj.opacity[g][:, None] * np.exp(np.minimum(power, 0.0)))
        alpha[(power > 0) | (alpha < ALPHA_MIN)] = 0.0  # skipped: T unchanged, no termination
        steps = np.concatenate([trans[live][None, :], 1.0 - alpha])
        t_after = np.cumprod(steps, axis=0)[1:]  # T * (1 - alpha), sequential products
        ok = t_after >= T_MIN  # monotone in depth order: False from the stopping Gaussian on
        t_before = np.concatenate([trans[live][None, :], t_after[:-1]])
        weight = np.where(ok, alpha * t_before, 0.0)
        color[live] += weight.T @ proj.color[g]
        n_ok = ok.sum(axis=0)
        t_last = t_after[np.maximum(n_ok - 1, 0), np.arange(live.shape[0])]
        trans[live] = np.where(n_ok > 0, t_last, trans[live])
        live = live[ok[-1]]
        if live.shape[0] == 0:
            break
    return color, trans


def rasterize_numpy(
    proj: Projected, bins: TileBins, width: int, height: int, background: F64
) -> npt.NDArray[np.float32]:
    """The (H, W, 3) image: every tile composited front to back, plus background * T."""
    image = np.zeros((height, width, 3), np.float64)
    for ty in range(bins.grid_y):
        for tx in range(bins.grid_x):
            y0, x0 = ty * TILE, tx * TILE
            ys, xs = np.mgrid[y0 : min(y0 + TILE, height), x0 : min(x0 + TILE, width)]
            k = ty * bins.grid_x + tx
            ids = bins.ids[bins.starts[k] : bins.starts[k + 1]]
            color, trans = _composite_tile(
                proj, ids, xs.ravel().astype(np.float64), ys.ravel().astype(np.float64)
            )
            out = color + trans[:, None] * background[None, :]
            image[y0 : y0 + ys.shape[0], x0 : x0 + xs.shape[1]] = out.reshape(*ys.shape, 3)
    return image.astype(np.float32)
