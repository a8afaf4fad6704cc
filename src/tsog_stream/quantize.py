"""256-entry scalar codebooks of SOG v2 (scales, sh0, shN), after splat-transform's quantizer.

:func:`dp_codebook` is the reference algorithm (SOG v2 notes §6.1, docs/design/quantizers.md
§1); :func:`build_codebook` keeps its slots and ±inf sentinels and refines it by 1-D Lloyd
passes (never a larger error; optionally weighted); :func:`assign_codebook` maps values to
their nearest entry.
"""

from __future__ import annotations

from typing import Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from .columns import row_blocks, rows_per_block
from .constants import CODEBOOK_SIZE, INFINITY_SENTINEL_OFFSET
from .errors import InputError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
Span = tuple[float, float]
"""The least and the greatest of the usable samples."""

HIST_BINS: Final = 1024
"""Upper bound on histogram bins (splat-transform's H)."""
DENSITY_ALPHA: Final = 0.5
"""Bin weight = count ** DENSITY_ALPHA."""
BETA_MIN: Final = 0.5
BETA_MAX: Final = 0.999
REFINE_PASSES: Final = 200
"""Upper bound on 1-D Lloyd passes in :func:`build_codebook`; it stops when nothing moves."""
VALUE_BYTES: Final = 32
"""Bytes of temporaries one value's blocked arithmetic holds (its float64 and about three
more): a block (``columns.rows_per_block``) bounds a codebook's memory."""


def dp_codebook(samples: npt.ArrayLike) -> F32:
    """The reference codebook (histogram + DP), unrefined."""
    return _codebook(samples, refine=False)


def build_codebook(samples: npt.ArrayLike, weights: npt.ArrayLike | None = None) -> F32:
    """A 256-entry ascending float32 codebook for the pooled ``samples`` (any shape).

    Same slots and sentinels as :func:`dp_codebook`, never a larger mean squared error; empty
    or all-NaN input gives zeros. ``weights`` (one per sample, >= 0) weigh each sample's
    error; at most as many distinct values as slots are stored exactly either way.
    """
    return _codebook(samples, refine=True, weights=weights)


def assign_codebook(values: npt.ArrayLike, codebook: npt.ArrayLike) -> U8:
    """Index of the nearest codebook entry for every value (same shape as ``values``).

    As splat-transform: a value on a midpoint goes up, -inf to 0, +inf and NaN to the last.
    """
    table = np.asarray(codebook)
    if table.ndim != 1 or not 1 <= table.size <= CODEBOOK_SIZE:
        raise InputError(f"codebook must be 1-D with 1..{CODEBOOK_SIZE} entries, got {table.shape}")
    table = table.astype(np.float64)
    if not np.all(np.isfinite(table)) or np.any(np.diff(table) < 0):
        raise InputError("codebook must hold finite values in ascending order")
    mids = (table[:-1] + table[1:]) * 0.5
    data = np.asarray(values)
    flat = data.reshape(-1)
    bins = _label_bins(flat, mids) if flat.size >= BINNED_FROM else None
    labels = np.empty(flat.size, np.uint8)
    for rows in row_blocks(flat.size, VALUE_BYTES):  # float64 a block at a time
        block = np.asarray(flat[rows], dtype=np.float64)
        if bins is None:
            labels[rows] = np.searchsorted(mids, block, side="right")
        else:
            labels[rows] = _binned_labels(block, mids, bins)
    return labels.reshape(data.shape)


BINNED_FROM: Final = 1 << 16
"""Values from which :func:`assign_codebook` looks labels up by bin (quicker than searching)."""
LABEL_BINS: Final = 1 << 16
BIN_MARGIN: Final = 2
"""Bins on each side a value's computed bin is trusted within (its rounding moves it far less)."""


class _LabelBins(NamedTuple):
    """Equal bins over the values' finite range and the labels at each bin's two ends."""

    low: float
    width: float
    first: U8
    last: U8


def _label_bins(values: npt.NDArray[Any], mids: F64) -> _LabelBins | None:
    """The bins :func:`_binned_labels` reads; None where none can be laid (no finite value,
    or a range too narrow for its magnitude)."""
    low, high = np.inf, -np.inf
    for rows in row_blocks(values.size, VALUE_BYTES):
        block = np.asarray(values[rows], dtype=np.float64)
        block = block[np.isfinite(block)]
        if block.size:
            low, high = min(low, float(block.min())), max(high, float(block.max()))
    width = (high - low) / LABEL_BINS
    if not (np.isfinite(width) and width > 1e-9 * max(abs(low), abs(high))):
        return None
    edges = low + width * np.arange(-BIN_MARGIN, LABEL_BINS + BIN_MARGIN + 1)
    at_edge = np.searchsorted(mids, edges, side="right").astype(np.uint8)
    # bin b: edges b..b+2M+1
    return _LabelBins(low, width, at_edge[:LABEL_BINS], at_edge[2 * BIN_MARGIN + 1 :])


