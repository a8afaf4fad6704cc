"""Error-budgeted precision (``--quality``, codec/precision.py): each Gaussian's position
over the times it is visible (root mean square and worst) and its lifespan stay within the
budgets docs/spec.md §5.1 states, against the same chunk at quality 100; files shrink as the
quality drops."""

from __future__ import annotations

import io
import json
import math
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from tsog_stream import columns
from tsog_stream.cli.main import main
from tsog_stream.codec.budgets import (
    ALPHA_AT_ZERO,
    COLOUR_AT_ZERO,
    CORE_AT_ZERO,
    FAINT_MAX,
    MAX_TURN,
    MOTION_AT_ZERO,
    POSITION_AT_ZERO,
    SCALE_AT_ZERO,
    TIME_AT_ZERO,
    TURN_SURFACE,
    Budgets,
    budget_fraction,
    rms_room,
    stretch,
)
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.codec.coarsen import coarsen, most_frequent, to_codes
from tsog_stream.codec.sh_bands import encode_sh_bands
from tsog_stream.codec.tsog_images import quantize_timeline
from tsog_stream.constants import SH_C0
from tsog_stream.errors import InputError
from tsog_stream.framing import dense_core
from tsog_stream.model import Gaussians, Scene, Timeline, TimelineType, reference_times
from tsog_stream.opacity import alpha_to_logit, logit_to_alpha
from tsog_stream.sh_palette import COLOUR_PER_SQUARED
from tsog_stream.synthetic import freetime_scene, small_scene, static_gaussians
from tsog_stream.temporal import lifespans, recentre, time_range


@pytest.fixture(scope="module")
def scene() -> Scene:
    """4000 moving Gaussians with type-2 lifespans of 5-50 % of a 10 s clip."""
    return freetime_scene(static_gaussians(4000, seed=3), duration_s=10.0, lifespan=(0.05, 0.5))


SAMPLES = 64
"""Times per lifespan the position bounds are checked at."""


def _positions(s: Scene, t: np.ndarray) -> np.ndarray:
    """Each Gaussian's position at its own time t[i] (base + linear motion)."""
    assert s.timeline is not None
    dt = t - reference_times(s.timeline)
    return s.gaussians.means + s.temporal["means"][:, 0, :] * dt[:, None]


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Radians between the rotations of two sets of quaternions."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.asarray(2 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=1)), 0.0, 1.0)))


def test_quality_100_is_todays_precision(scene: Scene) -> None:
    assert encode_chunk(scene, quality=100) == encode_chunk(scene)


def _position_budget(scene: Scene, quality: int) -> np.ndarray:
    """P of docs/spec.md §5.1 for each Gaussian of ``scene``, in its chunk's texel order."""
    f = budget_fraction(quality)
    logits = scene.gaussians.opacities[texel_order(scene)]  # the source's, as the encoder sees
    alpha = logit_to_alpha(logits).reshape(len(scene))
    _, radius = dense_core(scene.gaussians)  # the chunk's core: the same Gaussians, any order
    stretch = 1 + (POSITION_AT_ZERO - 1) * f**4  # within 6 % of 1 down to quality 50
    return np.asarray(f * stretch * CORE_AT_ZERO * radius / np.maximum(alpha, 1 / FAINT_MAX))


def _fade(timeline: Timeline, t: np.ndarray) -> np.ndarray:
    """g(t) of docs/spec.md §5.1: the type-2 temporal opacity factor (1 for other types)."""
    if timeline.type is not TimelineType.CENTER_SCALE:
        return np.ones_like(t)
    return np.asarray(np.exp(-0.5 * ((t - timeline.t0) / timeline.t1) ** 2))


