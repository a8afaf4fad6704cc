"""The SH palette: vector quantisation of the f_rest vectors (SOG v2 ``shN``, spec §4.5, §6.2).

splat-transform runs 10 Lloyd iterations from K random Gaussians (single-threaded JS on a
CPU). We solve the same problem — K palette vectors and one label per Gaussian, minimising
the squared error — with a lower error in a small fraction of the time
(docs/design/quantizers.md):

1. identical vectors collapse to weighted unique rows; if those fit, the palette is exact;
2. Ward agglomeration in parallel rounds: every cluster finds its cheapest partner (Ward
   cost) among approximate nearest neighbours — brute force inside the leaves of two
   balanced kd-trees in PCA coordinates, one matrix product per leaf — and the cheapest
   merges that do not conflict are applied together, until K clusters remain;
3. Lloyd refinement where each vector compares only its centroid's nearest centroids,
   stopping early when the error improvement falls under a tolerance;
4. below quality 100 (``slack``), the fitted entries merge by Ward cost, cheapest first,
   while the view-dependent colour error they add stays within the slack.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from .constants import SH_PALETTE_MAX
from .errors import InputError
from .inplace import compact_rows, permute_rows

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.intp]
Labels = npt.NDArray[np.uint16] | npt.NDArray[np.uint32]
Progress = Callable[[float], None]

BLOCK_BYTES: Final = 2 << 20
"""Upper bound on the bytes of one block of products or distances: under glibc's mmap
threshold, so blocks reuse memory, and small enough to stay in cache (measured:
docs/design/quantizers.md, "The palette's constants").

Results do not depend on it, except the principal axes' covariance, whose block sums are
part of the palette's definition and use COVARIANCE_BLOCK_BYTES."""
COVARIANCE_BLOCK_BYTES: Final = 16 << 20
"""Rows of the points summed at a time into the covariance of the principal axes (a fixed
summation order: the palette, and so a chunk's bytes, depend on it)."""
LEAF_SIZE: Final = 128
"""Points per kd-tree leaf searched by brute force (chosen by measurement:
docs/design/quantizers.md)."""
TREES: Final = 2
"""Independent kd-trees whose leaf neighbours are pooled."""
SPLIT_DIMS: Final = 16
"""Leading principal axes the kd-trees split on."""
WIDTH_SAMPLE: Final = 64
"""Points per segment sampled to pick the widest coordinate."""
MIXED_DIMS: Final = 8
"""Leading axes randomly rotated for every tree after the first."""
REFINE_CANDIDATES: Final = 4
"""Nearest centroids per tree a vector may move to during refinement."""
REFINE_TOLERANCE: Final = 1e-3
"""Refinement stops when a pass lowers the squared error by less than this fraction."""
ROUND_LEFT_FAR: Final = 0.6
"""Share of the clusters still to merge that a merging round leaves while at least twice k
are left (measured: docs/design/quantizers.md, "The palette's constants")."""
ROUND_LEFT_NEAR: Final = 0.25
"""The share a round leaves near k; in between, blended by how many are
left: the progress expects the rounds still to come from these two."""
PASSES_BASE: Final = 2.0
PASSES_PER_RATIO: Final = 0.5
"""Refinement passes the progress expects before the tolerance stops them: PASSES_BASE plus
this per vector per palette entry, at least 2 (fitted to measured fits)."""
REFINE_SETUP_PASSES: Final = 1.0
"""The refinement's own set-up (the vectors sorted by label, their errors, their columns)
in passes: the first pass reports it with its own."""
SETUP_WEIGHT: Final = 0.65
"""Work before the first merging round (distinct rows, principal axes) per vector, against a
round's per cluster (measured)."""
PASS_WEIGHT: Final = 0.21
"""Work of a refinement pass per vector, against a merging round's per cluster; with
PASS_ENTRY_WEIGHT per palette entry (each pass finds the entries' neighbours), fitted to
measured passes."""
PASS_ENTRY_WEIGHT: Final = 1.8
"""Work of a refinement pass per palette entry (see PASS_WEIGHT)."""
COARSEN_ROUND_LEAST: Final = 64
"""Merging a palette's entries within a slack stops after a round that merged fewer than
1/64 of them: later rounds merge a few dozen entries each, for a pass over all."""
COARSEN_NEIGHBOURS: Final = 1
"""Nearest entries per tree each entry may merge with: found once, then renamed round after
round, the first ones those of the fit's last refinement pass (a search every round costs
more than the few entries it saves; more neighbours keep more entries)."""
COARSEN_RESEARCH: Final = 4 / 3
"""The entries' neighbours are searched again once a quarter of them have merged since the
last search: renamed lists thin out as their entries merge, and never searched again the
merging stops with most of the slack unspent."""
COLOUR_PER_SQUARED: Final = 1.0 / (12.0 * math.pi)
"""Mean squared view-dependent colour error (each channel, over every view direction) per unit
of an f_rest vector's squared error: the bands' basis is orthonormal over the sphere, so each
coefficient's error adds its square over 4 pi to the mean over directions, and a vector holds
three channels' coefficients."""


