"""Temporal evaluation: visibility per timeline type and polynomial attributes at t."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from tsog_stream import Gaussians, InputError, Scene, Timeline, TimelineType
from tsog_stream.model import count_at, evaluate_all, opacity_at, shown_at
from tsog_stream.temporal import lifespans, recentre, time_range, visibility_half_width


def f64(values: list[float]) -> npt.NDArray[np.float64]:
    """Times as the model holds them."""
    return np.asarray(values, np.float64)


def _gaussians(n: int) -> Gaussians:
    z = np.zeros((n, 3), np.float32)
    quats = np.tile(np.array([1.0, 0, 0, 0], np.float32), (n, 1))
    return Gaussians(z, z.copy(), quats, np.full(n, 2.0, np.float32), z.copy())


def test_frame_ids_select_their_frame_only() -> None:
    tl = Timeline(TimelineType.FRAME, f64([0, 1, 2, 2]), np.zeros(4), fps=10)
    scene = Scene(_gaussians(4), tl)
    assert len(scene.at(0.0)) == 1
    assert len(scene.at(0.1)) == 1  # exactly at 1/fps: frame 1 despite float rounding
    assert len(scene.at(0.2999)) == 2
    assert len(scene.at(0.3)) == 0


def test_start_duration_is_half_open() -> None:
    tl = Timeline(TimelineType.START_DURATION, f64([0, 5]), f64([5, 5]), fps=10)
    scene = Scene(_gaussians(2), tl)
    assert [len(scene.at(t)) for t in (0.0, 0.49, 0.5, 0.99, 1.0)] == [1, 1, 1, 1, 0]
    assert scene.at(0.5).opacities[0] == pytest.approx(2.0)


def test_center_scale_scales_opacity_and_cuts_at_threshold() -> None:
    tl = Timeline(TimelineType.CENTER_SCALE, f64([1.0]), f64([0.5]))
    scene = Scene(_gaussians(1), tl)
    alpha = 1 / (1 + math.exp(-2.0))
    at = scene.at(1.5)  # one sigma away: factor exp(-1/2)
    got = 1 / (1 + math.exp(-float(at.opacities[0])))
    assert got == pytest.approx(alpha * math.exp(-0.5), rel=1e-6)
    edge = 0.5 * visibility_half_width()
    assert len(scene.at(1.0 + edge * 0.999)) == 1
    assert len(scene.at(1.0 + edge * 1.001)) == 0
    start, end = lifespans(tl)
    assert start[0] == pytest.approx(1.0 - edge) and end[0] == pytest.approx(1.0 + edge)


def test_polynomial_motion_and_quaternion_renormalisation() -> None:
    tl = Timeline(TimelineType.START_DURATION, f64([10.0]), f64([100.0]), fps=10)  # starts at 1 s
    means = np.zeros((1, 1, 3), np.float32)
    means[0, :, 0] = [2.0]  # 2 units per second along x
    quats = np.zeros((1, 2, 4), np.float32)
    quats[0, 1, 1] = 1.0  # second order term on x component
    scene = Scene(
        _gaussians(1),
        tl,
        {"means": np.concatenate([means, np.zeros((1, 1, 3))], 1), "quats": quats},
    )
    g = scene.at(3.0)  # dt = 2 s
    assert g.means[0, 0] == pytest.approx(4.0)
    q = np.array([1.0, 4.0, 0, 0]) / math.sqrt(17)
    np.testing.assert_allclose(g.quats[0], q, rtol=1e-6)


def test_evaluate_all_keeps_alignment() -> None:
    tl = Timeline(TimelineType.FRAME, f64([0, 1]), np.zeros(2), fps=1)
    g, mask = evaluate_all(Scene(_gaussians(2), tl), 0.5)
    assert len(g) == 2 and mask.tolist() == [True, False]


@pytest.mark.parametrize("kind", list(TimelineType))
def test_opacity_at_is_what_evaluation_gives_the_visible(kind: TimelineType) -> None:
    """opacity_at: the evaluated opacity of every visible Gaussian (temporal opacity and the
    type-2 factor included), -inf for the others, without evaluating anything else."""
    n = 6
    rng = np.random.default_rng(2)
    g = _gaussians(n)
    g = Gaussians(g.means, g.scales, g.quats, rng.normal(0, 2, n).astype(np.float32), g.sh0)
    t0 = {
        TimelineType.FRAME: f64([0, 4, 4, 2, 4, 0]),
        TimelineType.START_DURATION: f64([0, 3, 5, 9, 1, 2]),
    }
    t1 = {TimelineType.FRAME: np.zeros(n), TimelineType.START_DURATION: f64([4, 4, 1, 2, 8, 1])}
    if kind is TimelineType.CENTER_SCALE:
        tl = Timeline(
            kind, f64([0.1, 0.4, 0.45, 0.9, 0.3, 2.0]), f64([0.1, 0.2, 0.05, 0.1, 1, 0.1])
        )
    else:
        tl = Timeline(kind, t0[kind], t1[kind], fps=10)
    opacity = rng.normal(0, 1, (n, 2, 1)).astype(np.float32)
    scene = Scene(g, tl, {"opacity": opacity})
    evaluated, shown = evaluate_all(scene, 0.4)
    got = opacity_at(scene, 0.4)
    assert 0 < shown.sum() < n
    assert np.array_equal(got[shown], scene.at(0.4).opacities)
    assert np.array_equal(got[shown], evaluated.opacities[shown])
    assert np.all(got[~shown] == -np.inf)
    for t in (0.0, 0.15, 0.4, 0.9):
        assert count_at(scene, t) == len(scene.at(t))  # counted without evaluating
        rows = scene.subset(np.flatnonzero(shown_at(scene, t)))
        assert np.array_equal(rows.gaussians.means, scene.at(t).means)
    assert count_at(Scene(g), 0.4) == n


def test_time_range_prefers_declared_length() -> None:
    tl = Timeline(TimelineType.FRAME, f64([0, 29]), np.zeros(2), fps=30)
    assert time_range(tl) == pytest.approx((0.0, 1.0))
    tl2 = Timeline(TimelineType.FRAME, f64([0, 29]), np.zeros(2), fps=30, scene_length=2.0)
    assert time_range(tl2) == (0.0, 2.0)


@pytest.mark.parametrize("t", [math.nan, math.inf])
def test_non_finite_time_is_an_input_error(t: float) -> None:
    scene = Scene(_gaussians(1), Timeline(TimelineType.FRAME, f64([0]), f64([0]), fps=1))
    with pytest.raises(InputError):
        scene.at(t)


def test_bad_timelines_are_refused() -> None:
    with pytest.raises(InputError, match="fps"):
        Timeline(TimelineType.CENTER_SCALE, f64([0]), f64([1]), fps=30)
    with pytest.raises(InputError, match="scales must be positive"):
        Timeline(TimelineType.CENTER_SCALE, f64([0]), f64([0]))
    with pytest.raises(InputError, match="temporal"):
        Scene(_gaussians(1), None, {"means": np.zeros((1, 1, 3), np.float32)})
    with pytest.raises(InputError, match=r"temporal\.means"):
        Scene(
            _gaussians(1),
            Timeline(TimelineType.FRAME, f64([0]), f64([0])),
            {"means": np.zeros((1, 1, 4), np.float32)},
        )


@pytest.mark.parametrize("kind", [TimelineType.START_DURATION, TimelineType.CENTER_SCALE])
def test_recentre_keeps_every_trajectory(kind: TimelineType) -> None:
    """A scene re-expanded about other reference times evaluates to the same attributes at
    every t (the encoder stores positions at the reference time the decoder reads)."""
    rng = np.random.default_rng(5)
    n = 500
    g = Gaussians.from_arrays(
        rng.normal(0, 2, (n, 3)),
        rng.normal(-3, 0.5, (n, 3)),
        rng.normal(0, 1, (n, 4)),
        rng.normal(0, 1, n),
        rng.normal(0, 1, (n, 3)),
    )
    timeline = Timeline(kind, rng.uniform(0, 10, n), rng.uniform(1, 3, n), scene_length=10.0)
    orders = {"means": (3, 3), "quats": (2, 4), "scales": (1, 3), "sh0": (2, 3), "opacity": (2, 1)}
    temporal = {a: rng.normal(0, 0.3, (n, k, c)).astype(np.float32) for a, (k, c) in orders.items()}
    scene = Scene(g, timeline, temporal)
    moved = scene.subset(np.arange(n))
    shn = moved.gaussians.shN
    recentre(moved, timeline.t0 + rng.uniform(-0.5, 0.5, n))
    assert moved.timeline is not None and not np.allclose(moved.timeline.t0, timeline.t0)
    assert moved.gaussians.shN is shn  # nothing but what moves is replaced
    for t in (0.5, 4.0, 9.5):
        was, _ = evaluate_all(scene, t, threshold=1e-6)
        now, _ = evaluate_all(moved, t, threshold=1e-6)
        for attr in ("means", "scales", "quats", "sh0"):
            assert np.allclose(getattr(now, attr), getattr(was, attr), atol=2e-4), attr
        if kind is TimelineType.START_DURATION:  # type 2's factor follows the centre
            assert np.allclose(now.opacities, was.opacities, atol=2e-4)


def test_recentre_without_motion_only_moves_the_reference_times() -> None:
    g = _gaussians(3)
    means = g.means
    scene = Scene(g, Timeline(TimelineType.CENTER_SCALE, f64([1, 2, 3]), f64([1, 1, 1])))
    recentre(scene, f64([1.5, 2, 2.5]))
    assert scene.timeline is not None and list(scene.timeline.t0) == [1.5, 2, 2.5]
    assert scene.gaussians.means is means and not scene.temporal