def _moved(full: Scene, cut: Scene) -> tuple[np.ndarray, np.ndarray]:
    """How far each Gaussian of ``cut`` is from ``full`` over the part of its lifespan inside
    the scene (nothing is drawn outside it), times g(t) (an error shows as much as the
    Gaussian is drawn): the worst axis at the worst time, and the largest of its axes' root
    mean squares."""
    assert full.timeline is not None
    start, end = lifespans(full.timeline)
    first, last = time_range(full.timeline)
    start, end = np.maximum(start, first), np.minimum(end, last)
    worst, squares = np.zeros(len(full)), np.zeros((len(full), 3))
    for share in (np.arange(SAMPLES) + 0.5) / SAMPLES:  # midpoints: never above the true mean
        t = start + share * (end - start)
        moved = np.abs(_positions(cut, t) - _positions(full, t))
        moved *= _fade(full.timeline, t)[:, None]
        worst, squares = np.maximum(worst, moved.max(axis=1)), squares + moved**2
    return worst, np.sqrt(squares / SAMPLES).max(axis=1)


def _kept_whole_at_times_of(ordered: Scene, cut: Scene) -> Scene:
    """``ordered`` (a scene in its chunk's texel order) re-expanded about the reference times
    of ``cut`` (its chunk at a lower quality) and written at quality 100: the cut differs
    from it only by what the quality rounded (a rounded t_ref moves nothing, docs/spec.md
    §5.1)."""
    assert cut.timeline is not None
    same_times = ordered.subset(np.arange(len(ordered)))
    recentre(same_times, cut.timeline.t0)
    return decode_chunk(encode_chunk(same_times, order=np.arange(len(ordered))))


@pytest.mark.parametrize("quality", [90, 50, 0])
def test_positions_and_lifespans_stay_within_their_budgets(scene: Scene, quality: int) -> None:
    full = decode_chunk(encode_chunk(scene))
    cut = decode_chunk(encode_chunk(scene, quality=quality))
    assert full.timeline is not None and cut.timeline is not None
    f = budget_fraction(quality)
    budget = _position_budget(scene, quality)
    ordered = scene.subset(texel_order(scene))  # the decoded chunks' order
    worst, rms = _moved(_kept_whole_at_times_of(ordered, cut), cut)
    budgets = Budgets.of(ordered, quality)
    assert budgets is not None and budgets.around_reference.all()  # centres inside the clip
    motion = stretch(f, MOTION_AT_ZERO)  # the motion's thirds
    assert budgets.motion_stretch == motion
    assert np.all(rms <= budget * (1 + motion) / 3 * 1.0001 + 1e-6)
    linear = (1 + rms_room(1) * motion) / 3  # the base a third; the motion's sqrt(3) x a third
    assert np.all(worst <= budget * linear * 1.0001 + 1e-6)
    span_budget = f * TIME_AT_ZERO * full.timeline.t1
    assert np.all(np.abs(cut.timeline.t0 - full.timeline.t0) <= span_budget * 1.0001 + 1e-9)
    assert np.all(np.abs(cut.timeline.t1 - full.timeline.t1) <= span_budget * 1.0001 + 1e-9)
    source = ordered.gaussians
    for attr, slack in (("scales", f * SCALE_AT_ZERO), ("sh0", f * COLOUR_AT_ZERO / SH_C0)):
        was = np.abs(getattr(full.gaussians, attr) - getattr(source, attr))
        now = np.abs(getattr(cut.gaussians, attr) - getattr(source, attr))
        assert np.all(now <= was + slack + 1e-5), attr
    alpha = [logit_to_alpha(g.opacities) for g in (cut.gaussians, full.gaussians)]
    assert np.all(np.abs(alpha[0] - alpha[1]) <= f * ALPHA_AT_ZERO + 1 / 255 + 1e-6)
    sigmas = np.exp(full.gaussians.scales.astype(np.float64))
    spread = sigmas.max(axis=1) - sigmas.min(axis=1)
    turn_budget = np.minimum(TURN_SURFACE * budget / np.maximum(spread, 1e-30), MAX_TURN)
    assert np.all(_turn(cut.gaussians.quats, full.gaussians.quats) <= turn_budget + 1e-3)
    if quality <= 50:
        assert worst.max() > budget.max() / 100  # the budget is used, not ignored