def palette_size(n: int) -> int:
    """splat-transform's K for ``n`` Gaussians: the largest power of two ≤ n, capped at 65536.

    Its formula min(64, 2^floor(log2(n/1024)))·1024 equals this for every n ≥ 1 (also below
    1024, e.g. 500 -> 256), so K is always in [1, n].
    """
    if n < 1:
        raise InputError(f"palette size needs at least one Gaussian, got n={n}")
    return min(SH_PALETTE_MAX, 1 << (int(n).bit_length() - 1))


def fit_palette(
    vectors: npt.ArrayLike,
    k: int | None = None,
    *,
    seed: int = 0,
    iterations: int = 10,
    progress: Progress | None = None,
    slack: float = 0.0,
    given_up: bool = False,
) -> tuple[F32, Labels]:
    """Palette (M, D) float32 with M ≤ k rows and one label per vector (uint16 if M ≤ 65536).

    ``k`` defaults to :func:`palette_size`. Without ``slack``, M < k only when there are
    fewer than k distinct vectors; the palette is then exact. ``slack`` (colour units, 0..1)
    lets the RMS over vectors and view directions of the colour error the bands make grow by
    that much beyond the k-entry fit's: its entries then merge, cheapest first, while they stay
    within it (:func:`_coarsened`). ``iterations`` bounds the refinement passes (like
    splat-transform's ``--sh-iterations``). The result depends only on the input, ``seed`` and
    ``slack``. The fit reads the distinct rows only: vectors passed without a reference kept
    elsewhere (``fit_palette(make_vectors())``) are freed before it starts. ``given_up``: the
    caller is done with ``vectors`` (float32, C-contiguous), so the fit keeps its distinct rows
    in their memory, written over, instead of a copy beside them.
    """
    data = _as_vectors(vectors)
    del vectors
    target = palette_size(len(data)) if k is None else int(k)
    if target < 1:
        raise InputError(f"palette size k must be at least 1, got {k}")
    if iterations < 0:
        raise InputError(f"iterations must be >= 0, got {iterations}")
    if not slack >= 0.0:
        raise InputError(f"palette slack must be >= 0, got {slack}")
    report = progress or (lambda _fraction: None)
    unique, inverse, weights = _unique_rows(data, in_place=given_up)
    del data
    with threadpool_limits(limits=1, user_api="blas"):
        near: Ints | None = None
        if len(unique) <= target:
            centroids, labels, error = unique, np.arange(len(unique)), 0.0
        else:
            centroids, labels, error, near = _fit(
                unique, weights, target, seed=seed, iterations=iterations, report=report
            )
        entries = len(centroids)
        if slack > 0.0 and entries > 1:
            allowance = _added_allowance(error, float(weights.sum()), slack)
            centroids, entry = _coarsened(
                centroids, labels, weights, allowance, seed=seed, near=near
            )
            labels = entry[labels]
    report(1.0)
    return centroids, _labels(labels[inverse], entries)


def _added_allowance(error: float, total: float, slack: float) -> float:
    """Squared error (summed over ``total`` weighted vectors) that merging a palette's entries
    may add to its ``error`` so their RMS colour error grows by at most ``slack``."""
    rms = math.sqrt(error / total * COLOUR_PER_SQUARED)
    return total * ((rms + slack) ** 2 - rms**2) / COLOUR_PER_SQUARED


