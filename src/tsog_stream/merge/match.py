"""Correspondence between two sets of Gaussians: by index where it holds, else by neighbours.

Candidates come from a grid over positions whose cell is the reach (a match lies in one of
27 neighbouring cells), scored in tolerance units; mutual best pairs within tolerance are kept.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import product

import numpy as np
import numpy.typing as npt

from .features import ALPHA, MEANS, SH0, align_signs

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
MATCH_ROUNDS = 3
"""Rounds of mutual-best matching on the leftovers."""
BATCH = 1 << 16
"""Rows of the query side scored at once (bounds the candidate arrays)."""
_OFFSETS = np.array(list(product((-1, 0, 1), repeat=3)), np.int64)
_BITS = 21
_BIAS = 1 << (_BITS - 1)
Pairer = Callable[[I64, I64], tuple[I64, I64]]
"""Pairs among the given rows of a and of b, as indices into those rows."""


@dataclass(frozen=True, slots=True)
class Side:
    """One side of a match: columns, unit quaternions and per-column tolerances."""

    cols: F64
    quats: F64
    tol: F64
    quat_tol: float

    def __len__(self) -> int:
        return int(self.cols.shape[0])

    def take(self, index: I64) -> Side:
        """The rows ``index``."""
        return Side(self.cols[index], self.quats[index], self.tol[index], self.quat_tol)


def deviation(a: Side, b: Side, ia: I64, ib: I64, *, with_means: bool = True) -> F64:
    """Largest deviation of each pair in units of both sides' tolerances summed (<= 1: within);
    positions left out when ``with_means`` is False."""
    allowed = a.tol[ia] + b.tol[ib]
    diff = np.abs(a.cols[ia] - b.cols[ib])
    scaled = np.divide(diff, allowed, out=np.where(diff > 0, np.inf, 0.0), where=allowed > 0)
    if not with_means:
        scaled[:, MEANS] = 0.0
    qa, qb = a.quats[ia], align_signs(b.quats[ib], a.quats[ia])
    qd = np.abs(qa - qb).max(axis=1)
    qallowed = a.quat_tol + b.quat_tol
    qscaled = qd / qallowed if qallowed > 0 else np.where(qd > 0, np.inf, 0.0)
    out: F64 = np.maximum(scaled.max(axis=1, initial=0.0), qscaled)
    return out


def by_index(a: Side, b: Side) -> tuple[I64, I64]:
    """Pairs (i, i) within tolerance, when both sides have the same length."""
    if len(a) != len(b) or len(a) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    idx = np.arange(len(a), dtype=np.int64)
    keep = deviation(a, b, idx, idx) <= 1.0
    return idx[keep], idx[keep]


def cell_keys(cells: I64) -> I64:
    """One int64 key per integer cell (x, y, z), 21 bits per axis."""
    c = (cells + _BIAS) & ((1 << _BITS) - 1)
    return np.asarray((c[:, 0] << (2 * _BITS)) | (c[:, 1] << _BITS) | c[:, 2], np.int64)


def candidate_pairs(keys_a: I64, cells_b: I64) -> Iterator[tuple[I64, I64]]:
    """(index into a, index into b) of every pair in neighbouring cells, in batches of b."""
    order = np.argsort(keys_a, kind="stable")
    sorted_keys = keys_a[order]
    for first in range(0, cells_b.shape[0], BATCH):
        batch = cells_b[first : first + BATCH]
        rank = np.argsort(cell_keys(batch), kind="stable")  # sorted queries search faster
        cb = batch[rank]
        parts_a, parts_b = [], []
        for off in _OFFSETS:
            k = cell_keys(cb + off)  # a constant offset keeps the keys sorted
            lo = np.searchsorted(sorted_keys, k, "left")
            hi = np.searchsorted(sorted_keys, k, "right")
            counts = hi - lo
            total = int(counts.sum())
            if total == 0:
                continue
            ib = np.repeat(rank, counts)
            starts = np.repeat(lo - (np.cumsum(counts) - counts), counts)
            parts_a.append(order[starts + np.arange(total)])
            parts_b.append(ib + first)
        if parts_a:
            yield np.concatenate(parts_a), np.concatenate(parts_b)


def mutual_best(ia: I64, ib: I64, cost: F64) -> tuple[I64, I64]:
    """Pairs that are each other's lowest cost (ties broken by index)."""
    if ia.size == 0:
        return ia, ib
    by_b = np.lexsort((ia, cost, ib))
    first_b = np.ones(by_b.size, bool)
    first_b[1:] = ib[by_b][1:] != ib[by_b][:-1]
    best_for_b = by_b[first_b]
    by_a = np.lexsort((ib, cost, ia))
    first_a = np.ones(by_a.size, bool)
    first_a[1:] = ia[by_a][1:] != ia[by_a][:-1]
    best_for_a = by_a[first_a]
    both = np.intersect1d(best_for_b, best_for_a, assume_unique=True)
    return ia[both], ib[both]