def _bands_colour_rms(decoded: Gaussians, source: Gaussians) -> float:
    """RMS over Gaussians, channels and view directions of the colour error of the SH bands."""
    squared = np.sum((decoded.shN.astype(np.float64) - source.shN) ** 2, axis=(1, 2))
    return math.sqrt(float(np.mean(squared)) * COLOUR_PER_SQUARED)


@pytest.mark.parametrize("quality", [90, 75])
def test_the_sh_bands_colour_error_grows_within_the_colour_slack(quality: int) -> None:
    """docs/spec.md §5.1: below 100 the palette's entries merge while the bands' colour error
    (RMS over Gaussians and view directions) stays within its quality-100 palette's plus
    f · 0.1 (decoded: through the 8-bit codebook as well); an SH-band chunk alike."""
    scene = Scene(static_gaussians(3000, sh_bands=3, seed=4))
    source = scene.subset(texel_order(scene)).gaussians
    full, cut = encode_chunk(scene), encode_chunk(scene, quality=quality)
    entries = [json.loads(files["meta.json"])["shN"]["count"] for files in (full, cut)]
    assert entries[1] < entries[0] == 2048
    was = _bands_colour_rms(decode_chunk(full).gaussians, source)
    now = _bands_colour_rms(decode_chunk(cut).gaussians, source)
    slack = budget_fraction(quality) * COLOUR_AT_ZERO
    assert was + 0.5 * slack < now <= was + slack * 1.02
    bands = [encode_sh_bands(scene, quality=q) for q in (100, quality)]
    assert bands[0] == encode_sh_bands(scene)
    counts = [json.loads(files["meta.json"])["shN"]["count"] for files in bands]
    assert counts[1] == entries[1] < counts[0]


def test_motion_seen_away_from_its_reference_time_keeps_the_worst_case_bound() -> None:
    """A type-2 Gaussian centred before the clip shows only its fading tail inside it, a part
    of its lifespan without t_ref: its position stays within P at every time there (the root
    mean square's room is only for lifespans holding t_ref)."""
    base = freetime_scene(static_gaussians(2000, seed=5), duration_s=10.0, lifespan=(0.2, 0.5))
    assert base.timeline is not None
    start, end = lifespans(base.timeline)
    early = np.arange(len(base)) % 2 == 0
    centre = np.where(early, -0.25 * (end - start), base.timeline.t0)  # a quarter visible
    timeline = Timeline(TimelineType.CENTER_SCALE, centre, base.timeline.t1, scene_length=10.0)
    scene = Scene(base.gaussians, timeline, base.temporal)
    full = decode_chunk(encode_chunk(scene))
    cut = decode_chunk(encode_chunk(scene, quality=0))
    budget = _position_budget(scene, 0)
    worst, rms = _moved(full, cut)
    budgets = Budgets.of(scene.subset(texel_order(scene)), 0)
    assert budgets is not None
    away = ~budgets.around_reference
    assert 0.3 < away.mean() < 0.7  # the early half
    within = (2 + MOTION_AT_ZERO) / 3  # at quality 0 the motion takes MOTION_AT_ZERO thirds
    assert np.all(worst[away] <= budget[away] * within * 1.0001 + 1e-6)
    assert np.all(rms <= budget * within * 1.0001 + 1e-6)
    velocity = np.abs(cut.temporal["means"][:, 0] - full.temporal["means"][:, 0])
    change = velocity.max(axis=1) * budgets.reach  # the motion's largest change
    share = budgets.position / 3 * MOTION_AT_ZERO
    assert np.all(change[away] <= share[away] * 1.0001 + 1e-9)
    assert np.any(change[away] > share[away] / 2)  # the share is used, not avoided
    assert np.all(velocity.max(axis=1) * budgets.motion_span(1) <= share * 1.0001 + 1e-9)
    assert np.any(change[~away] > share[~away])  # and the root mean square's room