def _coarsened(
    centroids: F32,
    labels: Ints,
    weights: F64,
    allowance: float,
    *,
    seed: int = 0,
    near: Ints | None = None,
) -> tuple[F32, Ints]:
    """The palette's entries merged in Ward rounds, cheapest first, while the squared error
    they add stays within ``allowance``, and each old entry's new one (unused entries are
    dropped). Entries that are their vectors' weighted means (a fit's, or distinct vectors)
    add exactly their Ward cost when merged; each round's addition is measured, and a round
    that would overrun is retried with half the merges. Rounds stop once one merges under
    1/COARSEN_ROUND_LEAST of the entries. ``near``: each entry's candidates from the fit's
    last refinement pass (its first per tree serve; else they are searched here)."""
    counted = np.bincount(labels, weights, minlength=len(centroids)).astype(np.float64)
    used = np.flatnonzero(counted > 0)
    entry = np.zeros(len(centroids), np.intp)
    entry[used] = np.arange(len(used))
    means, mass = np.take(centroids, used, axis=0), counted[used]
    rng = np.random.default_rng(seed)
    axes = _principal_axes(means, mass)
    if near is None:
        near = _neighbours(means, axes, COARSEN_NEIGHBOURS, rng)
    else:  # the fit's last candidates: the nearest of each tree, renamed to the used entries
        near = entry[near[used][:, ::REFINE_CANDIDATES]]
    searched = len(means)
    left = allowance
    while len(means) > 1:
        merged = _round_within(means, mass, _cheapest_partner(means, mass, near), left)
        if merged is None:
            break
        before = len(means)
        means, mass, new_id, added, kept = merged
        left -= added
        entry = new_id[entry]
        if (before - len(means)) * COARSEN_ROUND_LEAST < before:
            break
        if len(means) * COARSEN_RESEARCH < searched:
            near, searched = _neighbours(means, axes, COARSEN_NEIGHBOURS, rng), len(means)
        else:  # the neighbours found before, renamed
            near = new_id[near[kept]]
    return means, entry


def _round_within(
    means: F32, mass: F64, partners: tuple[Ints, F64], left: float
) -> tuple[F32, F64, Ints, float, npt.NDArray[np.bool_]] | None:
    """One merging round whose measured added error is within ``left`` (the merges its
    cheapest costs afford, halved until it fits): the new means and masses, each old entry's
    new one, the error added and which old entries were kept; None when not even one fits."""
    partner, cost = partners
    need = min(_affordable(partner, cost, left), len(means) - 1)
    while need > 0:
        movers = _pick_moves(partner, cost, need)
        merged, merged_mass, new_id = _merge(means, mass, movers, partner, own=False)
        added = float(np.dot(mass, _distances(means, merged, new_id)))
        if added <= left:
            kept = np.ones(len(means), np.bool_)
            kept[movers] = False
            return merged, merged_mass, new_id, added, kept
        need //= 2
    return None


def _affordable(partner: Ints, cost: F64, left: float) -> int:
    """How many of the cheapest finite costs add up to at most ``left``, a mutual pair's
    counted once (it is one merge)."""
    ids = np.arange(len(partner))
    once = np.isfinite(cost) & ~((partner[partner] == ids) & (ids > partner))
    ascending = np.sort(cost[once])
    return int(np.searchsorted(np.cumsum(ascending), left, side="right"))


def _fit(
    unique: F32, weights: F64, target: int, *, seed: int, iterations: int, report: Progress
) -> tuple[F32, Ints, float, Ints | None]:
    """Agglomeration then refinement of more than ``target`` distinct weighted vectors, with
    the palette's squared error (weighted sum) and its entries' neighbours (:func:`_refine`),
    on one BLAS thread (the caller's): the leaf products are thousands of small matrix
    products, which a multi-threaded BLAS ran 60x slower on a busy machine, and one thread
    keeps every product's summation order (and so the palette) the same in any process.
    ``unique`` is reordered in place (by :func:`_refine`)."""
    rng = np.random.default_rng(seed)
    axes = _principal_axes(unique, weights)
    expected = PASSES_BASE + PASSES_PER_RATIO * len(unique) / target
    passes = min(iterations, max(2, int(expected)))
    meter = _Work(len(unique), target, passes, report)
    meter.set_up()
    centroids, labels = _agglomerate(unique, weights, target, axes=axes, rng=rng, meter=meter)
    return _refine(
        unique, weights, centroids, labels, axes=axes, iterations=iterations, rng=rng, meter=meter
    )


