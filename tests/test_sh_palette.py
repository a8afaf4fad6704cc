"""SH palette: splat-transform's K, exactness, determinism and error vs the reference Lloyd."""

from __future__ import annotations

import itertools
import math
import weakref

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream import columns, palette_kernels, sh_palette
from tsog_stream.constants import BLOCK_BYTES
from tsog_stream.errors import InputError
from tsog_stream.render.sh import sh_basis
from tsog_stream.sh_palette import (
    COLOUR_PER_SQUARED,
    PASSES_BASE,
    PASSES_PER_RATIO,
    _Work,
    fit_palette,
    palette_mse,
    palette_size,
)

F32 = npt.NDArray[np.float32]


def _reference_lloyd(
    points: F32, k: int, seed: int, iterations: int = 10
) -> tuple[F32, npt.NDArray[np.intp]]:
    """splat-transform's CPU k-means: k distinct random points, then plain Lloyd iterations.

    Its unseeded Math.random is replaced by a seeded generator; an empty cluster is re-seeded
    with a random point; labels are the last assignment, centroids the means after it.
    """
    rng = np.random.default_rng(seed)
    centroids = points[rng.choice(len(points), k, replace=False)].astype(np.float64)
    labels = np.zeros(len(points), np.intp)
    for _ in range(iterations):
        dots = points @ centroids.T.astype(np.float32)
        labels = np.argmin(0.5 * (centroids**2).sum(1)[None, :] - dots, axis=1)
        mass = np.bincount(labels, minlength=k)
        sums = np.stack([np.bincount(labels, points[:, j], k) for j in range(points.shape[1])], 1)
        centroids = sums / np.maximum(mass, 1)[:, None]
        empty = mass == 0
        centroids[empty] = points[rng.integers(0, len(points), int(empty.sum()))]
    return centroids.astype(np.float32), labels


def _sh_like(n: int, dim: int, seed: int) -> F32:
    """f_rest-like vectors: correlated channels, heavy-tailed magnitude, zeros and clones."""
    rng = np.random.default_rng(seed)
    coeffs = dim // 3
    decay = 0.08 / np.sqrt(1.0 + np.arange(coeffs))
    shared = rng.standard_normal((n, coeffs)) * decay
    per_channel = [shared + 0.4 * rng.standard_normal((n, coeffs)) * decay for _ in range(3)]
    scale = rng.lognormal(0.0, 0.6, (n, 1))
    vectors = (np.concatenate(per_channel, axis=1) * scale).astype(np.float32)
    vectors[rng.random(n) < 0.05] = 0.0
    clones = np.flatnonzero(rng.random(n) < 0.05)
    vectors[clones] = vectors[rng.integers(0, n, len(clones))]
    return vectors


@pytest.mark.parametrize(
    ("n", "k"),
    [
        *[(1, 1), (2, 2), (3, 2), (500, 256), (1023, 512), (1024, 1024), (5000, 4096)],
        *[(50_000, 32_768), (65_536, 65_536), (100_000, 65_536), (10**7, 65_536)],
    ],
)
def test_palette_size_examples(n: int, k: int) -> None:
    assert palette_size(n) == k


def test_palette_size_matches_tool_formula() -> None:
    for n in range(1, 300_000, 997):
        tool = int(min(64, 2 ** math.floor(math.log2(n / 1024))) * 1024)
        assert palette_size(n) == tool, n
    with pytest.raises(InputError):
        palette_size(0)


@pytest.mark.parametrize(("n", "dim", "k"), [(5000, 45, 4096), (3000, 9, None), (6000, 24, 512)])
def test_error_not_worse_than_reference_lloyd(n: int, dim: int, k: int | None) -> None:
    points = _sh_like(n, dim, seed=n + dim)
    size = palette_size(n) if k is None else k
    centroids, labels = fit_palette(points, k, seed=1)
    ref_centroids, ref_labels = _reference_lloyd(points, size, seed=1)
    ours = palette_mse(points, centroids, labels)
    reference = palette_mse(points, ref_centroids, ref_labels)
    assert ours <= reference, (ours, reference)
    assert centroids.shape == (size, dim) and centroids.dtype == np.float32
    assert labels.shape == (n,) and labels.dtype == np.uint16
    assert int(labels.max()) < size