@pytest.mark.parametrize("order", [1, 2, 3])
def test_the_motion_span_bounds_the_faded_root_mean_square(order: int) -> None:
    """motion_span(k) bounds the root mean square of g(t) (t - t_ref)^k over the part of each
    lifespan inside the scene (by quadrature, dense), for lifespans inside the clip, cut by
    its ends and longer than it; and a fading Gaussian gets more room than sqrt(2k + 1)."""
    rng = np.random.default_rng(order)
    n = 600
    centre = rng.uniform(-1.0, 11.0, n)
    scale = np.exp(rng.uniform(np.log(0.02), np.log(40.0), n))
    timeline = Timeline(TimelineType.CENTER_SCALE, centre, scale, scene_length=10.0)
    scene = Scene(static_gaussians(n, seed=order), timeline)
    budgets = Budgets.of(scene, 50)
    assert budgets is not None
    span = budgets.motion_span(order)
    for rows in (slice(0, 7), slice(595, 600)):  # a block's rows: those rows' values
        np.testing.assert_array_equal(budgets.motion_span(order, rows), span[rows])
        for attr, channels in (("means", 3), ("quats", 4), ("sh0", 4)):
            whole = budgets.change_over_lifespan(attr, channels)
            np.testing.assert_array_equal(
                budgets.change_over_lifespan(attr, channels, rows), whole[rows]
            )
    start, end = lifespans(timeline)
    start, end = np.maximum(start, 0.0), np.minimum(end, 10.0)
    held = budgets.around_reference
    t = start[:, None] + (np.arange(4096) + 0.5) / 4096 * (end - start)[:, None]
    weighed = np.exp(-0.5 * ((t - centre[:, None]) / scale[:, None]) ** 2)
    weighed *= np.abs(t - centre[:, None]) ** order
    rms = np.sqrt(np.mean(weighed**2, axis=1))
    assert np.all(rms[held] <= span[held] * 1.0001)
    worst = np.abs(t - centre[:, None]).max(axis=1) ** order
    away = ~held & (end > start)  # seen, but not at its centre
    assert away.sum() > 20 and np.all(worst[away] <= span[away] * 1.0001)
    uniform = budgets.reach**order / rms_room(order)
    whole_start, whole_end = lifespans(timeline)
    inside = (whole_start > 0.0) & (whole_end < 10.0)  # whole lifespans inside the clip
    assert inside.sum() > 20 and np.all(span[inside] < uniform[inside] / 4)


def test_positions_move_by_the_core_share_over_alpha_whatever_their_size() -> None:
    """At quality 0 a position may move by POSITION_AT_ZERO x CORE_AT_ZERO of the chunk's core
    radius over its alpha (at most FAINT_MAX times): flat Gaussians (smallest sigma 1e-6) move
    as far as round ones, faint ones further, never beyond; the means images shrink."""
    g = static_gaussians(4000, seed=8)
    g.scales[:2000, 0] = np.log(1e-6)  # flat
    alpha = np.where(np.arange(4000) % 4 == 0, 1 / 64, 0.9)  # a quarter faint (FAINT_MAX x)
    g.opacities = alpha_to_logit(alpha)
    scene = Scene(g)
    full, cut = (encode_chunk(scene, quality=q) for q in (100, 0))
    moved = np.abs(decode_chunk(cut).gaussians.means - decode_chunk(full).gaussians.means)
    moved = moved.max(axis=1)
    bound = _position_budget(scene, 0)
    assert np.all(moved <= bound * 1.0001 + 1e-7)
    ordered = scene.subset(texel_order(scene)).gaussians  # the decoded chunks' order
    flat = ordered.scales[:, 0] < np.log(1e-5)
    faint = logit_to_alpha(ordered.opacities) < 0.1
    opaque = bound[~faint].max()
    assert moved[flat & ~faint].max() > opaque / 4  # thin ones use the share too
    assert moved[faint].max() > 4 * opaque  # and faint ones their larger one
    sizes = [len(f["means_l.webp"]) for f in (full, cut)]
    assert sizes[1] < 0.8 * sizes[0], sizes


