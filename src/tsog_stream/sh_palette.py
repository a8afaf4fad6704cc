"""The SH palette: vector quantisation of the f_rest vectors (SOG v2 ``shN``, spec §4.5, §6.2).

K palette vectors and one label per Gaussian, minimising the squared error: lower error than
splat-transform's 10 Lloyd iterations in a fraction of its time (docs/design/quantizers.md).
1. identical vectors collapse to weighted distinct rows; if those fit, the palette is exact;
2. Ward agglomeration in parallel rounds, each cluster's partner the cheapest of its
   approximate nearest neighbours (kd-tree leaves, ``palette_kernels``), until K are left;
3. Lloyd refinement, each vector comparing only its centroid's nearest centroids;
4. below quality 100 (``slack``), the entries merge by Ward cost while the view-dependent
   colour error they add stays within the slack.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from . import palette_kernels as kernels
from .constants import SH_PALETTE_MAX
from .errors import InputError
from .inplace import permute_rows

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.intp]
Labels = npt.NDArray[np.uint16] | npt.NDArray[np.uint32]
Progress = Callable[[float], None]

REFINE_CANDIDATES: Final = 4
"""Nearest centroids per tree a vector may move to during refinement."""
REFINE_TOLERANCE: Final = 1e-3
"""Refinement stops when a pass lowers the squared error by less than this fraction."""
ROUND_LEFT_FAR: Final = 0.6
"""Share of the clusters still to merge that a round leaves while at least twice k are left
(the progress's estimate; docs/design/quantizers.md, "The palette's constants")."""
ROUND_LEFT_NEAR: Final = 0.25
"""The share a round leaves near k; in between, blended by how many are left."""
PASSES_BASE: Final = 2.0
PASSES_PER_RATIO: Final = 0.5
"""Refinement passes the progress expects: PASSES_BASE plus this per vector per palette
entry, at least 2."""
REFINE_SETUP_PASSES: Final = 1.0
"""The refinement's own set-up in passes (the first pass reports it with its own)."""
SETUP_WEIGHT: Final = 0.65
"""Work before the first merging round per vector, against a round's per cluster."""
PASS_WEIGHT: Final = 0.21
"""Work of a refinement pass per vector, against a merging round's per cluster."""
PASS_ENTRY_WEIGHT: Final = 1.8
"""Work of a refinement pass per palette entry (see PASS_WEIGHT)."""
COARSEN_ROUND_LEAST: Final = 64
"""Merging a palette's entries within a slack stops after a round that merged fewer than
1/64 of them (later rounds merge a few dozen entries each, for a pass over all)."""
COARSEN_NEIGHBOURS: Final = 1
"""Nearest entries per tree each entry may merge with, found again only after
COARSEN_RESEARCH (else renamed round after round)."""
COARSEN_RESEARCH: Final = 4 / 3
"""The entries' neighbours are searched again once a quarter of them have merged since the
last search (renamed lists thin out as their entries merge)."""
COLOUR_PER_SQUARED: Final = 1.0 / (12.0 * math.pi)
"""Mean squared view-dependent colour error (each channel, over every view direction) per unit
of an f_rest vector's squared error: the basis is orthonormal over the sphere (1 / 4 pi) and
a vector holds three channels."""


def palette_size(n: int) -> int:
    """splat-transform's K for ``n`` Gaussians: the largest power of two ≤ n, capped at 65536
    (its formula min(64, 2^floor(log2(n/1024)))·1024 for every n ≥ 1)."""
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
) -> tuple[F32, Labels]:
    """Palette (M, D) float32 with M ≤ k rows and one label per vector (uint16 if M ≤ 65536).

    ``k`` defaults to :func:`palette_size`. Without ``slack``, M < k only when there are
    fewer than k distinct vectors; the palette is then exact. ``slack`` (colour units, 0..1)
    lets the RMS over vectors and view directions of the colour error the bands make grow by
    that much beyond the k-entry fit's: its entries then merge, cheapest first, while they stay
    within it. ``iterations`` bounds the refinement passes (splat-transform's
    ``--sh-iterations``). The result depends only on the input, ``seed`` and ``slack``; vectors
    passed without another reference are freed once their distinct rows are taken.
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
    unique, inverse, weights = kernels.unique_rows(data)
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
    they add (measured each round) stays within ``allowance``, and each old entry's new one
    (unused entries dropped). ``near``: each entry's candidates from the fit's last refinement
    pass (else searched here)."""
    counted = np.bincount(labels, weights, minlength=len(centroids)).astype(np.float64)
    used = np.flatnonzero(counted > 0)
    entry = np.zeros(len(centroids), np.intp)
    entry[used] = np.arange(len(used))
    means, mass = np.take(centroids, used, axis=0), counted[used]
    rng = np.random.default_rng(seed)
    axes = kernels.principal_axes(means, mass)
    if near is None:
        near = kernels.neighbours(means, axes, COARSEN_NEIGHBOURS, rng)
    else:  # the fit's last candidates: the nearest of each tree, renamed to the used entries
        near = entry[near[used][:, ::REFINE_CANDIDATES]]
    searched = len(means)
    left = allowance
    while len(means) > 1:
        merged = _round_within(means, mass, kernels.cheapest_partner(means, mass, near), left)
        if merged is None:
            break
        before = len(means)
        means, mass, new_id, added, kept = merged
        left -= added
        entry = new_id[entry]
        if (before - len(means)) * COARSEN_ROUND_LEAST < before:
            break
        if len(means) * COARSEN_RESEARCH < searched:
            near, searched = kernels.neighbours(means, axes, COARSEN_NEIGHBOURS, rng), len(means)
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
        movers = kernels.pick_moves(partner, cost, need)
        merged, merged_mass, new_id = kernels.merge(means, mass, movers, partner, own=False)
        added = float(np.dot(mass, kernels.distances(means, merged, new_id)))
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
    the palette's squared error and its entries' neighbours (:func:`_refine`); ``unique`` is
    reordered in place. On one BLAS thread (the caller's): thousands of small products, whose
    summation order (and so the palette) must not depend on the process."""
    rng = np.random.default_rng(seed)
    axes = kernels.principal_axes(unique, weights)
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


class _Work:
    """Progress of a fit as the share of its work done: a merging round costs one visit of each
    cluster it starts with, a refinement pass PASS_WEIGHT per vector and PASS_ENTRY_WEIGHT per
    entry, the set-up SETUP_WEIGHT per vector; the rounds and passes to come are estimated."""

    def __init__(self, points: int, k: int, passes: int, report: Progress) -> None:
        self._points, self._k, self._passes, self._report = points, k, passes, report
        self._pass = PASS_WEIGHT * points + PASS_ENTRY_WEIGHT * k
        self._done, self._refined, self._said = SETUP_WEIGHT * points, 0, 0.0

    def set_up(self) -> None:
        """The distinct rows and the axes are found: the fit's first report."""
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
    """Parallel Ward merging from one cluster per distinct point down to ``k`` clusters (nothing
    writes into ``points``); a round's arrays go as soon as it is done with them."""
    means, mass = points, weights
    labels: Ints | None = None  # each point its own cluster until the first round ends
    while len(means) > k:
        clusters = len(means)
        partner, cost = kernels.cheapest_partner(
            means, mass, kernels.neighbours(means, axes, 1, rng)
        )
        movers = kernels.pick_moves(partner, cost, len(means) - k)
        del cost
        means, mass, new_id = kernels.merge(means, mass, movers, partner, own=means is not points)
        del partner, movers
        labels = new_id if labels is None else new_id[labels]
        del new_id
        meter.merged(clusters, len(means) - k)
    if means.base is not None:  # compacted in place: let the first round's array go
        means = means.copy()
    return means, np.arange(len(points)) if labels is None else labels


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
    pass). The points are permuted in place into label order, so a block's candidate
    centroids are a few rows used over and over."""
    order = np.argsort(labels, kind="stable")
    permute_rows(points, order)
    weights, labels = weights[order], labels[order]
    errors = kernels.distances(points, centroids, labels)
    near: Ints | None = None
    for _ in range(iterations):
        near = kernels.neighbours(centroids, axes, REFINE_CANDIDATES, rng)
        options = np.concatenate([np.arange(len(centroids))[:, None], near], axis=1)
        assigned = kernels.assign(points, centroids, options, labels)
        moved, relabelled = kernels.update(points, weights, centroids, assigned)
        moved_errors = kernels.distances(points, moved, relabelled)
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