def test_deterministic_for_a_seed() -> None:
    points = _sh_like(4000, 45, seed=11)
    first = fit_palette(points, 1024, seed=5)
    second = fit_palette(points.copy(), 1024, seed=5)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])


def test_exact_when_palette_holds_every_distinct_vector() -> None:
    rng = np.random.default_rng(12)
    distinct = rng.normal(0, 0.05, (300, 24)).astype(np.float32)
    points = distinct[rng.integers(0, 300, 5000)]
    centroids, labels = fit_palette(points, 512)
    assert len(centroids) == len(np.unique(points, axis=0))
    assert palette_mse(points, centroids, labels) == 0.0
    np.testing.assert_array_equal(centroids[labels], points)


@pytest.mark.parametrize("hashes", ["real", "colliding"])
def test_distinct_rows_are_found_by_bytes_even_when_hashes_collide(
    hashes: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Identical vectors (-0.0 and 0.0 are different bytes) collapse to one weighted row; a
    hash shared by distinct rows (forced here: every row hashes alike) falls back to the
    rows' bytes, with the same distinct rows and counts."""
    if hashes == "colliding":
        monkeypatch.setattr(
            palette_kernels, "row_hashes", lambda data: np.zeros(len(data), np.uint64)
        )
    rng = np.random.default_rng(21)
    distinct = rng.normal(0, 0.05, (40, 9)).astype(np.float32)
    distinct[1] = 0.0
    distinct[2] = -0.0
    pick = rng.integers(0, 40, 700)
    points = distinct[pick]
    given = points.copy()
    monkeypatch.setattr(columns, "BLOCK_BYTES", 4 * 9 * 3)
    unique, inverse, weights = palette_kernels.unique_rows(given)
    expected = np.unique(points.view(np.uint32), axis=0)
    assert len(unique) == len(expected) == len(np.unique(pick))
    np.testing.assert_array_equal(unique[inverse].view(np.uint32), points.view(np.uint32))
    assert weights.sum() == len(points)
    np.testing.assert_array_equal(np.bincount(inverse, minlength=len(unique)), weights)


def test_small_k_gives_the_weighted_mean() -> None:
    points = _sh_like(2000, 9, seed=13)
    centroids, labels = fit_palette(points, 1)
    assert labels.max() == 0
    np.testing.assert_allclose(centroids[0], points.mean(0, dtype=np.float64), atol=1e-6)


@pytest.mark.parametrize("k", [2, 7, 100])
def test_labels_point_at_nearby_centroids(k: int) -> None:
    points = _sh_like(3000, 9, seed=14)
    centroids, labels = fit_palette(points, k)
    assert len(centroids) == k and int(labels.max()) < k
    assert palette_mse(points, centroids, labels) < palette_mse(points, centroids[:1], labels * 0)


def test_progress_is_monotone_and_finishes() -> None:
    seen: list[float] = []
    fit_palette(_sh_like(3000, 45, seed=15), 1024, progress=seen.append)
    assert seen and seen[-1] == 1.0
    assert all(0.0 <= a <= b <= 1.0 for a, b in itertools.pairwise(seen))


MEASURED_FITS = {
    200_000: (
        (200000, 144378, 109149, 85154, 72169, 67173, 65892, 65594, 65545, 65540, 65537),
        3,
        (0.074, 0.224, 0.327, 0.392, 0.439, 0.478, 0.513, 0.545, 0.578, 0.61, 0.643, 0.676,
         0.816, 0.917, 0.998),
    ),
    833_000: (
        (833000, 544773, 367804, 238584, 152456, 102367, 77894, 68840, 66391, 65762, 65591,
         65548),
        8,
        (0.088, 0.257, 0.363, 0.432, 0.475, 0.5, 0.516, 0.527, 0.536, 0.545, 0.553, 0.562,
         0.571, 0.67, 0.719, 0.763, 0.809, 0.857, 0.905, 0.952, 0.999),
    ),
}  # fmt: skip
"""Fits of random SH3 vectors into 65536 measured on 2026-11-28: the clusters each merging
round started with, the refinement passes that followed, and the share of the fit's time
at which each step (the set-up, every round, every pass) ended."""


@pytest.mark.parametrize("vectors", sorted(MEASURED_FITS))
def test_progress_follows_the_time_of_a_measured_fit(vectors: int) -> None:
    """Replaying a real fit's rounds and passes, the progress said after each step is within
    0.07 of the share of the fit's time then gone (the model before 2026-11-28 lagged 0.10
    behind through the 833k fit's refinement: the first ETA of a 5M scene said 74 s for 48 s
    left), and stays below 1 until the fit returns."""
    k, seen = 65536, list[float]()
    rounds, passes, times = MEASURED_FITS[vectors]
    expected = min(10, max(2, int(PASSES_BASE + PASSES_PER_RATIO * vectors / k)))
    assert expected == passes
    work = _Work(vectors, k, expected, seen.append)
    work.set_up()
    for clusters, left in zip(rounds, [*rounds[1:], k], strict=True):
        work.merged(clusters, left - k)
    for _ in range(passes):
        work.refined()
    assert len(seen) == len(times)
    off = np.asarray(seen[:-1], np.float64) - times[:-1]
    assert bool(np.all(np.abs(off) <= 0.07)), np.round(off, 3)
    assert all(a <= b < 1.0 for a, b in itertools.pairwise(seen))


def test_zero_iterations_still_returns_a_palette() -> None:
    points = _sh_like(3000, 24, seed=16)
    centroids, labels = fit_palette(points, 256, iterations=0)
    assert len(centroids) == 256 and int(labels.max()) < 256


def test_bad_arguments() -> None:
    good = np.zeros((10, 9), np.float32)
    with pytest.raises(InputError):
        fit_palette(np.zeros(9, np.float32))
    with pytest.raises(InputError):
        fit_palette(np.zeros((0, 9), np.float32))
    with pytest.raises(InputError):
        fit_palette(np.full((4, 9), np.nan, np.float32))
    with pytest.raises(InputError):
        fit_palette(good, 0)
    with pytest.raises(InputError):
        fit_palette(good, 4, iterations=-1)


@pytest.mark.parametrize(("n", "dim"), [(2, 1), (3, 45), (5, 3), (257, 1), (300, 45)])
def test_tiny_inputs_give_exactly_k_entries(n: int, dim: int) -> None:
    points = np.random.default_rng(n + dim).normal(0, 1, (n, dim)).astype(np.float32)
    for k in sorted({1, max(1, n // 3), n - 1}):
        centroids, labels = fit_palette(points, k)
        assert centroids.shape == (k, dim) and int(labels.max()) < k


def test_vectors_handed_over_are_freed_before_the_fit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Vectors passed with no other reference (as the encoder passes them) are gone once the
    distinct rows are known: the fit holds one copy of the SH data, not two."""
    gone: list[bool] = []
    real_fit = sh_palette._fit

    def watching(*args: object, **kwargs: object) -> object:
        gone.append(handed() is None)
        return real_fit(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(sh_palette, "_fit", watching)
    held = [_sh_like(3000, 45, seed=4)]
    handed = weakref.ref(held[0])
    centroids, labels = fit_palette(held.pop(), 512, seed=1)
    assert gone == [True] and len(centroids) == 512 and len(labels) == 3000


def test_work_in_blocks_gives_what_whole_arrays_give(monkeypatch: pytest.MonkeyPatch) -> None:
    """Merging (its means copied or compacted in place), leaf neighbours, tree coordinates,
    the refinement's cluster means and the distinct-row check work a block of rows at a time
    to bound memory; blocks of a few rows give the same results as one block of everything,
    and a row matched to a different row is seen in the last block too. The tree's coordinates
    agree to float32 rounding: BLAS may round a product of a few rows unlike one of many
    (OpenBLAS's small-matrix kernels on an AMD EPYC, 3.6e-7 at most here)."""
    points = _sh_like(2000, 45, seed=8)
    rng = np.random.default_rng(3)
    mass = rng.random(2000) + 0.5
    partner = rng.integers(0, 2000, 2000)
    movers = palette_kernels.pick_moves(partner, rng.random(2000), 600)
    leaves = palette_kernels.leaves(points[:, :4].T.copy(), 64)
    repeated = points[rng.integers(0, 2000, 2000)]
    axes = palette_kernels.principal_axes(points, mass)
    centroids = points[:300].copy()
    labels = rng.integers(0, 299, 2000)  # the last centroid has no point: it moves

    def run() -> list[npt.NDArray[np.generic]]:
        merged = palette_kernels.merge(points, mass, movers, partner, own=False)
        compacted = palette_kernels.merge(points.copy(), mass, movers, partner, own=True)
        near = palette_kernels.leaf_neighbours(points, *leaves, 3)
        coords = palette_kernels.tree_coords(points, axes, 1, np.random.default_rng(2))
        means = palette_kernels.update(points, mass, centroids, labels)
        summed = palette_kernels.principal_axes(
            points, mass
        )  # its own blocks: COVARIANCE_BLOCK_BYTES
        found: list[npt.NDArray[np.generic]] = [*merged, *compacted, near, coords, *means]
        return [*found, *summed, *palette_kernels.unique_rows(repeated)]

    whole = run()
    for copied, in_place in zip(whole[:3], whole[3:6], strict=True):
        np.testing.assert_array_equal(copied, in_place)
    fitted = sh_palette.fit_palette(points, 256, seed=2)
    monkeypatch.setattr(columns, "BLOCK_BYTES", 1024)
    for fit, again in zip(fitted, sh_palette.fit_palette(points, 256, seed=2), strict=True):
        np.testing.assert_array_equal(fit, again)  # the whole fit: only the covariance's blocks
    blocked = run()
    coords = 7  # after the merged and compacted triples and the neighbours: a BLAS product
    for k in (k for k in range(len(whole)) if k != coords):
        np.testing.assert_array_equal(whole[k], blocked[k])
    np.testing.assert_allclose(
        whole[coords].astype(np.float64), blocked[coords].astype(np.float64), rtol=0, atol=1e-6
    )
    _, first, inverse = np.unique(repeated, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    assert palette_kernels._each_matches(repeated, first, inverse)
    inverse[-1] = (inverse[-1] + 1) % len(first)  # the last row matched to another row
    assert not palette_kernels._each_matches(repeated, first, inverse)


def test_cluster_means_are_each_clusters_weighted_mean() -> None:
    """The refinement's new centroids are each cluster's weighted mean summed in float64 in
    point order, bit for bit (a cluster's sum as ``np.bincount`` adds it), and an empty
    cluster takes the worst-served point."""
    points = _sh_like(3000, 45, seed=9)
    rng = np.random.default_rng(4)
    weights = rng.random(3000) + 0.5
    labels = rng.integers(0, 199, 3000)
    centroids = points[:200].copy()
    moved, relabelled = palette_kernels.update(points, weights, centroids, labels)
    mass = np.bincount(labels, weights, minlength=200)
    for coordinate in (0, 17, 44):
        sums = np.bincount(labels, weights * points[:, coordinate], minlength=200)
        expected = (sums[:199] / mass[:199]).astype(np.float32)
        np.testing.assert_array_equal(moved[:199, coordinate], expected)
    worst = int(relabelled[relabelled != labels][0])
    assert worst == 199 and np.count_nonzero(relabelled != labels) == 1
    np.testing.assert_array_equal(moved[199], points[np.flatnonzero(relabelled == 199)[0]])


def test_merged_means_are_each_hosts_weighted_mean_with_its_movers_in_order() -> None:
    """A merging round's grown means equal the host's and its movers' weighted sum taken in
    mover order in float64 (the sums of the palette before it folded a block of hosts at a
    time), bit for bit, copied or compacted in place, with blocks of a few rows too."""
    points = _sh_like(3000, 45, seed=10)
    rng = np.random.default_rng(5)
    mass = rng.random(3000) + 0.5
    partner = rng.integers(0, 40, 3000)  # few hosts, many movers each
    movers = np.flatnonzero(np.arange(3000) >= 40)
    target = np.arange(3000)
    target[movers] = partner[movers]
    expected = points[:40].astype(np.float64) * mass[:40, None]
    np.add.at(expected, target[movers], points[movers].astype(np.float64) * mass[movers, None])
    total = mass.copy()
    np.add.at(total, target[movers], mass[movers])
    expected = (expected / total[:40, None]).astype(np.float32)
    for block_bytes in (BLOCK_BYTES, 1024):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(columns, "BLOCK_BYTES", block_bytes)
            for own in (False, True):
                merged, _, _ = palette_kernels.merge(points.copy(), mass, movers, partner, own=own)
                np.testing.assert_array_equal(merged, expected)


def _colour_rms(vectors: F32, centroids: F32, labels: npt.ArrayLike) -> float:
    """RMS over vectors, channels and view directions of the colour error the bands make."""
    return math.sqrt(palette_mse(vectors, centroids, labels) * COLOUR_PER_SQUARED)


def test_colour_per_squared_is_the_mean_over_view_directions() -> None:
    """An f_rest error vector's squared colour error averaged over the sphere (the renderer's
    basis, 20000 evenly spread directions) and the three channels is its squared length
    times COLOUR_PER_SQUARED."""
    count = 20000
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    ring = np.sqrt(1.0 - z * z)
    angle = math.pi * (1.0 + math.sqrt(5.0)) * index
    dirs = np.stack([ring * np.cos(angle), ring * np.sin(angle), z], axis=1)
    basis = sh_basis(dirs, 16)[:, 1:]  # the bands beyond DC
    errors = np.random.default_rng(2).standard_normal((5, 3, 15))  # channel-major, as f_rest
    for error in errors:
        colour = basis @ error.T  # (directions, channels)
        mean_square = float(np.mean(colour**2))
        assert mean_square == pytest.approx(np.sum(error**2) * COLOUR_PER_SQUARED, rel=2e-3)


@pytest.mark.parametrize("slack", [0.0005, 0.002, 0.01])
def test_a_slack_merges_entries_while_the_colour_error_stays_within_it(slack: float) -> None:
    vectors = _sh_like(4000, 45, seed=5)
    full, full_labels = fit_palette(vectors, 1024, seed=2)
    centroids, labels = fit_palette(vectors, 1024, seed=2, slack=slack)
    assert len(centroids) < len(full) and int(labels.max()) < len(centroids)
    assert len(np.unique(labels)) == len(centroids)  # no entry left unused
    within = _colour_rms(vectors, full, full_labels) + slack
    assert _colour_rms(vectors, centroids, labels) <= within * (1 + 1e-5)
    assert _colour_rms(vectors, centroids, labels) > within - 2 * slack  # the slack is spent


def test_larger_slacks_keep_fewer_entries() -> None:
    vectors = _sh_like(4000, 45, seed=6)
    sizes = [len(fit_palette(vectors, 1024, seed=1, slack=s)[0]) for s in (0.0, 0.001, 0.004)]
    assert sizes[0] == 1024 and sizes[0] > sizes[1] > sizes[2]


def test_merged_entries_are_the_means_of_their_vectors() -> None:
    """Ward merging keeps every entry the weighted mean of the vectors labelled with it, which
    makes each merge's added error exact."""
    vectors = _sh_like(3000, 24, seed=7)
    centroids, labels = fit_palette(vectors, 512, seed=3, slack=0.003)
    for entry in range(0, len(centroids), 17):
        members = vectors[labels == entry].astype(np.float64)
        assert np.allclose(centroids[entry], members.mean(axis=0), atol=1e-5)


def test_an_exact_palette_merges_within_its_slack_too() -> None:
    """Fewer distinct vectors than k: the palette starts exact (no error) and its slack
    alone bounds the error."""
    distinct = _sh_like(300, 45, seed=8)
    vectors = distinct[np.random.default_rng(0).integers(0, 300, 5000)]
    exact, exact_labels = fit_palette(vectors, 1024)
    assert palette_mse(vectors, exact, exact_labels) == 0.0
    centroids, labels = fit_palette(vectors, 1024, slack=0.002)
    assert 1 <= len(centroids) < len(exact)
    assert _colour_rms(vectors, centroids, labels) <= 0.002 * (1 + 1e-5)


@pytest.mark.parametrize("slack", [-0.001, math.nan])
def test_a_negative_or_missing_slack_is_refused(slack: float) -> None:
    with pytest.raises(InputError, match="slack"):
        fit_palette(_sh_like(100, 9, seed=1), 16, slack=slack)