def test_lower_quality_writes_fewer_bytes(scene: Scene) -> None:
    sizes = [len(bundle_bytes(encode_chunk(scene, quality=q))) for q in (100, 75, 50, 0)]
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] < 0.85 * sizes[0]


def test_codebook_entries_no_label_uses_repeat_a_used_one(scene: Scene) -> None:
    """Below quality 100 the scale and colour labels move to fewer entries; the entries left
    unused repeat the one their labels went to (ascending still), so meta.json deflates them:
    it shrinks, and the decoded values are the same as if they had stayed."""
    files = encode_chunk(scene, quality=0)
    meta = json.loads(files["meta.json"])
    for attr, channels in (("scales", 3), ("sh0", 3)):
        image = np.asarray(Image.open(io.BytesIO(files[f"{attr}.webp"])))
        used = np.unique(image.reshape(-1, 4)[: len(scene), :channels])
        table = np.asarray(meta[attr]["codebook"])
        assert len(used) < 200 and np.all(np.diff(table) >= 0), attr
        assert len(np.unique(table)) == len(np.unique(table[used])), attr
    full = zlib.compress(encode_chunk(scene, quality=100)["meta.json"])
    assert len(zlib.compress(files["meta.json"])) < 0.7 * len(full)


def test_frame_ids_stay_exact() -> None:
    frames = static_gaussians(500, seed=1)
    ids = np.repeat(np.arange(5, dtype=np.float64), 100)
    timeline = Timeline(TimelineType.FRAME, ids, np.zeros(500), 30.0)
    back = decode_chunk(encode_chunk(Scene(frames, timeline), quality=0))
    assert back.timeline is not None
    assert sorted(back.timeline.t0.tolist()) == sorted(ids.tolist())


def test_coarsen_rounds_to_the_coarsest_grid_within_the_tolerance() -> None:
    """Grids of 1, 8 and 512 codes laid through each channel's most frequent code (here 0,
    1000, 65535 and 1000): a code rounding out of the range keeps its value."""
    codes = np.array([[0, 1000, 65535, 40000]] + [[0, 1000, 65535, 1000]] * 2, np.uint16)
    out = coarsen(codes, np.array([[0.4, 7.9, 300.0, 300.0]]), shared=True)
    assert out[0].tolist() == [0, 1000, 65535, 1000 + 76 * 512]  # 39912, 88 codes away
    assert out[1:].tolist() == codes[1:].tolist()  # the shared codes stay as they are
    assert np.all(np.abs(out.astype(int) - codes.astype(int)) <= [[0, 4, 256, 256]])
    plain = coarsen(codes[:1], np.array([[0.4, 7.9, 300.0, 300.0]]))  # grids through code 0
    assert plain.tolist() == [[0, 1000, 65535, 39936]]


