"""Scalar codebooks: the spec §6.1 reference algorithm, our refinement, and nearest assignment."""

from __future__ import annotations

import math
import tracemalloc
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream import columns, quantize
from tsog_stream.constants import CODEBOOK_SIZE
from tsog_stream.errors import InputError
from tsog_stream.quantize import (
    SHORT_CODEBOOK_STEPS,
    assign_codebook,
    build_codebook,
    codebook_mse,
    dp_codebook,
    short_codebook,
)

F64 = npt.NDArray[np.float64]


def _literal_quantize_finite(s: list[float], k_target: int) -> list[float]:
    """splat-transform's quantizeFinite transliterated line by line (plain loops; tiny inputs)."""
    n = len(s)
    vmin, vmax = s[0], s[-1]
    h = min(1024, n)
    vrange = vmax - vmin
    iqr = s[math.floor(n * 0.75)] - s[math.floor(n * 0.25)]
    beta = max(0.5, min(0.999, 1 - iqr / vrange))
    counts, sums = [0.0] * h, [0.0] * h
    for i, v in enumerate(s):
        b = min(h - 1, math.floor(h * (beta * (i / n) + (1 - beta) * ((v - vmin) / vrange))))
        counts[b] += 1
        sums[b] += v
    centers = [
        sums[i] / counts[i] if counts[i] > 0 else vmin + (i + 0.5) / h * vrange for i in range(h)
    ]
    weights = [math.sqrt(c) for c in counts]
    pw, pwx, pwxx = [0.0] * (h + 1), [0.0] * (h + 1), [0.0] * (h + 1)
    for i in range(h):
        pw[i + 1] = pw[i] + weights[i]
        pwx[i + 1] = pwx[i] + weights[i] * centers[i]
        pwxx[i + 1] = pwxx[i] + weights[i] * centers[i] * centers[i]

    def cost(a: int, b: int) -> float:
        w = pw[b + 1] - pw[a]
        if w <= 0:
            return 0.0
        wx = pwx[b + 1] - pwx[a]
        return (pwxx[b + 1] - pwxx[a]) - (wx * wx) / w

    groups = min(k_target, sum(1 for c in counts if c > 0))
    prev = [cost(0, j) for j in range(h)]
    splits: dict[int, list[int]] = {}
    for m in range(2, groups + 1):
        cur, split = [1e30] * h, [0] * h
        for j in range(m - 1, h):
            best, best_s = 1e30, m - 2
            for s_ in range(m - 2, j):
                c = prev[s_] + cost(s_ + 1, j)
                if c < best:
                    best, best_s = c, s_
            cur[j], split[j] = best, best_s
        splits[m], prev = split, cur
    out, j = [0.0] * groups, h - 1
    for m in range(groups, 0, -1):
        s_ = splits[m][j] if m > 1 else -1
        w = pw[j + 1] - pw[s_ + 1]
        out[m - 1] = (pwx[j + 1] - pwx[s_ + 1]) / w if w > 0 else (centers[s_ + 1] + centers[j]) / 2
        j = s_
    return out


def _literal_codebook(samples: npt.NDArray[np.floating], k: int) -> npt.NDArray[np.float32]:
    """Reference finite-only codebook with k slots (no infinities), padded like the tool."""
    finite = np.sort(samples.astype(np.float32)).astype(np.float64).tolist()
    cents = np.sort(np.array(_literal_quantize_finite(finite, k), np.float32))
    table = np.full(CODEBOOK_SIZE, cents[-1], np.float32)
    table[: cents.size] = cents
    return table


DISTRIBUTIONS: dict[str, Callable[[np.random.Generator], F64]] = {
    "normal": lambda r: r.normal(0.0, 1.0, 60_000),
    "log_scales": lambda r: np.concatenate(
        [r.normal(-5.0, 1.5, 90_000), r.uniform(-1.0, 4.0, 300), r.normal(-14.0, 0.5, 200)]
    ),
    "heavy_tail": lambda r: r.standard_t(1.5, 50_000) * 0.1,
    "sh_dc": lambda r: np.concatenate([r.normal(0.0, 0.6, 40_000), r.normal(1.8, 0.2, 5_000)]),
    "discrete": lambda r: r.integers(-600, 600, 40_000).astype(np.float64) * 0.01,
    "few_distinct": lambda r: r.choice([-1.0, 0.0, 0.25, 3.0], 10_000),
    "with_inf": lambda r: np.concatenate([r.normal(-5.0, 1.5, 30_000), [-np.inf] * 50, [np.inf]]),
}


