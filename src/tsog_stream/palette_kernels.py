"""The SH palette's kernels (``sh_palette``): distinct rows, principal axes, approximate
nearest neighbours in balanced kd-trees, Ward merges and Lloyd steps, on numpy arrays.

Work goes a block of rows at a time (``constants.BLOCK_BYTES``) so a fit holds about one copy of
its vectors; results do not depend on the block size (docs/design/quantizers.md).
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from .columns import rows_per_block
from .inplace import compact_rows

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.intp]

COVARIANCE_BLOCK_BYTES: Final = 16 << 20
"""Bytes of the rows summed at a time into the principal axes' covariance: a fixed summation
order, on which the palette (and so a chunk's bytes) depends."""
LEAF_SIZE: Final = 128
"""Points per kd-tree leaf searched by brute force."""
TREES: Final = 2
"""Independent kd-trees whose leaf neighbours are pooled."""
SPLIT_DIMS: Final = 16
"""Leading principal axes the kd-trees split on."""
WIDTH_SAMPLE: Final = 64
"""Points per segment sampled to pick the widest coordinate."""
MIXED_DIMS: Final = 8
"""Leading axes randomly rotated for every tree after the first."""
HASH_MULTIPLIER: Final = np.uint64(0x9E3779B97F4A7C15)
"""Odd 64-bit multiplier of the row hash (2^64 over the golden ratio)."""


def unique_rows(data: F32) -> tuple[F32, Ints, F64]:
    """Distinct rows (byte-wise), the row of each input vector, and multiplicities: rows told
    apart by a 64-bit hash, checked, and sorted themselves only on a collision (3x faster)."""
    _, first, inverse, counts = np.unique(
        row_hashes(data), return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1).astype(np.intp)
    if not _each_matches(data, first, inverse):  # a collision: sort the rows themselves
        rows = data.view(np.dtype((np.void, data.dtype.itemsize * data.shape[1]))).reshape(-1)
        _, first, inverse, counts = np.unique(
            rows, return_index=True, return_inverse=True, return_counts=True
        )
        inverse = inverse.reshape(-1).astype(np.intp)
    return np.take(data, first, axis=0), inverse, counts.astype(np.float64)


def _each_matches(data: F32, first: Ints, inverse: Ints) -> bool:
    """Whether every row equals the row its hash matched it to (a block at a time)."""
    step = rows_per_block(4 * data.shape[1])
    for start in range(0, len(data), step):
        rows = np.take(first, inverse[start : start + step])
        if not np.array_equal(np.take(data, rows, axis=0), data[start : start + step]):
            return False
    return True


def row_hashes(data: F32) -> npt.NDArray[np.uint64]:
    """A 64-bit hash of each row's bytes: h = h * HASH_MULTIPLIER + word, word by word, each
    step mixed by a xor-shift (wrapping arithmetic)."""
    words = data.view(np.uint32)
    hashes = np.zeros(len(data), np.uint64)
    for column in words.T:
        hashes *= HASH_MULTIPLIER
        hashes += column
        hashes ^= hashes >> np.uint64(29)
    return hashes


def principal_axes(points: F32, weights: F64) -> tuple[F32, F32]:
    """Weighted mean and the leading principal axes (D, ≤ SPLIT_DIMS) of the points, summed by
    ``einsum`` (BLAS sums in an order that depends on its thread count)."""
    mean = np.einsum("n,nd->d", weights, points) / weights.sum()  # float64 sums, no copy
    centre = mean.astype(np.float32)
    cov = np.zeros((points.shape[1], points.shape[1]), np.float64)
    step = max(1, COVARIANCE_BLOCK_BYTES // (4 * points.shape[1]))
    for start in range(0, len(points), step):
        centred = points[start : start + step] - centre
        weighted = centred * weights[start : start + step, None].astype(np.float32)
        cov += np.einsum("nd,ne->de", weighted, centred)
    _, vecs = np.linalg.eigh(cov)
    axes = np.ascontiguousarray(vecs[:, ::-1][:, : min(SPLIT_DIMS, points.shape[1])])
    return mean.astype(np.float32), axes.astype(np.float32)


def tree_coords(points: F32, axes: tuple[F32, F32], tree: int, rng: np.random.Generator) -> F32:
    """Split coordinates of tree ``tree``, one row per coordinate (coordinate j of point i at
    [j, i], as :func:`leaves` reads them): PCA coordinates, leading ones rotated after tree 0."""
    dims = axes[1].shape[1]
    by_axis: F32 = np.empty((dims, len(points)), np.float32)
    mixed = min(MIXED_DIMS, dims)
    rotation = None
    if tree > 0 and mixed > 1:
        rotation = np.linalg.qr(rng.standard_normal((mixed, mixed)))[0].astype(np.float32)
    step = rows_per_block(4 * points.shape[1])
    coords: F32 = np.empty((min(step, len(points)), dims), np.float32)
    for start in range(0, len(points), step):
        block = coords[: min(step, len(points) - start)]
        np.matmul(points[start : start + step] - axes[0], axes[1], out=block)
        if rotation is not None:
            block[:, :mixed] = np.matmul(block[:, :mixed], rotation)
        by_axis[:, start : start + step] = block.T
    return by_axis


def leaves(by_axis: F32, leaf: int) -> tuple[Ints, npt.NDArray[np.bool_]]:
    """Balanced kd-tree leaves as (C, L) point ids; padding slots repeat points, flagged False.
    Each level splits every segment at its median along its widest coordinate (one
    ``argpartition`` over equal-length rows: O(n) a level)."""
    n = by_axis.shape[1]
    flat = by_axis.reshape(-1)  # coordinate j of point i at j*n + i
    levels = max(0, int(np.ceil(np.log2(max(1.0, n / leaf)))))
    cells = 1 << levels
    length = -(-n // cells)
    pad = cells * length - n
    ids = np.concatenate([np.arange(n), np.arange(pad) % n])
    real = np.concatenate([np.ones(n, bool), np.zeros(pad, bool)])
    for level in range(levels):
        rows = ids.reshape(1 << level, -1)
        widest = np.argmax(
            _widths(by_axis, rows[:, :: max(1, rows.shape[1] // WIDTH_SAMPLE)]), axis=0
        )
        key = np.take(flat, widest[:, None] * n + rows)
        order = np.argpartition(key, rows.shape[1] // 2 - 1, axis=1)
        ids = np.take_along_axis(rows, order, axis=1).reshape(-1)
        real = np.take_along_axis(real.reshape(rows.shape), order, axis=1).reshape(-1)
    return ids.reshape(cells, length), real.reshape(cells, length)


def _widths(by_axis: F32, picks: Ints) -> F32:
    """(D, C) extent along each coordinate of each row of ``picks`` (C sampled point ids)."""
    out: F32 = np.empty((len(by_axis), len(picks)), np.float32)
    for axis, coordinate in enumerate(by_axis):
        sample = np.take(coordinate, picks)
        np.subtract(sample.max(axis=1), sample.min(axis=1), out=out[axis])
    return out


def leaf_neighbours(points: F32, ids: Ints, real: npt.NDArray[np.bool_], count: int) -> Ints:
    """For every point, its ``count`` nearest other points in its leaf, (n, count): scores
    x·y − |y|²/2, one BLAS product per leaf (on the one thread the fit allows)."""
    cells, length = ids.shape
    best = np.empty((cells, length, count), np.intp)
    step = rows_per_block(4 * length * max(length, points.shape[1]))
    block = np.empty((min(step, cells), length, length), np.float32)
    diag = np.arange(length)
    for start in range(0, cells, step):  # leaves gathered a block at a time, not all at once
        stop = min(cells, start + step)
        near = np.take(points, ids[start:stop], axis=0)
        half = 0.5 * np.einsum("cld,cld->cl", near, near)
        half[~real[start:stop]] = np.inf  # padding slots repeat points: never a neighbour
        scores = block[: stop - start]
        np.matmul(near, near.transpose(0, 2, 1), out=scores)  # a transposed view, no copy
        scores -= half[:, None, :]
        scores[:, diag, diag] = -np.inf
        for nearest in range(count):  # a few argmax passes: cheaper than one argpartition
            pick = np.argmax(scores, axis=2)
            best[start:stop, :, nearest] = pick
            if nearest + 1 < count:
                np.put_along_axis(scores, pick[..., None], -np.inf, axis=2)
    found = np.take_along_axis(ids, best.reshape(cells, -1), axis=1).reshape(cells, length, count)
    out = np.empty((len(points), count), np.intp)
    out[ids[real]] = found[real]
    return out


def neighbours(points: F32, axes: tuple[F32, F32], count: int, rng: np.random.Generator) -> Ints:
    """Approximate nearest neighbours: ``count`` per tree, pooled over TREES trees."""
    if len(points) < 2:
        return np.zeros((len(points), 1), np.intp)
    found = []
    for tree in range(TREES):
        ids, real = leaves(tree_coords(points, axes, tree, rng), max(LEAF_SIZE, 2 * count))
        found.append(leaf_neighbours(points, ids, real, min(count, ids.shape[1] - 1)))
    return np.concatenate(found, axis=1)


def cheapest_partner(means: F32, mass: F64, candidates: Ints) -> tuple[Ints, F64]:
    """Each cluster's candidate with the smallest Ward merge cost, and that cost."""
    costs = np.empty(candidates.shape, np.float64)
    for col in range(candidates.shape[1]):
        other = candidates[:, col]
        dist = distances(means, means, other)
        costs[:, col] = mass * mass[other] / (mass + mass[other]) * dist
    rows = np.arange(len(means))
    costs[candidates == rows[:, None]] = np.inf
    pick = np.argmin(costs, axis=1)
    partner, cost = candidates[rows, pick], costs[rows, pick]
    lonely = np.flatnonzero(~np.isfinite(cost))  # no other candidate: pair with the next id
    if len(lonely):
        partner[lonely] = (lonely + 1) % len(means)
        cost[lonely] = cheapest_partner(means, mass, partner[:, None])[1][lonely]
    return partner, cost


def pick_moves(partner: Ints, cost: F64, need: int) -> Ints:
    """Clusters that merge into their partner this round: cheap, and never into a mover.

    Only the ``need`` cheapest costs qualify. Of a mutual pair the higher index moves; a
    cluster may move into a partner that stays or that is the staying half of a pair.
    """
    ids = np.arange(len(partner))
    limit = np.partition(cost, need - 1)[need - 1]
    mover = (cost <= limit) & np.isfinite(cost)
    mutual = mover & (partner[partner] == ids)
    stays = mutual & (ids < partner)
    moves = (mutual & (ids > partner)) | (mover & ~mutual & (~mover[partner] | stays[partner]))
    chosen = np.flatnonzero(moves)
    if len(chosen) > need:
        chosen = chosen[np.argsort(cost[chosen], kind="stable")[:need]]
    if len(chosen) == 0:
        chosen = np.array([int(np.argmin(cost))], np.intp)
    return chosen


def merge(
    means: F32, mass: F64, movers: Ints, partner: Ints, *, own: bool
) -> tuple[F32, F64, Ints]:
    """Fold every mover into its partner: new means, masses and the old->new id map. Means the
    merging ``own`` (every round's after the first) are compacted in place."""
    target = np.arange(len(means))
    target[movers] = partner[movers]
    keep = np.ones(len(means), bool)
    keep[movers] = False
    new_id = (np.cumsum(keep) - 1)[target]
    hosts = np.unique(target[movers])  # only the clusters that grow get new means
    slot = np.searchsorted(hosts, target[movers])
    total = mass.copy()
    np.add.at(total, target[movers], mass[movers])
    kept = np.flatnonzero(keep)  # hosts are never movers: all kept
    if own:  # the compaction writes over the movers' rows: their sums come first
        grown = np.empty((len(hosts), means.shape[1]), np.float32)
        _fold_movers(
            means, mass, total, (hosts, movers, slot), out=grown, rows=np.arange(len(hosts))
        )
        out = compact_rows(means, kept)
        out[new_id[hosts]] = grown
    else:
        out = np.take(means, kept, axis=0)
        _fold_movers(means, mass, total, (hosts, movers, slot), out=out, rows=new_id[hosts])
    return out, total[keep], new_id


def _fold_movers(
    means: F32, mass: F64, total: F64, moves: tuple[Ints, Ints, Ints], *, out: F32, rows: Ints
) -> None:
    """Each host's weighted mean with the movers folded into it (``moves``: hosts, movers and
    each mover's host slot), written to ``out[rows]``: each host's movers added in their order,
    a block of hosts at a time (the same sums as all at once)."""
    hosts, movers, slot = moves
    by_host = np.argsort(slot, kind="stable")  # stable: each host's movers keep their order
    slots = slot[by_host]
    step = rows_per_block(8 * means.shape[1])
    taken = np.empty((min(step, len(movers)), means.shape[1]), np.float32)
    moved = np.empty(taken.shape, np.float64)  # both reused: one block's memory at a time
    for first in range(0, len(hosts), step):
        group = hosts[first : first + step]
        weighted = np.take(means, group, axis=0).astype(np.float64) * mass[group, None]
        low, high = np.searchsorted(slots, [first, first + len(group)])
        for start in range(int(low), int(high), step):
            block = movers[by_host[start : min(int(high), start + step)]]
            count = len(block)
            np.take(means, block, axis=0, out=taken[:count])
            np.multiply(taken[:count], mass[block, None], out=moved[:count])
            np.add.at(weighted, slots[start : start + count] - first, moved[:count])
        weighted /= total[group, None]
        out[rows[first : first + len(group)]] = weighted  # cast to float32 as it is stored


def assign(points: F32, centroids: F32, options: Ints, labels: Ints) -> Ints:
    """Nearest centroid among the options of each point's current centroid, in blocks."""
    step = rows_per_block(4 * options.shape[1] * points.shape[1])
    norms = np.einsum("kd,kd->k", centroids, centroids)
    out = np.empty_like(labels)
    for start in range(0, len(points), step):
        choice = np.take(options, labels[start : start + step], axis=0)
        candidates = np.take(centroids, choice, axis=0)
        dots = np.einsum("bd,bkd->bk", points[start : start + step], candidates)
        best = np.argmin(np.take(norms, choice) - 2.0 * dots, axis=1)
        out[start : start + step] = np.take_along_axis(choice, best[:, None], axis=1)[:, 0]
    return out


def update(points: F32, weights: F64, centroids: F32, labels: Ints) -> tuple[F32, Ints]:
    """Weighted means of the clusters; empty clusters move onto the worst-served points."""
    count = len(centroids)
    mass = np.bincount(labels, weights, minlength=count)
    means = _cluster_sums(points, weights, labels, count)
    filled = (mass > 0)[:, None]
    np.divide(means, mass[:, None], out=means, where=filled)
    out = centroids.copy()
    np.copyto(out, means, where=filled, casting="same_kind")
    del means
    empty = np.flatnonzero(~filled[:, 0])
    if len(empty):
        errors = distances(points, out, labels) * weights
        worst = np.argsort(-errors, kind="stable")[: len(empty)]
        worst = worst[errors[worst] > 0]
        out[empty[: len(worst)]] = points[worst]
        labels = labels.copy()
        labels[worst] = empty[: len(worst)]
    return out, labels


def _cluster_sums(points: F32, weights: F64, labels: Ints, count: int) -> F64:
    """(count, D) float64 sums of each cluster's weighted points, added point by point in order
    (the same bits for any block size), a transposed block of rows at a time."""
    sums = np.zeros((count, points.shape[1]), np.float64)
    step = rows_per_block(4 * points.shape[1])
    columns = np.empty((points.shape[1], min(step, len(points))), np.float32)  # reused
    for start in range(0, len(points), step):
        block = columns[:, : min(step, len(points) - start)]
        np.copyto(block, points[start : start + step].T)
        rows, scale = labels[start : start + step], weights[start : start + step]
        for coordinate, values in enumerate(block):
            np.add.at(sums[:, coordinate], rows, scale * values)
    return sums


def distances(rows: F32, others: F32, picks: Ints) -> F64:
    """Squared distance of every row to ``others[picks]``, in blocks through one buffer."""
    out: F64 = np.empty(len(rows), np.float64)
    step = rows_per_block(4 * rows.shape[1])
    buffer = np.empty((min(step, len(rows)), rows.shape[1]), np.float32)
    for start in range(0, len(rows), step):
        diff = buffer[: min(step, len(rows) - start)]
        np.take(others, picks[start : start + step], axis=0, out=diff)
        np.subtract(rows[start : start + step], diff, out=diff)
        out[start : start + step] = np.einsum("nd,nd->n", diff, diff)
    return out