def _coarsen_by_the_formula(codes: np.ndarray, tolerance: np.ndarray, shared: bool) -> np.ndarray:
    """coarsen written as its definition: steps 2^floor(log2(2 tol)) (1 below a tolerance of
    0.5, at most half the range), round half up on a grid through the anchor, in int64."""
    top = int(np.iinfo(codes.dtype).max)
    tol = np.broadcast_to(np.nan_to_num(tolerance, nan=0.0, posinf=float(top)), codes.shape)
    bits = np.floor(np.log2(np.maximum(2.0 * tol, 1.0)))
    grid = np.left_shift(1, np.clip(bits, 0, top.bit_length() - 1).astype(np.int64))
    q = codes.astype(np.int64)
    anchor = most_frequent(codes) if shared else 0
    rounded = (q - anchor + grid // 2) // grid * grid + anchor
    return np.where((rounded > top) | (rounded < 0), q, rounded).astype(codes.dtype)


@pytest.mark.parametrize("seed", range(4))
def test_coarsen_equals_its_formula(seed: int) -> None:
    """The int32 bit arithmetic (frexp for the step, & -grid for the floor) gives the
    formula's codes for 8- and 16-bit codes, tolerances of every shape and kind (0, below
    0.5, huge, negative, NaN, infinite), grids through 0 or the most frequent code."""
    rng = np.random.default_rng(seed)
    for dtype in (np.uint8, np.uint16):
        codes: Any = rng.integers(0, int(np.iinfo(dtype).max) + 1, (3000, 3)).astype(dtype)
        codes[:1000] = codes[0]
        for shape in [(3000, 3), (3000, 1), (3,)]:
            tol = np.exp(rng.normal(0.0, 5.0, shape))
            for value in (np.inf, np.nan, 0.0, 0.5, -3.0):
                tol[rng.random(shape) < 0.04] = value
            for shared in (False, True):
                out = coarsen(codes, tol, shared=shared)
                assert out.dtype == codes.dtype
                np.testing.assert_array_equal(out, _coarsen_by_the_formula(codes, tol, shared))
        for value in (np.inf, np.nan, 0.0, 0.4, 3.0, 700.0, -3.0):  # one tolerance for all
            for shared in (False, True):
                out = coarsen(codes, np.asarray(value), shared=shared)
                expected = _coarsen_by_the_formula(codes, np.asarray(value), shared)
                np.testing.assert_array_equal(out, expected)


def test_coarsening_a_block_of_rows_at_a_time_gives_the_codes_of_all_at_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Rows coarsened 7 at a time (the last block short), the tolerances given whole or a
    block's at a time by a function of the rows, give the codes of every row at once: the
    grids of every block run through the most frequent code of all rows, not the block's."""
    rng = np.random.default_rng(5)
    codes = rng.integers(0, 65536, (1000, 3)).astype(np.uint16)
    codes[:400] = codes[0]
    tol = np.exp(rng.normal(0.0, 5.0, (1000, 3)))
    expected = {shared: _coarsen_by_the_formula(codes, tol, shared) for shared in (False, True)}
    monkeypatch.setattr(columns, "BLOCK_BYTES", 7 * 8 * 3)  # 7 rows of three float64 a block
    asked: list[slice] = []

    def of_rows(rows: slice) -> np.ndarray:
        asked.append(rows)
        return tol[rows]

    for shared in (False, True):
        np.testing.assert_array_equal(coarsen(codes, tol, shared=shared), expected[shared])
        np.testing.assert_array_equal(coarsen(codes, of_rows, shared=shared), expected[shared])
    assert asked[:2] == [slice(0, 7), slice(7, 14)] and asked[142] == slice(994, 1000)
    assert len(asked) == 2 * 143


def test_tolerances_in_codes_follow_each_channels_range() -> None:
    """A tolerance in value units becomes tolerance x 65535 / (max - min) codes per channel
    (the last axis), unlimited on a channel whose range is empty (its codes are all 0)."""
    tol = np.array([[0.5, 0.5, 0.5], [2.0, 0.0, np.inf]])
    mins, maxs = np.array([0.0, -1.0, 3.0]), np.array([65535.0, 1.0, 3.0])
    out = to_codes(tol, mins, maxs)
    assert out.tolist() == [[0.5, 0.5 * 65535 / 2, np.inf], [2.0, 0.0, np.inf]]
    assert to_codes(np.array([[1.0]]), mins, maxs).tolist() == [[1.0, 65535 / 2, np.inf]]


def test_a_value_many_gaussians_share_stays_one_value() -> None:
    """A zero rate of turn for most Gaussians, each with its own step, still costs nothing."""
    rng = np.random.default_rng(0)
    codes = np.full((1000, 1), 32771, np.uint16)
    codes[:50, 0] = rng.integers(0, 65536, 50)
    out = coarsen(codes, rng.uniform(0, 2000, (1000, 1)), shared=True)
    assert np.all(out[50:] == 32771) and np.all(np.abs(out.astype(int) - codes) <= 2000)


@pytest.mark.parametrize("value", [-1, 101, 50.5, True])
def test_quality_outside_0_to_100_is_refused(value: object) -> None:
    with pytest.raises(InputError, match="0 to 100"):
        encode_chunk(Scene(static_gaussians(10)), quality=value)  # type: ignore[arg-type]


def test_the_cli_takes_quality(
    tmp_path: Path, scene: Scene, capsys: pytest.CaptureFixture[str]
) -> None:
    src = tmp_path / "in.sog"  # a 4D chunk is an input like any other
    src.write_bytes(bundle_bytes(encode_chunk(scene)))
    assert main(["encode", str(src), str(tmp_path / "a.sog"), "--quality", "40", "-q"]) == 0
    assert main(["encode", str(src), str(tmp_path / "b.sog"), "-q"]) == 0
    assert (tmp_path / "a.sog").stat().st_size < (tmp_path / "b.sog").stat().st_size
    with pytest.raises(SystemExit) as exc:
        main(["encode", str(src), str(tmp_path / "c.sog"), "--quality", "101"])
    assert exc.value.code == 2
    assert "from 0 to 100" in capsys.readouterr().err


@pytest.mark.parametrize("quality", [75, 0])
def test_motion_of_every_attribute_stays_within_its_budget(quality: int) -> None:
    """Each order k of a rotation's, scale's, colour's or opacity's motion moves it by its
    share over the lifespan as a root mean square weighted by g(t)²: |Δc_k| times
    :meth:`Budgets.motion_span` <= (what the base may move) / orders."""
    dynamic = ("means", "quats", "scales", "sh0", "opacity")
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=dynamic, seed=4)
    ordered = scene.subset(texel_order(scene))
    budgets = Budgets.of(ordered, quality)
    assert budgets is not None
    decoded = decode_chunk(encode_chunk(scene, quality=quality))
    full = _kept_whole_at_times_of(ordered, decoded).temporal
    cut = decoded.temporal
    f = budget_fraction(quality)
    shares = {
        "quats": budgets.rotation[:, None] / (4 * np.sqrt(3.0)),
        "scales": np.full((len(scene), 1), f * SCALE_AT_ZERO),
        "sh0": np.full((len(scene), 1), f * COLOUR_AT_ZERO / SH_C0),
        "opacity": np.full((len(scene), 1), 4 * f * ALPHA_AT_ZERO),
    }
    moved_any = False
    for attr, share in shares.items():
        orders = full[attr].shape[1]
        for k in range(orders):
            span = budgets.motion_span(k + 1)[:, None]
            change = np.abs(cut[attr][:, k] - full[attr][:, k]) * span
            assert np.all(change <= share / orders * 1.0001 + 1e-6), (attr, k)
            moved_any |= bool(np.any(change > 0))
    assert moved_any  # the budgets are used


