"""Morton order: a permutation, spatially coherent, refined inside crowded cells."""

from __future__ import annotations

import numpy as np
import pytest

from tsog_stream.morton import morton_order, morton_parts, morton_run


def test_is_a_permutation_and_deterministic() -> None:
    pts = np.random.default_rng(1).normal(size=(5000, 3)).astype(np.float32)
    order = morton_order(pts)
    assert sorted(order.tolist()) == list(range(5000))
    assert np.array_equal(order, morton_order(pts))


def test_grid_follows_z_curve() -> None:
    # 2x2x2 corners: code = x | y<<1 | z<<2 gives this exact order.
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float32)
    shuffled = corners[::-1].copy()
    order = morton_order(shuffled)
    np.testing.assert_array_equal(shuffled[order], corners)


def test_crowded_cell_is_refined() -> None:
    rng = np.random.default_rng(2)
    far = np.array([[1000.0, 1000.0, 1000.0]], np.float32)
    cluster = rng.uniform(0, 1e-3, (2000, 3)).astype(np.float32)  # all in one top-level cell
    pts = np.concatenate([far, cluster])
    order = morton_order(pts)
    inner = pts[order[:-1]]
    jumps = np.linalg.norm(np.diff(inner, axis=0), axis=1)
    assert np.median(jumps) < 1e-4  # neighbours in texel order are neighbours in space


def test_degenerate_inputs() -> None:
    assert morton_order(np.zeros((0, 3))).size == 0
    same = np.ones((300, 3), np.float32)
    assert np.array_equal(morton_order(same), np.arange(300))
    bad = np.array([[np.nan, 0, 0], [1, 1, 1]], np.float32)
    assert sorted(morton_order(bad).tolist()) == [0, 1]


def test_a_run_is_the_same_gaussians_as_that_run_of_the_whole_order() -> None:
    """morton_run picks by partial selection; on distinct cells it selects exactly the slice
    the full sort would, and returns it in Morton order."""
    pts = np.random.default_rng(3).normal(size=(20_000, 3)).astype(np.float32)
    whole = morton_order(pts)
    for start, count in [(0, 100), (9_000, 2_048), (19_000, 1_000), (0, 20_000)]:
        run = morton_run(pts, start, count)
        np.testing.assert_array_equal(np.sort(run), np.sort(whole[start : start + count]))
        np.testing.assert_array_equal(run, run[morton_order(pts[run])])


def test_a_run_of_crowded_or_degenerate_points_is_still_a_run() -> None:
    """Ties (many Gaussians per cell) and degenerate boxes give a run of the asked length
    without repeats; a run outside the scene is refused."""
    crowded = np.random.default_rng(4).integers(0, 4, (5_000, 3)).astype(np.float32)
    for pts in (crowded, np.zeros((300, 3), np.float32), np.full((50, 3), np.nan, np.float32)):
        run = morton_run(pts, 10, 40)
        assert run.size == 40 and np.unique(run).size == 40
    with pytest.raises(ValueError, match="outside"):
        morton_run(crowded, 4_990, 20)


def test_parts_are_the_runs_of_the_whole_order_cut_as_array_split_cuts() -> None:
    """morton_parts cuts by partial selection: on distinct cells each part is exactly that
    run of the full sort (as np.array_split sizes the runs), its members ascending; crowded
    or degenerate points still give every index once, in parts of those sizes."""
    pts = np.random.default_rng(5).normal(size=(20_011, 3)).astype(np.float32)
    whole = morton_order(pts)
    for parts in (1, 2, 6, 7):
        got = morton_parts(pts, parts)
        runs = np.array_split(whole, parts)
        assert [p.size for p in got] == [r.size for r in runs]
        for part, run in zip(got, runs, strict=True):
            np.testing.assert_array_equal(part, np.sort(run))
    crowded = np.random.default_rng(4).integers(0, 4, (5_000, 3)).astype(np.float32)
    for pts in (crowded, np.zeros((300, 3), np.float32), np.full((50, 3), np.nan, np.float32)):
        got = morton_parts(pts, 4)
        assert [p.size for p in got] == [a.size for a in np.array_split(np.arange(len(pts)), 4)]
        assert np.array_equal(np.sort(np.concatenate(got)), np.arange(len(pts)))
        assert all(np.all(np.diff(p) > 0) for p in got)