def palette_mse(vectors: npt.ArrayLike, centroids: npt.ArrayLike, labels: npt.ArrayLike) -> float:
    """Mean over vectors of the squared distance to their assigned palette vector."""
    data = np.asarray(vectors, dtype=np.float64)
    diff = data - np.asarray(centroids, dtype=np.float64)[np.asarray(labels, dtype=np.intp)]
    return float(np.einsum("ij,ij->", diff, diff) / max(1, len(data)))


def _as_vectors(vectors: npt.ArrayLike) -> F32:
    """C-contiguous float32 (N, D) with N, D ≥ 1 and finite values, or InputError."""
    data = np.asarray(vectors)
    if data.ndim != 2 or data.shape[0] == 0 or data.shape[1] == 0:
        raise InputError(f"SH vectors must be a non-empty (N, D) array, got shape {data.shape}")
    data = np.ascontiguousarray(data, dtype=np.float32)
    if not np.all(np.isfinite(data)):
        raise InputError("SH vectors must be finite (found NaN or infinity)")
    return data


def _labels(labels: Ints, count: int) -> Labels:
    """Smallest unsigned label type that addresses ``count`` palette entries."""
    if count <= SH_PALETTE_MAX:
        return labels.astype(np.uint16)
    return labels.astype(np.uint32)


def _unique_rows(data: F32, *, in_place: bool = False) -> tuple[F32, Ints, F64]:
    """Distinct rows (byte-wise), the row of each input vector, and multiplicities;
    ``in_place``: the distinct rows are kept in ``data``'s memory, a view of its front, not a
    copy (a copy would hold the vectors twice).

    Rows are told apart by a 64-bit hash of their bytes, then checked against the row each
    was matched to; only when two distinct rows share a hash are the rows themselves sorted
    (sorting 833k rows of 180 bytes took 1.8 s, hashing, sorting and checking them 0.6 s).
    """
    _, first, inverse, counts = np.unique(
        _row_hashes(data), return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1).astype(np.intp)
    if not _each_matches(data, first, inverse):  # a collision: sort the rows themselves
        rows = data.view(np.dtype((np.void, data.dtype.itemsize * data.shape[1]))).reshape(-1)
        _, first, inverse, counts = np.unique(
            rows, return_index=True, return_inverse=True, return_counts=True
        )
        inverse = inverse.reshape(-1).astype(np.intp)
    return _gathered(data, first, in_place), inverse, counts.astype(np.float64)


def _gathered(data: F32, first: Ints, in_place: bool) -> F32:
    """``data[first]`` (distinct rows in the hashes' order), or with ``in_place`` the same
    rows in ``data``'s own memory: moved to the front in the order they occur (no row moves
    backwards), then put in the hashes' order a block at a time. The fit is the same either
    way; fitted in the order the rows occur it was 0.6-0.9 % worse (squared error on the alti
    and fruit vectors, four seeds)."""
    if not in_place:
        return np.take(data, first, axis=0)
    by_first = np.argsort(first)
    rows = compact_rows(data, first[by_first])
    place = np.empty_like(by_first)
    place[by_first] = np.arange(len(by_first))
    permute_rows(rows, place)
    return rows


def _each_matches(data: F32, first: Ints, inverse: Ints) -> bool:
    """Whether every row equals the row its hash matched it to, compared a block at a time
    (the matched rows gathered at once would be another copy of the vectors)."""
    step = _rows_per_block(4 * data.shape[1])
    for start in range(0, len(data), step):
        rows = np.take(first, inverse[start : start + step])
        if not np.array_equal(np.take(data, rows, axis=0), data[start : start + step]):
            return False  # np.take: 10x fancy indexing on rows this wide
    return True