def _binned_labels(data: F64, mids: F64, bins: _LabelBins) -> U8:
    """``searchsorted(mids, data, side="right")`` as bytes, exactly: a bin whose (widened)
    ends share a label gives it to its values; only the others and non-finite ones are
    searched."""
    finite = np.isfinite(data)
    everywhere = bool(finite.all())
    position = data - bins.low if everywhere else np.where(finite, data, bins.low) - bins.low
    position *= 1.0 / bins.width
    index = position.astype(np.intp)  # truncation is the floor: no position is negative
    np.clip(index, 0, LABEL_BINS - 1, out=index)
    labels = np.take(bins.first, index)
    unsure = labels != np.take(bins.last, index)
    if not everywhere:
        unsure |= ~finite
    if unsure.any():
        labels[unsure] = np.searchsorted(mids, data[unsure], side="right")
    return labels


def codebook_mse(samples: npt.ArrayLike, codebook: npt.ArrayLike) -> float:
    """Mean squared error of the finite ``samples`` against their nearest codebook entry."""
    data = np.asarray(samples, dtype=np.float64).reshape(-1)
    data = data[np.isfinite(data)]
    if data.size == 0:
        return 0.0
    table = np.asarray(codebook, dtype=np.float64)
    err = data - table[assign_codebook(data, table)]
    return float(np.dot(err, err) / data.size)


def _codebook(samples: npt.ArrayLike, *, refine: bool, weights: npt.ArrayLike | None = None) -> F32:
    """Split off non-finite values, quantise the finite ones, add sentinels."""
    data = np.asarray(samples)
    if not (np.issubdtype(data.dtype, np.floating) or np.issubdtype(data.dtype, np.integer)):
        raise InputError(f"samples must be numeric, got dtype {data.dtype}")
    if data.dtype != np.float32:
        data = data.astype(np.float64)
    data = data.reshape(-1)
    usable = np.isfinite(data)
    finite = _sorted_wide(data[usable])
    weighed = _usable_weights(weights, data.size, usable) if weights is not None else None
    has_neg = bool(np.any(data == -np.inf))
    has_pos = bool(np.any(data == np.inf))
    if finite.size == 0 and not (has_neg or has_pos):
        return np.zeros(CODEBOOK_SIZE, np.float32)
    if not (has_neg or has_pos) and finite[-1] - finite[0] < 1e-20:
        return np.full(CODEBOOK_SIZE, finite[0], np.float32)
    slots = CODEBOOK_SIZE - int(has_neg) - int(has_pos)
    if weighed is not None and _steps(finite) >= slots:
        span = (float(finite[0]), float(finite[-1]))
        centroids = _weighted_centroids(_binned(data, usable, weighed, span), span, slots)
    else:
        centroids = _finite_centroids(finite, slots, refine)
    return _compose(centroids, finite, has_neg, has_pos)


def _sorted_wide(values: npt.NDArray[np.floating]) -> F64:
    """The caller's own copy ``values`` sorted in place, as float64."""
    values.sort()
    return values.astype(np.float64)


def _steps(ascending: F64) -> int:
    """Distinct values less one of the ascending values."""
    return int(np.count_nonzero(ascending[1:] != ascending[:-1]))


def _usable_weights(weights: npt.ArrayLike, size: int, usable: npt.NDArray[np.bool_]) -> F64 | None:
    """The finite samples' weights as float64 (non-finite or negative: 0); None where none is
    positive."""
    given = np.array(weights, dtype=np.float64)  # its own copy (of a broadcast too), zeroed below
    if given.size != size:
        raise InputError(f"{given.size} weights for {size} samples")
    chosen = given.reshape(-1)
    if not usable.all():
        chosen = chosen[usable]
    chosen[~(np.isfinite(chosen) & (chosen > 0))] = 0.0
    return chosen if chosen.any() else None


WEIGHTED_BINS: Final = 1 << 16
"""Equal bins over the finite range in which :func:`_weighted_centroids` sums the weights."""