def _prefilter(a: Side, b: Side, ia: I64, ib: I64) -> npt.NDArray[np.bool_]:
    """Cheap first cut of candidate pairs: alpha, then colour within tolerance."""
    keep = np.ones(ia.size, bool)
    for part in (ALPHA, SH0):
        rows = np.flatnonzero(keep)
        diff = np.abs(a.cols[ia[rows], part] - b.cols[ib[rows], part])
        allowed = a.tol[ia[rows], part] + b.tol[ib[rows], part]
        keep[rows[~np.all(diff <= allowed, axis=1)]] = False
    return keep


def by_neighbours(a: Side, b: Side, reach: F64, *, moving: bool = False) -> tuple[I64, I64]:
    """Mutual best pairs whose positions are within ``reach`` (per axis) and whose other
    attributes are within tolerance; static matching (``moving`` False) also needs the
    positions within tolerance and scores by deviation, moving matching scores by distance."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    cell = np.where(reach > 0, reach, 1.0)
    keys_a = cell_keys(np.floor(a.cols[:, MEANS] / cell).astype(np.int64))
    cells_b = np.floor(b.cols[:, MEANS] / cell).astype(np.int64)
    found_a, found_b, found_cost = [], [], []
    for all_a, all_b in candidate_pairs(keys_a, cells_b):
        gap = np.abs(a.cols[all_a, MEANS] - b.cols[all_b, MEANS])
        near = np.all(gap <= reach, axis=1)
        ia, ib, gap = all_a[near], all_b[near], gap[near]
        keep = _prefilter(a, b, ia, ib)
        ia, ib, gap = ia[keep], ib[keep], gap[keep]
        dev = deviation(a, b, ia, ib, with_means=not moving)
        ok = dev <= 1.0
        cost = np.linalg.norm(gap[ok], axis=1) if moving else dev[ok]
        found_a.append(ia[ok])
        found_b.append(ib[ok])
        found_cost.append(cost)
    if not found_a:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return mutual_best(np.concatenate(found_a), np.concatenate(found_b), np.concatenate(found_cost))


def correspond(
    a: Side, b: Side, reach: F64, *, moving: bool = False, rounds: int = MATCH_ROUNDS
) -> tuple[I64, I64]:
    """Pairs (index in a, index in b): by index first, the rest by neighbours, repeated on
    what is left so twins that lost a mutual-best tie to each other still pair up."""
    found = by_index(a, b) if not moving else (np.zeros(0, np.int64), np.zeros(0, np.int64))

    def neighbours(rest_a: I64, rest_b: I64) -> tuple[I64, I64]:
        return by_neighbours(a.take(rest_a), b.take(rest_b), reach, moving=moving)

    return in_rounds(_all(len(a)), _all(len(b)), [neighbours] * rounds, found)


def in_rounds(
    rows_a: I64,
    rows_b: I64,
    rounds: Iterable[Pairer],
    found: tuple[I64, I64] | None = None,
    *,
    until_empty: bool = True,
) -> tuple[I64, I64]:
    """Pairs of ``rows_a`` and ``rows_b``: ``found``, then each round's on the rows still
    unpaired; with ``until_empty`` the first round finding none ends them (it repeats)."""
    found_a, found_b = ([found[0]], [found[1]]) if found else ([_all(0)], [_all(0)])
    for pair in rounds:
        rest_a = np.setdiff1d(rows_a, np.concatenate(found_a))
        rest_b = np.setdiff1d(rows_b, np.concatenate(found_b))
        ia, ib = pair(rest_a, rest_b)
        if until_empty and ia.size == 0:
            break
        found_a.append(rest_a[ia])
        found_b.append(rest_b[ib])
    return np.concatenate(found_a), np.concatenate(found_b)


def _all(count: int) -> I64:
    return np.arange(count, dtype=np.int64)
