"""Coarsening: a 16-bit (or 8-bit) code rounded to the coarsest power-of-two grid whose error
stays within its budget (``budgets``).

Sans-I/O. A coarsened code is still a code over the chunk's ``[min, max]``: its dropped bits
are zeros, which lossless WebP stores almost for free, and every reader decodes it unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from ..columns import row_blocks
from ..constants import U16_MAX
from .budgets import TURN_PER_COMPONENT, Budgets

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
U16 = npt.NDArray[np.uint16]
CodesT = TypeVar("CodesT", npt.NDArray[np.uint8], npt.NDArray[np.uint16])

QUAT_STEP = float(np.sqrt(2.0)) / 255.0
"""A smallest-three quaternion byte's step in component units (SOG v2 quats.webp)."""

Tolerance = F64 | Callable[[slice], F64]
"""Tolerances in codes broadcast against the codes, or a block of rows' tolerances from the
rows (where the tolerances of every row are themselves several arrays of every row)."""


def coarsen(codes: CodesT, tolerance: Tolerance, *, shared: bool = False) -> CodesT:
    """Each code (16-bit, or 8-bit) rounded to the coarsest grid of power-of-two steps whose
    rounding error is within its ``tolerance`` (in codes); a code that would round out of the
    code range keeps its value. With ``shared`` the grids are laid through each channel's most
    frequent code, so a value many Gaussians share (a zero rate of turn) stays one value;
    else through code 0. Integer arithmetic, a block of rows at a time."""
    anchor = most_frequent(codes).astype(np.int32) if shared else None
    of_rows = tolerance if callable(tolerance) else _rows_of(tolerance, codes.shape)
    out = np.empty_like(codes)
    for rows in row_blocks(len(codes), 8 * int(np.prod(codes.shape[1:]))):
        out[rows] = _on_grids(codes[rows], of_rows(rows), anchor)
    return out


def _rows_of(tolerance: F64, shape: tuple[int, ...]) -> Callable[[slice], F64]:
    """A block of rows' tolerances of tolerances broadcast against codes of ``shape``."""
    every = np.broadcast_to(tolerance, shape)
    return lambda rows: every[rows]


def _on_grids(codes: CodesT, tolerance: F64, anchor: npt.NDArray[np.int32] | None) -> CodesT:
    """:func:`coarsen` of a block of rows, the grids through ``anchor`` (else code 0)."""
    top = int(np.iinfo(codes.dtype).max)
    tol = np.minimum(np.fmax(tolerance, 0.5), float(top))  # NaN, -inf and < 0.5: 0.5; inf: top
    # floor(log2(2 tol)): 0 for a tolerance under one code
    bits = np.minimum(np.frexp(tol)[1], top.bit_length() - 1)
    if not bits.any():
        return codes
    grid = np.left_shift(np.int32(1), bits, dtype=np.int32)
    q = codes.astype(np.int32)  # codes, grids and sums all fit in int32
    rounded = q + (grid >> 1)
    if anchor is not None:
        rounded -= anchor
        rounded &= -grid  # floor to the grid
        rounded += anchor
    else:
        rounded &= -grid
    outside = rounded > top
    if anchor is not None:  # a grid through the anchor may round below 0 too
        outside |= rounded < 0
    return np.where(outside, q, rounded).astype(codes.dtype)


def most_frequent(codes: CodesT) -> npt.NDArray[np.int64]:
    """The most frequent code of each channel (the columns of a 2-D array; all of a 1-D one),
    shaped to broadcast against ``codes``; 0 when there are none."""
    columns = codes.reshape(len(codes), -1)
    modes = [
        int(np.bincount(columns[:, c]).argmax()) if len(columns) else 0
        for c in range(columns.shape[1])
    ]
    return np.asarray(modes, np.int64).reshape(codes.shape[1:])