def _binned(
    data: npt.NDArray[np.floating], usable: npt.NDArray[np.bool_], weights: F64, span: Span
) -> tuple[F64, F64]:
    """The usable samples' weights and weighted values summed in WEIGHTED_BINS equal bins
    over ``span``, a block at a time (the same bits as ``np.bincount`` whole)."""
    low, high = span
    mass, moment = np.zeros(WEIGHTED_BINS), np.zeros(WEIGHTED_BINS)
    done = 0
    for rows in row_blocks(data.size, VALUE_BYTES):
        values = data[rows][usable[rows]]
        values = values.astype(np.float64)
        index = ((values - low) * (WEIGHTED_BINS / (high - low))).astype(np.intp)
        np.minimum(index, WEIGHTED_BINS - 1, out=index)
        scale = weights[done : done + len(values)]
        np.add.at(mass, index, scale)
        np.add.at(moment, index, scale * values)
        done += len(values)
    return mass, moment


def _weighted_centroids(sums: tuple[F64, F64], span: Span, slots: int) -> F32:
    """Ascending centroids (at most ``slots``) minimising the weighted squared error: the
    reference's programme then weighted Lloyd passes, on the binned sums of :func:`_binned`
    (quantizers.md, "Weighted")."""
    low, high = span
    mass, moment = sums
    occupied = mass > 0
    mass, moment = mass[occupied], moment[occupied]
    centres = moment / mass
    share = np.cumsum(mass)
    rank = (share - mass) / share[-1]
    q25, q75 = centres[np.searchsorted(rank, [0.25, 0.75], side="right") - 1]
    coarse = _blended_bins(rank, centres, q75 - q25, low, high - low, bins=HIST_BINS)
    bin_mass = _sums(coarse, mass, HIST_BINS)
    bin_moment = _sums(coarse, moment, HIST_BINS)
    filled = bin_mass > 0
    density = np.power(bin_mass[filled], DENSITY_ALPHA)
    start = _dp_centroids(bin_moment[filled] / bin_mass[filled], density, slots)
    return _lloyd_1d(centres, np.sort(start), mass)[0]


def _sums(index: npt.NDArray[np.intp], values: F64, bins: int) -> F64:
    """The sum of ``values`` in each of ``bins`` bins, by bin index."""
    return np.asarray(np.bincount(index, values, bins), np.float64)


def _finite_centroids(finite: F64, slots: int, refine: bool) -> F32:
    """Ascending centroids (at most ``slots``) for the sorted finite values."""
    if finite.size == 0 or slots == 0:
        return np.zeros(0, np.float32)
    if finite[-1] - finite[0] < 1e-20:
        return finite[:1].astype(np.float32)
    if refine and _steps(finite) < slots:
        return np.unique(finite.astype(np.float32))  # few distinct values: store them exactly
    centers, counts = _histogram(finite)
    centroids = _dp_centroids(centers, counts**DENSITY_ALPHA, slots)
    if refine:
        centroids = _lloyd_1d(finite, centroids)[0]
    return np.sort(centroids)


def _compose(centroids: F32, finite: F64, has_neg: bool, has_pos: bool) -> F32:
    """[-inf sentinel] + centroids padded with the last one + [+inf sentinel], 256 entries."""
    lo = (float(finite[0]) if finite.size else 0.0) - INFINITY_SENTINEL_OFFSET
    hi = (float(finite[-1]) if finite.size else 0.0) + INFINITY_SENTINEL_OFFSET
    first = int(has_neg)
    pad = centroids[-1] if centroids.size else np.float32(lo if has_neg else hi)
    table = np.full(CODEBOOK_SIZE, pad, np.float32)
    table[first : first + centroids.size] = centroids
    if has_neg:
        table[0] = lo
    if has_pos:
        table[-1] = hi
    return table


def _histogram(finite: F64) -> tuple[F64, F64]:
    """Bin centres (means) and counts of the rank/value-blended histogram (quantizers.md §1)."""
    n = finite.size
    bins = min(HIST_BINS, n)
    vmin, vrange = finite[0], finite[-1] - finite[0]
    iqr = finite[int(n * 0.75)] - finite[int(n * 0.25)]
    index = np.empty(n, np.intp)
    for rows in row_blocks(n, VALUE_BYTES):
        rank = np.arange(rows.start, rows.stop) / n
        index[rows] = _blended_bins(rank, finite[rows], iqr, vmin, vrange, bins=bins)
    counts = np.bincount(index, minlength=bins).astype(np.float64)
    sums = np.bincount(index, weights=finite, minlength=bins)
    empty_centre = vmin + (np.arange(bins) + 0.5) / bins * vrange
    with np.errstate(invalid="ignore", divide="ignore"):
        centers = np.where(counts > 0, sums / counts, empty_centre)
    return centers, counts