@pytest.mark.parametrize("name", sorted(DISTRIBUTIONS))
def test_codebook_shape_and_order(name: str) -> None:
    samples = DISTRIBUTIONS[name](np.random.default_rng(3)).astype(np.float32)
    for table in (build_codebook(samples), dp_codebook(samples)):
        assert table.dtype == np.float32
        assert table.shape == (CODEBOOK_SIZE,)
        assert np.all(np.isfinite(table))
        assert np.all(np.diff(table) >= 0)


@pytest.mark.parametrize("name", sorted(DISTRIBUTIONS))
def test_refined_mse_never_worse_than_reference(name: str) -> None:
    samples = DISTRIBUTIONS[name](np.random.default_rng(4)).astype(np.float32)
    ours = codebook_mse(samples, build_codebook(samples))
    reference = codebook_mse(samples, dp_codebook(samples))
    assert ours <= reference


def test_refinement_helps_on_realistic_scales() -> None:
    samples = DISTRIBUTIONS["log_scales"](np.random.default_rng(5)).astype(np.float32)
    assert codebook_mse(samples, build_codebook(samples)) < 0.99 * codebook_mse(
        samples, dp_codebook(samples)
    )


def dp_codebook_with_slots(samples: F64, k: int) -> npt.NDArray[np.float32]:
    """dp_codebook restricted to k centroids, padded to 256 like the tool pads."""
    finite = np.sort(samples.astype(np.float32)).astype(np.float64)
    cents = quantize._finite_centroids(finite, k, refine=False)
    table = np.full(CODEBOOK_SIZE, cents[-1], np.float32)
    table[: cents.size] = cents
    return table