def _rows_per_block(row_bytes: int, block_bytes: int | None = None) -> int:
    """Rows of ``row_bytes`` each that a block of ``block_bytes`` (BLOCK_BYTES) holds (at
    least one)."""
    return max(1, (BLOCK_BYTES if block_bytes is None else block_bytes) // max(1, row_bytes))


HASH_MULTIPLIER: Final = np.uint64(0x9E3779B97F4A7C15)
"""Odd 64-bit multiplier of the row hash (2^64 over the golden ratio)."""


def _row_hashes(data: F32) -> npt.NDArray[np.uint64]:
    """A 64-bit hash of each row's bytes: h = h * HASH_MULTIPLIER + word, word by word, each
    step mixed by a xor-shift (wrapping arithmetic)."""
    words = data.view(np.uint32)
    hashes = np.zeros(len(data), np.uint64)
    for column in words.T:
        hashes *= HASH_MULTIPLIER
        hashes += column
        hashes ^= hashes >> np.uint64(29)
    return hashes


def _principal_axes(points: F32, weights: F64) -> tuple[F32, F32]:
    """Weighted mean and the leading principal axes (D, ≤ SPLIT_DIMS) of the points.

    Sums by ``einsum``, not BLAS: a multi-threaded BLAS sums in an order that depends on its
    thread count, so the palette (and the chunk's bytes) differed between a process with one
    BLAS thread (a Dask worker) and one with two. The covariance is summed a block of rows at
    a time (the centred points whole, and weighted, were twice the points).
    """
    mean = np.einsum("n,nd->d", weights, points) / weights.sum()  # float64 sums, no copy
    centre = mean.astype(np.float32)
    cov = np.zeros((points.shape[1], points.shape[1]), np.float64)
    step = _rows_per_block(4 * points.shape[1], COVARIANCE_BLOCK_BYTES)
    for start in range(0, len(points), step):
        centred = points[start : start + step] - centre
        weighted = centred * weights[start : start + step, None].astype(np.float32)
        cov += np.einsum("nd,ne->de", weighted, centred)
    _, vecs = np.linalg.eigh(cov)
    axes = np.ascontiguousarray(vecs[:, ::-1][:, : min(SPLIT_DIMS, points.shape[1])])
    return mean.astype(np.float32), axes.astype(np.float32)


def _tree_coords(points: F32, axes: tuple[F32, F32], tree: int, rng: np.random.Generator) -> F32:
    """Split coordinates of tree ``tree``, one row per coordinate (coordinate j of point i at
    [j, i]): PCA coordinates, leading ones rotated after tree 0.

    Projected (and rotated) a block of rows at a time and written transposed: the centred
    points whole were as large as the points (the fit's peak),
    and the leaves read the coordinates by axis, which took a transposed copy of them."""
    dims = axes[1].shape[1]
    by_axis: F32 = np.empty((dims, len(points)), np.float32)
    mixed = min(MIXED_DIMS, dims)
    rotation = None
    if tree > 0 and mixed > 1:
        rotation = np.linalg.qr(rng.standard_normal((mixed, mixed)))[0].astype(np.float32)
    step = _rows_per_block(4 * points.shape[1])
    coords: F32 = np.empty((min(step, len(points)), dims), np.float32)
    for start in range(0, len(points), step):
        block = coords[: min(step, len(points) - start)]
        np.matmul(points[start : start + step] - axes[0], axes[1], out=block)
        if rotation is not None:
            block[:, :mixed] = np.matmul(block[:, :mixed], rotation)
        by_axis[:, start : start + step] = block.T
    return by_axis


def _leaves(by_axis: F32, leaf: int) -> tuple[Ints, npt.NDArray[np.bool_]]:
    """Balanced kd-tree leaves as (C, L) point ids; padding slots repeat points, flagged False.

    ``by_axis``: the points' coordinates, one row per coordinate. Each level splits every
    segment at its median along its widest coordinate with one ``argpartition`` over
    equal-length rows, so a level costs O(n). Keys are gathered by ``np.take``: fancy
    indexing took 2-3x as long.
    """
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
    """(D, C) extent along each coordinate of each row of ``picks`` (C sampled point ids),
    a coordinate at a time (all at once, the samples would be D times larger)."""
    out: F32 = np.empty((len(by_axis), len(picks)), np.float32)
    for axis, coordinate in enumerate(by_axis):
        sample = np.take(coordinate, picks)
        np.subtract(sample.max(axis=1), sample.min(axis=1), out=out[axis])
    return out


def _leaf_neighbours(points: F32, ids: Ints, real: npt.NDArray[np.bool_], count: int) -> Ints:
    """For every point, its ``count`` nearest other points in its leaf, (n, count).

    Scores x·y − |y|²/2: one product per leaf, by BLAS on the one thread ``_fit`` allows
    (faster than ``einsum``'s loops; multi-threaded, thousands of these small products
    stalled on a busy machine), less half the squared norms. The leaves' rows are gathered
    by ``np.take`` (faster than fancy indexing on rows this wide).
    """
    cells, length = ids.shape
    best = np.empty((cells, length, count), np.intp)
    step = _rows_per_block(4 * length * max(length, points.shape[1]))
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


def _neighbours(points: F32, axes: tuple[F32, F32], count: int, rng: np.random.Generator) -> Ints:
    """Approximate nearest neighbours: ``count`` per tree, pooled over TREES trees."""
    if len(points) < 2:
        return np.zeros((len(points), 1), np.intp)
    found = []
    for tree in range(TREES):
        ids, real = _leaves(_tree_coords(points, axes, tree, rng), max(LEAF_SIZE, 2 * count))
        found.append(_leaf_neighbours(points, ids, real, min(count, ids.shape[1] - 1)))
    return np.concatenate(found, axis=1)


class _Work:
    """Progress of a fit as the share of its work done: a merging round costs about one visit
    of each cluster it starts with, a refinement pass PASS_WEIGHT of one per vector and
    PASS_ENTRY_WEIGHT per palette entry, what comes before the first round SETUP_WEIGHT of
    one per vector. Rounds merge most of what is left early and a few hundred near k, each
    still a full pass, so counting merged clusters ran ahead of the time (0.47 reported at
    0.30 of a 200k fit); the rounds still to come are estimated from ROUND_LEFT_FAR and
    ROUND_LEFT_NEAR, the passes from PASSES_BASE and PASSES_PER_RATIO."""

    def __init__(self, points: int, k: int, passes: int, report: Progress) -> None:
        self._points, self._k, self._passes, self._report = points, k, passes, report
        self._pass = PASS_WEIGHT * points + PASS_ENTRY_WEIGHT * k
        self._done, self._refined, self._said = SETUP_WEIGHT * points, 0, 0.0

    def set_up(self) -> None:
        """The distinct rows and the axes are found: the fit's first report, before the first
        merging round (the first ETA of a 5M scene waited ~3 s more for that round)."""
        self._say(self._rounds_to_come(self._points - self._k) + self._refinement())

    def merged(self, clusters: int, left: int) -> None:
        """A round over ``clusters`` ended with ``left`` clusters above k still to merge."""
        self._done += clusters
        self._say(self._rounds_to_come(left) + self._refinement())

    def refined(self) -> None:
        """A refinement pass over the points ended (the first with the refinement's set-up)."""
        first = REFINE_SETUP_PASSES if self._refined == 0 else 0.0
        self._done += (1.0 + first) * self._pass
        self._refined += 1
        self._say(max(1, self._passes - self._refined) * self._pass)

    def _refinement(self) -> float:
        """Work of the refinement to come: its set-up and the passes expected."""
        return (REFINE_SETUP_PASSES + self._passes) * self._pass

    def _rounds_to_come(self, left: int) -> float:
        """Work of the rounds that merge ``left`` more clusters: each leaves a share of them,
        ROUND_LEFT_FAR while at least twice k are left, falling to ROUND_LEFT_NEAR near k."""
        work, rounds = 0.0, 0
        while left >= 1 and rounds < 64:
            work += self._k + left
            far = min(1.0, left / (2 * self._k))
            left = int(left * (ROUND_LEFT_NEAR + (ROUND_LEFT_FAR - ROUND_LEFT_NEAR) * far))
            rounds += 1
        return work

    def _say(self, remaining: float) -> None:
        """Report done / (done + remaining), never less than before and below 1 until the end."""
        self._said = max(self._said, min(0.99, self._done / (self._done + remaining)))
        self._report(self._said)


def _agglomerate(
    points: F32,
    weights: F64,
    k: int,
    *,
    axes: tuple[F32, F32],
    rng: np.random.Generator,
    meter: _Work,
) -> tuple[F32, Ints]:
    """Parallel Ward merging from one cluster per unique point down to ``k`` clusters (the
    points and their weights are the first round's means and masses: nothing writes into
    them). A round's arrays of every cluster go as soon as it is done with them: the first
    round's, a point's each, would be held beside the second's."""
    means, mass = points, weights
    labels: Ints | None = None  # each point its own cluster until the first round ends
    while len(means) > k:
        clusters = len(means)
        partner, cost = _cheapest_partner(means, mass, _neighbours(means, axes, 1, rng))
        movers = _pick_moves(partner, cost, len(means) - k)
        del cost
        means, mass, new_id = _merge(means, mass, movers, partner, own=means is not points)
        del partner, movers
        labels = new_id if labels is None else new_id[labels]
        del new_id
        meter.merged(clusters, len(means) - k)
    if means.base is not None:  # compacted in place: let the first round's array go
        means = means.copy()
    return means, np.arange(len(points)) if labels is None else labels


def _cheapest_partner(means: F32, mass: F64, candidates: Ints) -> tuple[Ints, F64]:
    """Each cluster's candidate with the smallest Ward merge cost, and that cost."""
    costs = np.empty(candidates.shape, np.float64)
    for col in range(candidates.shape[1]):
        other = candidates[:, col]
        dist = _distances(means, means, other)
        costs[:, col] = mass * mass[other] / (mass + mass[other]) * dist
    rows = np.arange(len(means))
    costs[candidates == rows[:, None]] = np.inf
    pick = np.argmin(costs, axis=1)
    partner, cost = candidates[rows, pick], costs[rows, pick]
    lonely = np.flatnonzero(~np.isfinite(cost))  # no other candidate: pair with the next id
    if len(lonely):
        partner[lonely] = (lonely + 1) % len(means)
        cost[lonely] = _cheapest_partner(means, mass, partner[:, None])[1][lonely]
    return partner, cost


def _pick_moves(partner: Ints, cost: F64, need: int) -> Ints:
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


def _merge(
    means: F32, mass: F64, movers: Ints, partner: Ints, *, own: bool
) -> tuple[F32, F64, Ints]:
    """Fold every mover into its partner; returns new means, masses and the old->new id map.
    Means the merging ``own`` (every round's after the first) are compacted in place, not
    copied; the first round's kept means are copied first and the grown ones written into
    them (:func:`_fold_movers`), without a float64 array of every host beside them."""
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
    each mover's host slot), written to ``out[rows]``, a block of hosts at a time. Each host's
    movers are added in their order, as all at once (the same sums, without a float64 copy
    of every mover, nor of every host)."""
    hosts, movers, slot = moves
    by_host = np.argsort(slot, kind="stable")  # stable: each host's movers keep their order
    slots = slot[by_host]
    step = _rows_per_block(8 * means.shape[1])
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


def _refine(
    points: F32,
    weights: F64,
    centroids: F32,
    labels: Ints,
    *,
    axes: tuple[F32, F32],
    iterations: int,
    rng: np.random.Generator,
    meter: _Work,
) -> tuple[F32, Ints, float, Ints | None]:
    """Lloyd passes restricted to each centroid's nearest centroids; stop when gains stall.
    Returns the centroids, each point's label, the weighted squared error and the last
    pass's nearest centroids of each centroid (REFINE_CANDIDATES per tree; None without a
    pass), which the palette's merging starts from.

    The points are visited in label order, so a block's candidate centroids are a few rows
    used over and over (gathered at random they took most of a pass).
    They are put in that order in place, a block at a time (``points`` is the fit's own array
    of distinct rows): a sorted copy would hold them twice, as would
    a transposed copy for the cluster sums (:func:`_update` transposes a block at a time).
    """
    order = np.argsort(labels, kind="stable")
    permute_rows(points, order)
    weights, labels = weights[order], labels[order]
    errors = _errors(points, centroids, labels)
    near: Ints | None = None
    for _ in range(iterations):
        near = _neighbours(centroids, axes, REFINE_CANDIDATES, rng)
        options = np.concatenate([np.arange(len(centroids))[:, None], near], axis=1)
        assigned = _assign(points, centroids, options, labels)
        moved, relabelled = _update(points, weights, centroids, assigned)
        moved_errors = _errors(points, moved, relabelled)
        meter.refined()
        before = float(np.einsum("n,n->", weights, errors))
        after = float(np.einsum("n,n->", weights, moved_errors))
        if after > before:  # float32 rounding can undo a tiny gain: keep the better palette
            break
        centroids, labels, errors = moved, relabelled, moved_errors
        if before - after <= REFINE_TOLERANCE * before:
            break
    unsorted = np.empty_like(labels)
    unsorted[order] = labels
    return centroids, unsorted, float(np.einsum("n,n->", weights, errors)), near


def _assign(points: F32, centroids: F32, options: Ints, labels: Ints) -> Ints:
    """Nearest centroid among the options of each point's current centroid, in blocks."""
    step = _rows_per_block(4 * options.shape[1] * points.shape[1])
    norms = np.einsum("kd,kd->k", centroids, centroids)
    out = np.empty_like(labels)
    for start in range(0, len(points), step):
        choice = np.take(options, labels[start : start + step], axis=0)
        candidates = np.take(centroids, choice, axis=0)  # np.take: wide rows, 3-4x fancy's speed
        dots = np.einsum("bd,bkd->bk", points[start : start + step], candidates)
        best = np.argmin(np.take(norms, choice) - 2.0 * dots, axis=1)
        out[start : start + step] = np.take_along_axis(choice, best[:, None], axis=1)[:, 0]
    return out