def _blended_bins(
    rank: F64, values: F64, iqr: float, low: float, span: float, *, bins: int
) -> npt.NDArray[np.intp]:
    """Each point's bin of the reference's histogram: its rank (0..1) and its value blended,
    the more by rank the narrower the interquartile range ``iqr`` is against the ``span``."""
    beta = max(BETA_MIN, min(BETA_MAX, 1.0 - iqr / span))
    position = beta * rank + (1.0 - beta) * ((values - low) / span)
    return np.clip(np.floor(bins * position), 0, bins - 1).astype(np.intp)


def _group_costs(centers: F64, weights: F64) -> tuple[F64, F64, F64]:
    """Prefix sums of w, w·x, w·x² so any group's weighted SSE is O(1)."""
    zero = np.zeros(1)
    pw = np.concatenate([zero, np.cumsum(weights)])
    pwx = np.concatenate([zero, np.cumsum(weights * centers)])
    pwxx = np.concatenate([zero, np.cumsum(weights * centers * centers)])
    return pw, pwx, pwxx


def _cost_matrix(pw: F64, pwx: F64, pwxx: F64, out: F64 | None = None) -> F64:
    """cost[end, start] = weighted SSE of bins start..end (inf where start > end), into ``out``
    when given, a block of ends at a time."""
    h = pw.size - 1
    cost = np.empty((h, h)) if out is None else out
    step = rows_per_block(VALUE_BYTES * h)
    for first in range(0, h, step):
        _group_costs_ending(pw, pwx, pwxx, first, cost[first : first + step])
    return cost


