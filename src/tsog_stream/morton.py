"""Morton (Z-order) permutation of Gaussians, identical to splat-transform's texel order.

Rules (docs/spec.md, "Gaussian order"): per call, the bounding box of the points; 10 bits per
axis, x in bit 0, y in bit 1, z in bit 2; stable sort by code; every run of more than
``REFINE_RUN`` Gaussians sharing one code is sorted again with its own bounding box.
"""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt

CELLS_PER_AXIS = 1024
REFINE_RUN = 256


def _spread_bits(v: npt.NDArray[np.uint32]) -> npt.NDArray[np.uint32]:
    """Insert two zero bits between each of the low 10 bits of ``v``."""
    v = v & np.uint32(0x000003FF)
    v = (v ^ (v << np.uint32(16))) & np.uint32(0xFF0000FF)
    v = (v ^ (v << np.uint32(8))) & np.uint32(0x0300F00F)
    v = (v ^ (v << np.uint32(4))) & np.uint32(0x030C30C3)
    v = (v ^ (v << np.uint32(2))) & np.uint32(0x09249249)
    return v


def _cells(axis: npt.NDArray[np.float64]) -> npt.NDArray[np.uint32] | None:
    """10-bit cell index of each value within the axis' own extent (None if not finite)."""
    lo, hi = float(axis.min()), float(axis.max())
    extent = hi - lo
    if not np.isfinite(extent):
        return None
    mul = 0.0 if extent == 0 else CELLS_PER_AXIS / extent
    cell = np.minimum(CELLS_PER_AXIS - 1, (axis - lo) * mul)
    return np.nan_to_num(cell, nan=0.0).astype(np.uint32)


def _codes(points: npt.NDArray[np.float64]) -> npt.NDArray[np.uint32] | None:
    """Morton codes of ``points`` (M, 3) in their own box, or None to leave them as they are."""
    if points.shape[0] == 0:
        return None
    cells = [_cells(points[:, a]) for a in range(3)]
    if any(c is None for c in cells):
        return None
    if all(float(points[:, a].min()) == float(points[:, a].max()) for a in range(3)):
        return None
    cx, cy, cz = (c for c in cells if c is not None)
    return (
        (_spread_bits(cz) << np.uint32(2)) + (_spread_bits(cy) << np.uint32(1)) + _spread_bits(cx)
    )


def morton_order(positions: npt.ArrayLike) -> npt.NDArray[np.intp]:
    """Permutation ``order`` such that texel i holds Gaussian ``order[i]``."""
    pts = np.asarray(positions, dtype=np.float32).astype(np.float64)
    order = np.arange(pts.shape[0], dtype=np.intp)
    pending = [(0, pts.shape[0])]
    while pending:
        start, end = pending.pop()
        idx = order[start:end]
        codes = _codes(pts[idx])
        if codes is None:
            continue
        sort = np.argsort(codes, kind="stable")
        order[start:end] = idx[sort]
        pending.extend(_long_runs(codes[sort], start))
    return order


def morton_run(positions: npt.ArrayLike, start: int, count: int) -> npt.NDArray[np.intp]:
    """The ``count`` Gaussians from rank ``start`` of the Morton order (ties at its ends settled
    either way), in Morton order, by a partial selection rather than a full sort."""
    pts = np.asarray(positions, dtype=np.float32).astype(np.float64)
    total = pts.shape[0]
    if not 0 <= start <= start + count <= total:
        raise ValueError(f"run {start}..{start + count} outside 0..{total}")
    codes = _codes(pts)
    if codes is None or count in (0, total):
        return morton_order(pts)[start : start + count]
    bounds = [start, start + count - 1]
    picked = np.argpartition(codes, bounds)[start : start + count]
    picked.sort()  # input order within equal codes, as the stable sort keeps it
    return picked[morton_order(pts[picked])]


def morton_parts(positions: npt.ArrayLike, parts: int) -> list[npt.NDArray[np.intp]]:
    """The indices of ``positions`` cut into ``parts`` consecutive runs of their Morton order,
    sized as ``np.array_split`` sizes them, each run ascending (ties at a cut settled either
    way), by a partial selection at the cuts; points without codes are cut in input order."""
    total = int(np.shape(positions)[0])
    whole, extra = divmod(total, max(parts, 1))
    sizes = [whole + 1] * extra + [whole] * (max(parts, 1) - extra)  # as np.array_split
    bounds = np.cumsum([0, *sizes])
    codes = None
    if parts > 1:  # one run needs no codes, nor a float64 copy of the positions
        codes = _codes(np.asarray(positions, dtype=np.float32).astype(np.float64))
    if codes is None:
        return [np.arange(a, b, dtype=np.intp) for a, b in itertools.pairwise(bounds)]
    order = np.argpartition(codes, bounds[1:-1])
    return [np.sort(order[a:b]) for a, b in itertools.pairwise(bounds)]


def _long_runs(sorted_codes: npt.NDArray[np.uint32], offset: int) -> list[tuple[int, int]]:
    """(start, end) of every run longer than REFINE_RUN of equal codes, shifted by ``offset``."""
    if sorted_codes.size <= REFINE_RUN:
        return []
    breaks = np.flatnonzero(np.diff(sorted_codes)) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [sorted_codes.size]))
    long = (ends - starts) > REFINE_RUN
    return [
        (offset + int(s), offset + int(e)) for s, e in zip(starts[long], ends[long], strict=True)
    ]