def test_non_finite_values_get_no_budget_and_no_warning() -> None:
    """Hostile values (pytest makes warnings errors): NaN motion is refused with an error naming
    it; NaN and infinite scales, rotations, colours and opacities encode at quality 0 as at 100
    (those Gaussians keep their codes)."""
    dynamic = ("means", "quats", "scales", "sh0", "opacity")
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=dynamic, seed=5)
    g = scene.gaussians
    g.scales[0] = np.nan
    g.scales[1] = (-np.inf, 0.0, 0.0)
    g.scales[2] = np.inf
    g.quats[3] = np.nan
    g.sh0[4] = np.inf
    g.opacities[5] = -np.inf
    for attr in ("quats", "scales", "sh0", "opacity"):
        scene.temporal[attr][6] = np.nan
    for attr in ("quats", "scales", "sh0", "opacity"):
        with pytest.raises(InputError, match=f"1 Gaussians have non-finite {attr} motion"):
            encode_chunk(scene, quality=0)
        scene.temporal[attr][6] = 0.0
    sizes = [len(decode_chunk(encode_chunk(scene, quality=q))) for q in (100, 0)]
    assert sizes == [len(scene)] * 2


@pytest.mark.parametrize("quality", [100, 0])
def test_motion_too_large_to_re_expand_keeps_its_own_values(quality: int) -> None:
    """Hostile magnitudes: coefficients near float32's limit over a coarse grid of reference
    times (one lifespan 655 350 s away) would leave float32 when re-expanded about
    the rounded reference time; those rows keep their own values, without a warning (pytest
    makes warnings errors), and every decoded value is finite."""
    dynamic = ("means", "quats", "scales", "sh0", "opacity")
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=dynamic, seed=6)
    assert scene.timeline is not None
    first = float(scene.timeline.t0.min())
    scene.timeline.t0[0] = first + 10.0 * 65535  # reference times on a grid of 10 s
    scene.timeline.t0[1:4] = first + 4.0  # rounded to `first`: 4 s away
    scene.temporal["means"][1] = 3e38
    scene.temporal["means"][2] = -3e38
    scene.temporal["scales"][3] = 3e38
    decoded = decode_chunk(encode_chunk(scene, quality=quality))
    assert len(decoded) == len(scene)
    assert np.isfinite(decoded.gaussians.means).all()
    assert all(np.isfinite(c).all() for c in decoded.temporal.values())