def _group_costs_ending(pw: F64, pwx: F64, pwxx: F64, first: int, out: F64) -> None:
    """Rows ``first``.. of :func:`_cost_matrix` (one per end bin), into ``out``."""
    ends = slice(first + 1, first + 1 + len(out))
    np.subtract(pwxx[ends, None], pwxx[None, :-1], out=out)
    w = pw[ends, None] - pw[None, :-1]
    wx = pwx[ends, None] - pwx[None, :-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        wx *= wx
        wx /= w
    out -= wx
    out[~(w > 0)] = 0.0
    starts = np.arange(out.shape[1])
    out[starts[None, :] > np.arange(first, first + len(out))[:, None]] = np.inf


def _dp_centroids(centers: F64, weights: F64, target: int) -> F32:
    """Optimal partition into min(target, non-empty bins) groups; their weighted means.

    Row m searches each end's splits from row m - 1's onwards (Knuth's bound, quantizers.md
    §1); ties go to the smallest split, as in the reference.
    """
    h = centers.size
    groups = min(target, int(np.count_nonzero(weights)))
    pw, pwx, pwxx = _group_costs(centers, weights)
    band = h - groups + 1
    stride = h + band  # columns past h: inf, so a row's candidates never wrap into the next
    cost = np.empty((h, stride))
    cost[:, h:] = np.inf
    _cost_matrix(pw, pwx, pwxx, out=cost[:, :h])
    flat = cost.ravel()
    ends = np.arange(band)
    row = np.full(2 * band, np.inf)  # past the band: inf, as splits beyond an end
    row[:band] = cost[:band, 0]  # m = 1: one group over bins 0..j, j in [0, band)
    splits = np.zeros((groups + 1, band), np.intp)
    low = np.zeros(band, np.intp)  # each end's first candidate split, in band terms
    next_row = np.empty(band)  # row m's values, kept apart until every end has read row m - 1
    best = np.empty(band, np.intp)
    for m in range(2, groups + 1):
        # end j = m - 1 + i, splits s from low[i] on (inf past i): cost[j, m - 1 + s] + row[s]
        width = int((ends - low).max()) + 1
        step = rows_per_block(VALUE_BYTES * width)  # wide in the first rows: ends a block at a time
        for first in range(0, band, step):
            block = slice(first, first + step)
            candidates = low[block, None] + np.arange(width)
            first_cells = (m - 1) * (stride + 1) + ends[block] * stride
            total = np.take(flat, first_cells[:, None] + candidates)
            total += np.take(row, candidates)
            pick = np.argmin(total, axis=1)  # the first minimum: the smallest split
            best[block] = low[block] + pick
            next_row[block] = total[np.arange(len(pick)), pick]
        row[:band] = next_row
        splits[m] = best + (m - 2)
        low[:-1], low[-1] = best[1:], best[-1]
        np.maximum(low - 1, 0, out=low)
    out = np.empty(groups, np.float64)
    end = h - 1
    for m in range(groups, 0, -1):
        split = int(splits[m, end - (m - 1)]) if m > 1 else -1
        w = pw[end + 1] - pw[split + 1]
        wx = pwx[end + 1] - pwx[split + 1]
        out[m - 1] = wx / w if w > 0 else (centers[split + 1] + centers[end]) * 0.5
        end = split
    return out.astype(np.float32)


def _lloyd_1d(points: F64, start: F32, mass: F64 | None = None) -> tuple[F32, float]:
    """1-D Lloyd passes on ascending ``points`` (each of weight ``mass``, 1 when None); the
    codebook with the lowest exact (weighted) SSE, and its SSE."""
    shift = points[points.size // 2]
    p0 = None if mass is None else np.concatenate([np.zeros(1), np.cumsum(mass)])
    p1, p2 = _prefix_moments(points, shift, mass)

    def held(edges: npt.NDArray[np.intp]) -> npt.NDArray[np.floating]:
        return np.diff(edges) if p0 is None else p0[edges[1:]] - p0[edges[:-1]]

    edges = _edges(points, start)
    counts = held(edges)
    best, best_sse = start, _sse_1d(edges, p1, p2, shift, start, counts=counts)
    current = start
    for _ in range(REFINE_PASSES):
        sums = p1[edges[1:]] - p1[edges[:-1]]
        with np.errstate(invalid="ignore", divide="ignore"):
            moved = np.where(counts > 0, sums / counts + shift, current).astype(np.float32)
        moved.sort()
        if np.array_equal(moved, current):
            break
        current = moved
        edges = _edges(points, current)
        counts = held(edges)
        sse = _sse_1d(edges, p1, p2, shift, current, counts=counts)
        if sse < best_sse:
            best, best_sse = current, sse
    return best, best_sse


def _prefix_moments(points: F64, shift: float, mass: F64 | None) -> tuple[F64, F64]:
    """Prefix sums, from 0, of each point's weighted offset from ``shift`` and of its weighted
    square (weight ``mass``, 1 when None), a block at a time."""
    n = points.size
    p1, p2 = np.zeros(n + 1), np.zeros(n + 1)
    for rows in row_blocks(n, VALUE_BYTES):
        centred = points[rows] - shift
        weighted = centred if mass is None else mass[rows] * centred
        after = slice(rows.start + 1, rows.stop + 1)  # p1[0] = p2[0] = 0
        p1[after] = weighted
        np.multiply(weighted, centred, out=p2[after])
    np.cumsum(p1[1:], out=p1[1:])
    np.cumsum(p2[1:], out=p2[1:])
    return p1, p2


def _edges(finite: F64, table: F32) -> npt.NDArray[np.intp]:
    """Group boundaries of the sorted samples under nearest-entry assignment."""
    wide = table.astype(np.float64)
    cuts = np.searchsorted(finite, (wide[:-1] + wide[1:]) * 0.5, side="left")
    return np.concatenate([[0], cuts, [finite.size]]).astype(np.intp)


def _sse_1d(
    edges: npt.NDArray[np.intp],
    p1: F64,
    p2: F64,
    shift: float,
    table: F32,
    *,
    counts: npt.NDArray[np.floating] | npt.NDArray[np.intp],
) -> float:
    """Exact (weighted) SSE of the sorted points against ``table`` (group ``edges`` and
    ``counts`` or mass per group), via prefix sums."""
    c = table.astype(np.float64) - shift
    s1 = p1[edges[1:]] - p1[edges[:-1]]
    s2 = p2[edges[1:]] - p2[edges[:-1]]
    return float(np.sum(s2 - 2.0 * c * s1 + c * c * counts))


SHORT_CODEBOOK_STEPS: Final = 65536
"""A codebook entry may move by its span / this to be written with fewer digits."""


def short_codebook(codebook: npt.ArrayLike) -> F32:
    """Each entry replaced by the value of fewest significant digits within span /
    SHORT_CODEBOOK_STEPS of it, still ascending: about half meta.json's codebook bytes."""
    table = np.asarray(codebook, dtype=np.float64)
    span = float(table.max() - table.min()) if table.size else 0.0
    tol = max(span / SHORT_CODEBOOK_STEPS, 0.0)
    out = table.copy()
    settled = np.zeros(table.size, bool)
    magnitude = np.floor(np.log10(np.maximum(np.abs(table), 1e-30)))
    for digits in range(1, 10):
        scale = 10.0 ** (magnitude - digits + 1)
        rounded = np.round(table / scale) * scale
        close = ~settled & (np.abs(rounded.astype(np.float32).astype(np.float64) - table) <= tol)
        out[close] = rounded[close]
        settled |= close
    return np.maximum.accumulate(out.astype(np.float32))