def to_codes(tolerance: F64, mins: F64, maxs: F64) -> F64:
    """A tolerance in value units as one in 16-bit codes over ``[mins, maxs]`` (per channel, the
    last axis; unlimited where the range is empty: every code is 0 there)."""
    span = np.asarray(maxs, np.float64) - np.asarray(mins, np.float64)
    empty = ~(span > 0)
    out: F64 = np.multiply(tolerance, float(U16_MAX)) / np.where(empty, 1.0, span)
    if empty.any():
        out[..., empty] = np.inf
    return out


def coarsen_positions(codes: U16, mins: F64, maxs: F64, means: F64, budget: F64) -> U16:
    """Position codes (SOG's symmetric-log domain) coarsened within ``budget`` scene units per
    Gaussian: d(log)/dx = 1 / (1 + |x|) turns the budget into a log-domain one per axis."""
    log_budget = budget[:, None] / (1.0 + np.abs(means))
    return coarsen(codes, to_codes(log_budget, mins, maxs))


def coarsen_rotations(texels: U8, budget: F64) -> U8:
    """Smallest-three rotation texels (R, G, B; the A tag kept) coarsened so each rotation
    turns by at most ``budget`` radians: a turn is at most 4·√3 times the largest component
    error (twice the quaternion distance, the fourth component rederived)."""
    out = texels.copy()
    out[:, :3] = coarsen(texels[:, :3], (budget / TURN_PER_COMPONENT / QUAT_STEP)[:, None])
    return out


def thin_labels(labels: U8, codebook: F32, slack: float) -> tuple[U8, F32]:
    """Codebook labels moved to fewer distinct entries, and the codebook they index: entries
    are kept ascending while more than ``slack`` above the last kept one, and each label goes
    to the nearest kept entry, at most ``slack`` from its own, so a value's error grows by at
    most ``slack``. An entry no label points to any more repeats the kept one it moved to (still
    ascending): meta.json deflates repeats, so small chunks stop paying for unused entries."""
    table = np.asarray(codebook, np.float64)
    if slack <= 0 or table.size == 0:
        return labels, codebook
    kept = [0]
    for i in range(1, table.size):
        if table[i] - table[kept[-1]] > slack:
            kept.append(i)
    kept_values = table[kept]
    mids = (kept_values[:-1] + kept_values[1:]) / 2
    nearest = np.asarray(kept)[np.searchsorted(mids, table, side="right")]
    return nearest.astype(np.uint8)[labels], codebook[nearest]


def coarsen_alpha(alpha: U8, slack: float) -> U8:
    """Opacity bytes coarsened within ``slack`` (alpha units)."""
    return coarsen(alpha, np.asarray(slack * 255.0))


def coarsen_timeline(codes: U16, mins: F64, maxs: F64, budget: F64) -> U16:
    """Timeline codes (R and G) coarsened within ``budget`` ((N, 2), value units)."""
    return coarsen(codes, to_codes(budget, mins, maxs))


def coarsen_motion(
    codes: U16,
    mins: F64,
    maxs: F64,
    *,
    attr: str,
    order: int,
    orders: int,
    budgets: Budgets,
) -> U16:
    """Codes of order ``order`` of the motion of ``attr`` coarsened so that, over the
    Gaussian's lifespan, the change it makes to the attribute (times a type-2 Gaussian's
    temporal opacity) stays within its share of :meth:`Budgets.change_over_lifespan`, split
    evenly over the ``orders`` (their sum's too, by Minkowski's inequality); an error d moves
    the attribute by d times :meth:`Budgets.motion_span`."""
    shared = attr != "means"  # rates of turn, scale, colour, opacity: mostly one value (zero)

    def tolerance(rows: slice) -> F64:  # a block's at a time, not every row's float64
        share = budgets.change_over_lifespan(attr, codes.shape[1], rows)
        share /= orders
        span = budgets.motion_span(order, rows)
        still = ~(span > 0)  # no time to move in: any coefficient will do
        share /= np.where(still, 1.0, span)[:, None]
        share[still] = np.inf
        return to_codes(share, mins, maxs)

    return coarsen(codes, tolerance, shared=shared)