@pytest.mark.parametrize(("seed", "n", "k"), [(0, 90, 12), (1, 300, 40), (2, 700, 9)])
def test_dp_matches_literal_transliteration(seed: int, n: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    samples = np.concatenate([rng.normal(0, 1, n), rng.standard_t(2, n // 5) * 3])
    ours = dp_codebook_with_slots(samples, k)
    np.testing.assert_array_equal(ours, _literal_codebook(samples, k))


def test_dp_full_size_matches_literal_on_few_bins() -> None:
    # 200 samples -> 200 bins and 256 slots: every non-empty bin is its own centroid.
    samples = np.random.default_rng(6).normal(0, 1, 200).astype(np.float32)
    np.testing.assert_array_equal(dp_codebook(samples), _literal_codebook(samples, 256))


def _whole_band_centroids(centers: F64, weights: F64, target: int) -> npt.NDArray[np.float32]:
    """The dynamic programme searching every split of every end (no Knuth bound): the
    reference's loops as one (band x band) minimum per row."""
    h = centers.size
    groups = min(target, int(np.count_nonzero(weights)))
    pw, pwx, pwxx = quantize._group_costs(centers, weights)
    cost = quantize._cost_matrix(pw, pwx, pwxx)
    band = h - groups + 1
    row = cost[:band, 0].copy()
    splits = np.zeros((groups + 1, band), np.intp)
    for m in range(2, groups + 1):
        total = cost[m - 1 : m - 1 + band, m - 1 : m - 1 + band] + row[None, :]
        best = np.argmin(total, axis=1)
        row = total[np.arange(band), best]
        splits[m] = best + (m - 2)
    out, end = np.empty(groups), h - 1
    for m in range(groups, 0, -1):
        split = int(splits[m, end - (m - 1)]) if m > 1 else -1
        w = pw[end + 1] - pw[split + 1]
        wx = pwx[end + 1] - pwx[split + 1]
        out[m - 1] = wx / w if w > 0 else 0.5 * (centers[split + 1] + centers[end])
        end = split
    return out.astype(np.float32)


BOUND_CASES: dict[str, Callable[[np.random.Generator, int], F64]] = {
    "normal": lambda r, n: r.normal(0.0, 1.0, n),
    "log_scales": lambda r, n: np.concatenate([r.normal(-5, 1.5, n), r.normal(-14, 0.5, n // 300)]),
    "heavy_tail": lambda r, n: r.standard_t(1.5, n) * 0.1,
    "bimodal": lambda r, n: np.concatenate([r.normal(0, 0.6, n), r.normal(1.8, 0.2, n // 8)]),
    "exponential": lambda r, n: r.exponential(1.0, n),
}
REPEATED_CASES: dict[str, Callable[[np.random.Generator, int], F64]] = {
    "cents": lambda r, n: r.integers(-600, 600, n).astype(np.float64) * 0.01,
    "seven_values": lambda r, n: r.choice([-1.0, 0.0, 0.25, 3.0, 7.0, 8.0, 9.5], n),
    "spikes": lambda r, n: np.concatenate([r.normal(0, 1, n), r.normal(0, 1, 50).repeat(n // 100)]),
}


def _histogram_of(samples: F64) -> tuple[F64, F64]:
    """Bin centres and weights of the samples, as the codebook builds them."""
    finite = np.sort(samples.astype(np.float32)).astype(np.float64)
    centers, counts = quantize._histogram(finite)
    return centers, counts**quantize.DENSITY_ALPHA


@pytest.mark.parametrize("name", sorted(BOUND_CASES))
def test_knuth_bounded_dp_equals_the_whole_band_search(name: str) -> None:
    """Restricting each split to at least the previous row's changes nothing on values
    without repeats: same centroids bit for bit, for any number of groups."""
    rng = np.random.default_rng(11)
    for n, k in [(60_000, 256), (5_000, 254), (20_000, 37), (2_000, 3)]:
        centers, weights = _histogram_of(BOUND_CASES[name](rng, n))
        expected = _whole_band_centroids(centers, weights, k)
        np.testing.assert_array_equal(quantize._dp_centroids(centers, weights, k), expected)


def _histogram_sse(centers: F64, weights: F64, centroids: npt.NDArray[np.float32]) -> float:
    """The programme's objective for a set of centroids: each bin's weighted squared distance
    to its nearest centroid (no set of this size does better than the optimal partition)."""
    table = np.sort(centroids).astype(np.float64)
    err = centers - table[assign_codebook(centers, table)]
    return float(np.dot(weights, err * err))


@pytest.mark.parametrize("name", sorted(REPEATED_CASES))
def test_knuth_bounded_dp_on_repeated_values_is_still_optimal(name: str) -> None:
    """Runs of bins holding one value tie within rounding; the bounded search may settle a
    tie on another partition, never on a costlier one."""
    rng = np.random.default_rng(12)
    for n, k in [(5_333, 255), (40_000, 256), (16_000, 254), (60_000, 40)]:
        centers, weights = _histogram_of(REPEATED_CASES[name](rng, n))
        best = _histogram_sse(centers, weights, _whole_band_centroids(centers, weights, k))
        ours = _histogram_sse(centers, weights, quantize._dp_centroids(centers, weights, k))
        assert ours <= best * (1 + 1e-9) + 1e-12


def test_infinities_reserve_sentinel_slots() -> None:
    rng = np.random.default_rng(7)
    finite = rng.normal(-5.0, 1.5, 5000).astype(np.float32)
    samples = np.concatenate([finite, [-np.inf, np.inf, np.nan]]).astype(np.float32)
    table = build_codebook(samples)
    assert table[0] == np.float32(float(finite.min()) - 20.0)
    assert table[-1] == np.float32(float(finite.max()) + 20.0)
    assert table[1] >= finite.min() and table[-2] <= finite.max()
    labels = assign_codebook(np.array([-np.inf, np.inf], np.float32), table)
    assert labels.tolist() == [0, CODEBOOK_SIZE - 1]
    assert assign_codebook(finite, table).min() >= 1
    assert assign_codebook(finite, table).max() <= CODEBOOK_SIZE - 2


def test_only_negative_infinity_reserves_slot_zero() -> None:
    samples = np.array([1.0, 2.0, 3.0, -np.inf], np.float32)
    table = build_codebook(samples)
    assert table[0] == np.float32(-19.0)
    np.testing.assert_array_equal(table[1:4], [1.0, 2.0, 3.0])
    assert np.all(table[4:] == 3.0)


def test_nan_is_ignored() -> None:
    rng = np.random.default_rng(8)
    values = rng.normal(0, 1, 4000).astype(np.float32)
    with_nan = np.concatenate([values, np.full(100, np.nan, np.float32)])
    np.testing.assert_array_equal(build_codebook(with_nan), build_codebook(values))
    assert assign_codebook(np.array([np.nan]), build_codebook(values)).tolist() == [255]


def test_degenerate_inputs() -> None:
    np.testing.assert_array_equal(build_codebook(np.zeros(0, np.float32)), np.zeros(256))
    np.testing.assert_array_equal(build_codebook(np.full(9, np.nan)), np.zeros(256))
    np.testing.assert_array_equal(build_codebook(np.full(50, 0.25)), np.full(256, 0.25))
    np.testing.assert_array_equal(build_codebook(np.full(3, -np.inf)), np.full(256, -20.0))
    both = build_codebook(np.array([-np.inf, np.inf]))
    assert both[0] == -20.0 and both[-1] == 20.0


def test_few_distinct_values_are_exact() -> None:
    samples = DISTRIBUTIONS["few_distinct"](np.random.default_rng(9))
    table = build_codebook(samples)
    assert codebook_mse(samples, table) == 0.0
    np.testing.assert_array_equal(table[:4], [-1.0, 0.0, 0.25, 3.0])


def test_assignment_is_nearest_entry() -> None:
    rng = np.random.default_rng(10)
    samples = DISTRIBUTIONS["log_scales"](rng).astype(np.float32)
    table = build_codebook(samples)
    values = rng.uniform(-20.0, 8.0, 3000).astype(np.float32)
    labels = assign_codebook(values, table)
    err = np.abs(values.astype(np.float64) - table[labels])
    best = np.abs(values[:, None].astype(np.float64) - table[None, :].astype(np.float64)).min(1)
    np.testing.assert_allclose(err, best, rtol=0, atol=1e-12)
    inside = (values >= table[0]) & (values <= table[-1])
    assert np.all(err[inside] <= np.diff(table.astype(np.float64)).max() / 2 + 1e-12)


def _searched_labels(values: npt.ArrayLike, table: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """The labels by binary search over the float64 midpoints (the definition)."""
    entries = np.asarray(table, np.float64)
    mids = (entries[:-1] + entries[1:]) * 0.5
    return np.searchsorted(mids, np.asarray(values, np.float64), side="right").astype(np.uint8)


def _label_cases(rng: np.random.Generator) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Many values (enough to be looked up by bin) against codebooks, hostile ones included."""
    normal = rng.normal(size=(40_000, 3)).astype(np.float32)
    table = build_codebook(normal)
    entries = table.astype(np.float64)
    mids = np.repeat((entries[:-1] + entries[1:]) * 0.5, 300)
    near = mids.astype(np.float32)
    huge, holes = normal.copy(), normal.copy()
    huge[::100] *= np.float32(1e30)
    holes[::37, 0], holes[::41, 1], holes[::43, 2] = np.nan, np.inf, -np.inf
    narrow = np.float32(1000) + rng.normal(size=90_000).astype(np.float32) * np.float32(1e-3)
    few = rng.integers(0, 5, 90_000).astype(np.float32)
    return {
        "normal": (normal, table),
        "on midpoints (float64)": (mids, table),
        "beside midpoints": (np.concatenate([near, np.nextafter(near, np.float32(9))]), table),
        "huge outliers": (huge, build_codebook(huge)),
        "NaN and infinities": (holes, build_codebook(holes)),
        "a narrow range": (narrow, build_codebook(narrow)),
        "few values": (few, build_codebook(few)),
        "one value": (np.full(90_000, 3.5, np.float32), build_codebook([3.5])),
        "all NaN": (np.full(90_000, np.nan), table),
        "one entry": (normal, np.array([0.5], np.float32)),
    }


def test_labels_looked_up_by_bin_equal_the_binary_search() -> None:
    """Many values are labelled from a table of bins and searched only where a bin holds a
    midpoint: every label is the search's, through midpoints, outliers, NaN and infinities."""
    for name, (values, table) in _label_cases(np.random.default_rng(12)).items():
        assert values.size >= quantize.BINNED_FROM, name
        labels = assign_codebook(values, table)
        assert np.array_equal(labels, _searched_labels(values, table)), name


def test_midpoint_goes_up_and_shape_is_kept() -> None:
    table = np.arange(256, dtype=np.float32)
    values = np.array([[0.5, 1.49], [254.5, 1e9]], np.float32)
    labels = assign_codebook(values, table)
    assert labels.dtype == np.uint8
    assert labels.tolist() == [[1, 1], [255, 255]]


def test_bad_arguments() -> None:
    with pytest.raises(InputError):
        assign_codebook([1.0], [2.0, 1.0])
    with pytest.raises(InputError):
        assign_codebook([1.0], np.zeros(257))
    with pytest.raises(InputError):
        build_codebook(np.array(["a", "b"]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_short_codebook_moves_entries_within_its_grid_and_halves_the_digits(seed: int) -> None:
    """Entries move by at most span / 65536, stay ascending (sentinels included), and are
    written with far fewer digits."""
    rng = np.random.default_rng(seed)
    samples = np.concatenate([rng.normal(-4, 1.5, 5000), [-np.inf]]).astype(np.float32)
    codebook = build_codebook(samples)
    short = short_codebook(codebook)
    span = float(codebook.max()) - float(codebook.min())
    assert short.dtype == np.float32 and short.shape == codebook.shape
    assert np.all(np.diff(short) >= 0)
    assert np.abs(short.astype(np.float64) - codebook).max() <= span / SHORT_CODEBOOK_STEPS
    digits = sum(len(str(v)) for v in short)
    assert digits < 0.75 * sum(len(str(v)) for v in codebook)


def _weighted_mse(samples: F64, weights: F64, codebook: npt.NDArray[np.float32]) -> float:
    table = codebook.astype(np.float64)
    err = samples - table[assign_codebook(samples, table)]
    return float(np.dot(weights, err * err) / weights.sum())


def _mixture(rng: np.random.Generator) -> tuple[F64, F64]:
    """Many light samples spread wide (tiny, faint Gaussians' log sizes) beside a few heavy
    ones in a narrow range (the sizes a view draws)."""
    light = rng.normal(-10.0, 3.0, 90_000)
    heavy = rng.normal(-1.0, 0.4, 10_000)
    samples = np.concatenate([light, heavy]).astype(np.float32).astype(np.float64)
    weights = np.concatenate([np.full(light.size, 1e-3), np.ones(heavy.size)])
    return samples, weights


def test_weights_send_the_entries_where_the_error_costs() -> None:
    samples, weights = _mixture(np.random.default_rng(21))
    plain = build_codebook(samples)
    weighted = build_codebook(samples, weights)
    heavy = weights == 1.0
    # measured: the weighted error 0.62x, the heavy samples' own 0.03x, their entries 224 / 29
    assert _weighted_mse(samples, weights, weighted) < 0.8 * _weighted_mse(samples, weights, plain)
    assert codebook_mse(samples[heavy], weighted) < 0.1 * codebook_mse(samples[heavy], plain)
    assert np.all(np.diff(weighted) >= 0) and weighted.dtype == np.float32
    inside = (weighted > -2.2) & (weighted < 0.2)
    assert inside.sum() > 4 * ((plain > -2.2) & (plain < 0.2)).sum()
    np.testing.assert_array_equal(build_codebook(samples, weights), weighted)  # deterministic


def test_weighted_codebook_still_stores_few_distinct_values_exactly() -> None:
    rng = np.random.default_rng(22)
    values = np.sort(rng.normal(0.0, 2.0, 200)).astype(np.float32)
    samples = rng.choice(values, 20_000)
    weights = rng.exponential(1.0, samples.size)
    table = build_codebook(samples, weights)
    assert set(values.tolist()) <= set(table.tolist())
    assert codebook_mse(samples, table) == 0.0


def test_weights_keep_the_infinity_sentinels_and_ignore_what_is_not_finite() -> None:
    samples, weights = _mixture(np.random.default_rng(23))
    with_inf = np.concatenate([samples, [-np.inf, np.inf, np.nan]])
    weights = np.concatenate([weights, [1.0, np.nan, 5.0]])
    weights[:10] = [np.inf, -1.0, np.nan, 0, 0, 0, 0, 0, 0, 0]  # counted as no weight
    table = build_codebook(with_inf, weights)
    finite = samples[np.isfinite(samples)]
    assert table[0] == np.float32(finite.min() - 20.0)
    assert table[-1] == np.float32(finite.max() + 20.0)
    assert np.all(np.isfinite(table)) and np.all(np.diff(table) >= 0)


def test_weighted_sums_taken_a_block_at_a_time_are_the_sums_of_all_at_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The weighted bins' sums, added a few samples at a time (non-finite ones skipped), are
    ``np.bincount``'s over all the usable samples, bit for bit; the caller's weights are left
    as they were (the unusable ones are zeroed in the codebook's own copy)."""
    samples, weights = _mixture(np.random.default_rng(25))
    samples[::97] = np.nan
    weights[::89] = -1.0
    given = weights.copy()
    expected = build_codebook(samples, weights)
    usable = np.isfinite(samples)
    values, scale = samples[usable], np.where(weights[usable] > 0, weights[usable], 0.0)
    span = (float(values.min()), float(values.max()))
    index = ((values - span[0]) * (quantize.WEIGHTED_BINS / (span[1] - span[0]))).astype(np.intp)
    index = np.minimum(index, quantize.WEIGHTED_BINS - 1)
    whole = (
        np.bincount(index, scale, quantize.WEIGHTED_BINS),
        np.bincount(index, scale * values, quantize.WEIGHTED_BINS),
    )
    monkeypatch.setattr(columns, "BLOCK_BYTES", 777 * 8)  # 777 float64 values a block
    blocked = quantize._binned(samples, usable, scale, span)
    for ours, theirs in zip(blocked, whole, strict=True):
        assert ours.tobytes() == theirs.tobytes()
    np.testing.assert_array_equal(build_codebook(samples, weights), expected)
    np.testing.assert_array_equal(weights, given)


def test_weights_with_nothing_positive_give_the_unweighted_codebook() -> None:
    samples, _ = _mixture(np.random.default_rng(24))
    np.testing.assert_array_equal(
        build_codebook(samples, np.zeros(samples.size)), build_codebook(samples)
    )
    with pytest.raises(InputError, match="weights"):
        build_codebook(samples, np.ones(samples.size - 1))


def _codebook_work(samples: npt.NDArray[np.float32]) -> list[npt.NDArray[np.generic]]:
    """Everything the module computes a block at a time, for one input."""
    weights = np.abs(samples.astype(np.float64)) + 0.1
    centers, density = _histogram_of(samples[np.isfinite(samples)].astype(np.float64))
    table = build_codebook(samples)
    return [
        table,
        dp_codebook(samples),
        build_codebook(samples, weights),
        assign_codebook(samples, table),
        quantize._dp_centroids(centers, density, 256),
    ]


def test_blocks_change_no_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Histograms, prefix sums, the DP's costs and labels worked out in blocks of 7 values
    equal the same work on the whole arrays, bit for bit (NaN and infinities included)."""
    rng = np.random.default_rng(25)
    samples = np.concatenate([rng.standard_t(3, 90_000), [np.nan, np.inf, -np.inf] * 4])
    samples = samples.astype(np.float32)
    monkeypatch.setattr(columns, "BLOCK_BYTES", 1 << 40)
    whole = _codebook_work(samples)
    monkeypatch.setattr(columns, "BLOCK_BYTES", 7 * 8)
    for blocked, at_once in zip(_codebook_work(samples), whole, strict=True):
        assert blocked.dtype == at_once.dtype
        assert np.array_equal(blocked.view(np.uint8), at_once.view(np.uint8))


def _traced_peak(work: Callable[[], object]) -> int:
    """Bytes numpy allocated at most while ``work`` ran, beyond what it held before."""
    tracemalloc.start()
    try:
        work()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_codebooks_of_many_values_hold_few_copies_of_them() -> None:
    """A codebook of n values (an SH palette's 65536 x 45 are 2.9M) holds at most 3.5 float64
    copies of them at once (5.1 when computed whole: 115 MiB at 2.9M), their labels a byte a
    value and a few blocks (24 bytes a value: a float64 copy, positions and indexes whole),
    the DP of 1024 bins 20 MiB (31 with its cost matrix computed whole)."""
    values = np.random.default_rng(26).standard_t(4, 1 << 21).astype(np.float32)
    assert _traced_peak(lambda: build_codebook(values)) <= 3.5 * 8 * values.size
    table = build_codebook(values)
    assert _traced_peak(lambda: assign_codebook(values, table)) <= values.size + (4 << 20)
    centers, density = _histogram_of(values[:50_000].astype(np.float64))
    assert centers.size == quantize.HIST_BINS
    assert _traced_peak(lambda: quantize._dp_centroids(centers, density, 256)) <= 20 << 20