def _update(points: F32, weights: F64, centroids: F32, labels: Ints) -> tuple[F32, Ints]:
    """Weighted means of the clusters; empty clusters move onto the worst-served points.

    The sums are taken a block of rows at a time, each block transposed so every coordinate is
    contiguous, and divided in place (:func:`_cluster_sums`): a transposed copy of all the
    points, a sum array per coordinate stacked and the filled rows' copies were the fit's
    peak, about twice the points beside them."""
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
        errors = _errors(points, out, labels) * weights
        worst = np.argsort(-errors, kind="stable")[: len(empty)]
        worst = worst[errors[worst] > 0]
        out[empty[: len(worst)]] = points[worst]
        labels = labels.copy()
        labels[worst] = empty[: len(worst)]
    return out, labels


def _cluster_sums(points: F32, weights: F64, labels: Ints, count: int) -> F64:
    """(count, D) float64 sums of each cluster's weighted points, added point by point in
    order (``np.add.at`` onto a zeroed array adds as ``np.bincount`` does: the same bits for
    any block size)."""
    sums = np.zeros((count, points.shape[1]), np.float64)
    step = _rows_per_block(4 * points.shape[1])
    columns = np.empty((points.shape[1], min(step, len(points))), np.float32)  # reused
    for start in range(0, len(points), step):
        block = columns[:, : min(step, len(points) - start)]
        np.copyto(block, points[start : start + step].T)
        rows, scale = labels[start : start + step], weights[start : start + step]
        for coordinate, values in enumerate(block):
            np.add.at(sums[:, coordinate], rows, scale * values)
    return sums


def _errors(points: F32, centroids: F32, labels: Ints) -> F64:
    """Squared distance of every point to its assigned centroid."""
    return _distances(points, centroids, labels)


def _distances(rows: F32, others: F32, picks: Ints) -> F64:
    """Squared distance of every row to ``others[picks]``, in blocks through one buffer: fresh
    temporaries faulted in new pages on every call, and the block before was still held while
    the next was made (three blocks at once)."""
    out: F64 = np.empty(len(rows), np.float64)
    step = _rows_per_block(4 * rows.shape[1])
    buffer = np.empty((min(step, len(rows)), rows.shape[1]), np.float32)
    for start in range(0, len(rows), step):
        diff = buffer[: min(step, len(rows) - start)]
        np.take(others, picks[start : start + step], axis=0, out=diff)
        np.subtract(rows[start : start + step], diff, out=diff)
        out[start : start + step] = np.einsum("nd,nd->n", diff, diff)
    return out