@pytest.mark.parametrize("quality", [75, 0])
def test_a_reference_time_moves_within_the_reach_of_its_polynomials(quality: int) -> None:
    """Moving a reference time by d lengthens the reach |t - t_ref| of every polynomial by d,
    so it moves at most f · 0.1 of that reach, whatever its temporal scale: a .splatv
    Gaussian visible for hours (scale 65504) in a 2 s clip may not move its centre by f · 0.1 ·
    40 s, which cost spinach_4 2.6 dB at quality 75 (docs/spec.md §5.1)."""
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=("means", "quats"), seed=7)
    assert scene.timeline is not None
    scene.timeline.t1[::3] = 65504.0  # visible throughout, as many .splatv Gaussians
    full = decode_chunk(encode_chunk(scene))
    cut = decode_chunk(encode_chunk(scene, quality=quality))
    assert full.timeline is not None and cut.timeline is not None
    ordered = scene.subset(texel_order(scene))
    assert ordered.timeline is not None
    start, end = lifespans(ordered.timeline)
    first, last = time_range(ordered.timeline)
    centre = ordered.timeline.t0
    reach = np.maximum(
        np.abs(np.maximum(start, first) - centre), np.abs(np.minimum(end, last) - centre)
    )
    moved = np.abs(cut.timeline.t0 - full.timeline.t0)
    room = budget_fraction(quality) * TIME_AT_ZERO * reach
    assert np.all(moved <= room * 1.0001 + 1e-9)
    assert np.any(moved[::3] > 0)  # the long-lived ones move too, within their reach


@pytest.mark.parametrize("quality", [100, 0])
@pytest.mark.parametrize("kind", list(TimelineType))
def test_attributes_are_stored_about_the_reference_times_a_reader_decodes(
    kind: TimelineType, quality: int
) -> None:
    """The encoder re-expands the motion about ``quantize_timeline``'s reference times: they
    are, to the bit, what a reader decodes (type-0 frame ids rounded to whole frames), so a
    frame's motion is stored about its own frame, not about a code a fraction of a frame off."""
    scene = small_scene(kind, dynamic=("means",), seed=8)
    assert scene.timeline is not None
    ordered = scene.subset(texel_order(scene))
    assert ordered.timeline is not None
    budgets = Budgets.of(ordered, quality)
    codes = quantize_timeline(ordered.timeline, budgets.time if budgets is not None else None)
    decoded = decode_chunk(encode_chunk(scene, quality=quality))
    assert decoded.timeline is not None
    assert np.array_equal(codes.reference_units(), decoded.timeline.t0)
