"""The segmenter: scene -> .tsogs -> the frame at t equals the unsegmented scene's at(t).

Frames are compared as multisets: every decoded Gaussian is matched to the source Gaussian
nearest to it (positions, base colour and scales together), each source Gaussian at most once,
then positions, opacity and rotation are checked against the codec's quantisation bounds (see
tests/test_codec.py ``_check_at``), using the largest steps found in any chunk's meta.json.
"""

from __future__ import annotations

import json
import weakref
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

import tsog_stream as tsog
from helpers import means_log_step
from tsog_stream import Gaussians, InputError, Scene, Timeline, TimelineType
from tsog_stream.cli.main import main as cli_main
from tsog_stream.client import Stream, open_stream
from tsog_stream.codec.bundle import read_bundle
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.codec.precision import DEFAULT_QUALITY
from tsog_stream.compare import rotation_angles_deg
from tsog_stream.constants import DEFAULT_MAX_PIXELS
from tsog_stream.io.ply import write_ply
from tsog_stream.io.readers import load_scene
from tsog_stream.io.sequence import open_sequence
from tsog_stream.merge.check import frame_errors
from tsog_stream.model import evaluate_all, reference_times
from tsog_stream.schemas.manifest import Policy
from tsog_stream.segment import (
    SegmentOptions,
    SegmentReport,
    encoding,
    layout,
    segment_scene,
    segment_sequence,
)
from tsog_stream.segment import jobs as jobs_module
from tsog_stream.segment import meter as meter_module
from tsog_stream.segment import options as options_module
from tsog_stream.segment import sequence as sequence_module
from tsog_stream.segment.encoding import JobParts, encoded
from tsog_stream.segment.jobs import ChunkJob, Part
from tsog_stream.segment.layers import LAYERED_MIN_GAUSSIANS
from tsog_stream.segment.layout import chunk_counts
from tsog_stream.segment.meter import Meter, encode_work, palette_progress
from tsog_stream.segment.plan import NodeKey, Plan, window_count
from tsog_stream.summary import chunk_summary
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians
from tsog_stream.temporal import lifespans, time_range, visibility_half_width

F64 = npt.NDArray[np.float64]
POLICIES = ("duplicate", "hierarchy", "hybrid")
KINDS = list(TimelineType)
WINDOW_S = 0.5
DURATION_S = 2.0
SLACK_S = 1e-6
"""Float slack when comparing a query time with stored interval edges."""
SMALL_CHUNKS = 12 * 12
"""Pixel budget of the frame tests: several chunks per node, and quick to encode."""
SH0_TOL = 0.03
SCALES_TOL = 0.05
"""Largest codebook errors (256-entry scalar codebooks) allowed after matching; measured on
these scenes: 0.006 and 0.004."""
ROTATION_MAX_DEG = 1.5
"""8-bit smallest-three base rotation (up to 1.1 degrees, tests/test_codec.py) plus the
quantised temporal coefficients; measured on these scenes: 0.82."""


def make_scene(
    kind: TimelineType,
    *,
    fps: float = 5.0,
    background: int = 150,
    objects: int = 3,
    per_object: int = 50,
    seed: int = 0,
) -> Scene:
    """A small seeded scene of ``kind`` (no SH bands: the palette fit is not under test)."""
    spec = SceneSpec(
        timeline_type=kind,
        background=background,
        objects=objects,
        per_object=per_object,
        duration=DURATION_S,
        fps=fps,
        sh_bands=0,
        motion_order=2,
        dynamic=("means", "quats"),
        seed=seed,
    )
    return generate_scene(spec)


@dataclass(frozen=True)
class Steps:
    """The largest quantisation steps over every chunk of a container (from the metas)."""

    means_log: float
    """One 16-bit step of the log-space position code."""
    timeline: tuple[float, float]
    """One step of timeline R and G, in timeline units (0 for exact type-0 frame ids)."""
    coeff_half: list[float]
    """Half a step of each order of the means coefficients."""
    spu: float
    """Seconds per timeline unit."""


def container_steps(reader: Stream) -> Steps:
    """Steps read from every chunk's meta.json (the largest of each)."""
    metas = [
        json.loads(read_bundle(reader.chunk_bytes(c.id))["meta.json"])
        for c in reader.index.manifest.chunks
    ]
    means = max(float(means_log_step(m["means"]["mins"], m["means"]["maxs"]).max()) for m in metas)
    r_step = g_step = 0.0
    orders = max(len(m["temporal"]["means"]["mins"]) for m in metas)
    coeff = [0.0] * orders
    spu = 1.0
    for m in metas:
        tl = m["timeline"]
        spu = 1.0 / tl["fps"] if tl.get("fps") else 1.0
        if tl["type"] != TimelineType.FRAME:
            r_step = max(r_step, (tl["maxs"][0] - tl["mins"][0]) / 65535)
            g_step = max(g_step, (tl["maxs"][1] - tl["mins"][1]) / 65535)
        entry = m["temporal"]["means"]
        for k, (lo, hi) in enumerate(zip(entry["mins"], entry["maxs"], strict=True)):
            coeff[k] = max(coeff[k], float((np.asarray(hi) - np.asarray(lo)).max()) / 65535 / 2)
    return Steps(means, (r_step, g_step), coeff, spu)


def _sigmoid(x: npt.ArrayLike) -> F64:
    return np.asarray(1.0 / (1.0 + np.exp(-np.asarray(x, np.float64))), np.float64)


def _near_edge(src: Scene, steps: Steps, t: float) -> npt.NDArray[np.bool_]:
    """Gaussians whose visibility at t may flip through quantisation of their lifespan."""
    assert src.timeline is not None
    if src.timeline.type is TimelineType.FRAME:
        return np.zeros(len(src), bool)  # frame ids are stored exactly
    half_width = visibility_half_width() if src.timeline.type is TimelineType.CENTER_SCALE else 1.0
    edge = (steps.timeline[0] + half_width * steps.timeline[1]) * steps.spu / 2 + 1e-9
    start, end = lifespans(src.timeline)
    return np.asarray(np.minimum(np.abs(t - start), np.abs(t - end)) <= edge)


def _position_bound(src: Scene, ref: Gaussians, steps: Steps, t: float) -> F64:
    """Per source Gaussian: base position step plus every order's coefficient error at t."""
    assert src.timeline is not None
    dt = np.abs(t - reference_times(src.timeline))
    coeff = np.abs(src.temporal["means"]).max(axis=(0, 2))
    bound = np.zeros(len(src))
    t_err = steps.timeline[0] * steps.spu / 2
    for k, half in enumerate(steps.coeff_half):
        bound += half * dt ** (k + 1) + (k + 1) * coeff[k] * (dt + 1) ** k * t_err
    size = np.maximum(np.abs(ref.means).max(axis=1), np.abs(src.gaussians.means).max(axis=1))
    total: npt.NDArray[np.float64] = bound + (1 + size) * steps.means_log + 1e-5
    return total


def _opacity_bound(src: Scene, steps: Steps) -> F64:
    """Alpha: half an 8-bit step, plus for type 2 the temporal factor's change when the
    centre and scale move by half a step (|df/dc| <= e^-1/2 / s, |df/ds| <= 2 e^-1 / s)."""
    assert src.timeline is not None
    bound = np.full(len(src), 0.5 / 255 + 1e-5)
    if src.timeline.type is TimelineType.CENTER_SCALE:
        dc, ds = steps.timeline[0] / 2, steps.timeline[1] / 2
        bound += (np.exp(-0.5) * dc + 2 * np.exp(-1) * ds) / src.timeline.t1
    return bound


def _pairwise_cost(
    got: Gaussians, ref: Gaussians, cand: npt.NDArray[np.intp], pos_tol: F64
) -> npt.NDArray[np.float64]:
    """cost[i, j] = worst attribute error of decoded i against candidate j, in tolerances."""
    cost = np.empty((len(got), cand.size))
    for lo in range(0, len(got), 256):
        rows = slice(lo, lo + 256)
        pos = np.abs(got.means[rows, None, :] - ref.means[None, cand, :]).max(axis=2)
        sh0 = np.abs(got.sh0[rows, None, :] - ref.sh0[None, cand, :]).max(axis=2)
        scl = np.abs(got.scales[rows, None, :] - ref.scales[None, cand, :]).max(axis=2)
        cost[rows] = np.maximum.reduce([pos / pos_tol[None, cand], sh0 / SH0_TOL, scl / SCALES_TOL])
    return cost


def assert_frame_matches(src: Scene, got: Gaussians, t: float, steps: Steps) -> None:
    """``got`` (a stream's frame at t) is src.at(t) as a multiset, within the codec's bounds."""
    ref, mask = evaluate_all(src, t)
    near = _near_edge(src, steps, t)
    cand = np.flatnonzero(mask | near)
    if len(got) == 0 or cand.size == 0:
        assert len(got) == 0 and not np.any(mask & ~near), f"t={t}: {len(got)} vs {mask.sum()}"
        return
    cost = _pairwise_cost(got, ref, cand, _position_bound(src, ref, steps, t))
    best = cost.argmin(axis=1)
    worst = cost[np.arange(len(got)), best]
    assert np.all(worst <= 1.0), f"t={t}: {np.sum(worst > 1)} Gaussians match none within bounds"
    matched = cand[best]
    assert np.unique(matched).size == matched.size, f"t={t}: a source Gaussian shown twice"
    shown = np.zeros(len(src), bool)
    shown[matched] = True
    assert not np.any(mask & ~near & ~shown), f"t={t}: {np.sum(mask & ~near & ~shown)} missing"
    assert len(got) >= np.sum(mask & ~near) and len(got) <= np.sum(mask | near)
    alpha_err = np.abs(_sigmoid(got.opacities) - _sigmoid(ref.opacities[matched]))
    assert np.all(alpha_err <= _opacity_bound(src, steps)[matched]), f"t={t}: opacity"
    angles = rotation_angles_deg(got.quats, ref.quats[matched])
    assert angles.max() < ROTATION_MAX_DEG, f"t={t}: rotation {angles.max():.2f} deg"


def probe_times(scene: Scene, window_s: float) -> list[float]:
    """Window boundaries, times just around them, frame times, and times outside the scene."""
    assert scene.timeline is not None
    first, last = time_range(scene.timeline)
    bounds = [first + k * window_s for k in range(window_count(first, last, window_s) + 1)]
    times = {first - 0.25, last + 0.25, 0.37, 1.23}
    for b in bounds:
        times |= {b, b - SLACK_S, b + SLACK_S}
    if scene.timeline.fps:
        frames = round((last - first) * scene.timeline.fps)
        times |= {first + f / scene.timeline.fps for f in range(frames + 1)}
    return sorted(times)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., tuple[Path, SegmentReport]]:
    """Segment (and cache) a container per scene kind and options."""
    folder = tmp_path_factory.mktemp("segment")
    cache: dict[tuple[object, ...], tuple[Path, SegmentReport]] = {}

    def build(
        kind: TimelineType,
        policy: Policy,
        window_s: float = WINDOW_S,
        max_pixels: int = SMALL_CHUNKS,
        slice_s: float | None = None,
    ) -> tuple[Path, SegmentReport]:
        key = (kind, policy, window_s, max_pixels, slice_s)
        if key not in cache:
            path = folder / f"{kind.name}-{policy}-{window_s}-{max_pixels}-{slice_s}.tsogs"
            options = SegmentOptions(
                window_s=window_s, policy=policy, max_pixels=max_pixels, slice_s=slice_s
            )
            cache[key] = (path, segment_scene(scenes(kind), path, options))
        return cache[key]

    return build


_SCENES: dict[TimelineType, Scene] = {}


def scenes(kind: TimelineType) -> Scene:
    """The (cached) test scene of a timeline type."""
    if kind not in _SCENES:
        _SCENES[kind] = make_scene(kind, seed=int(kind) + 1)
    return _SCENES[kind]


def _in_range(reader: Stream, t: float) -> bool:
    scene = reader.index.manifest.scene
    return scene.start_s <= t <= scene.end_s


@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("kind", KINDS)
def test_frames_equal_the_unsegmented_scene(
    kind: TimelineType, policy: Policy, built: Callable[..., tuple[Path, SegmentReport]]
) -> None:
    path, _ = built(kind, policy)
    src = scenes(kind)
    with open_stream(path) as reader:
        steps = container_steps(reader)
        for t in probe_times(src, WINDOW_S):
            frame = reader.frame_at(t)
            if not _in_range(reader, t):
                assert len(frame) == 0, f"t={t} is outside the scene but shows {len(frame)}"
                continue
            assert_frame_matches(src, frame, t, steps)


@pytest.mark.parametrize("policy", ["hierarchy", "hybrid"])
@pytest.mark.parametrize("kind", KINDS)
def test_time_slices_keep_every_frame_and_narrow_each_chunk(
    kind: TimelineType, policy: Policy, built: Callable[..., tuple[Path, SegmentReport]]
) -> None:
    """Chunks cut by start time (layout.py's slices): every frame is still the unsegmented
    scene's, and no chunk's own interval is longer than its node's."""
    slice_s = WINDOW_S / 4
    path, _ = built(kind, policy, slice_s=slice_s)
    plain, _ = built(kind, policy)
    src = scenes(kind)
    with open_stream(path) as reader, open_stream(plain) as whole:
        steps = container_steps(reader)
        for t in probe_times(src, WINDOW_S):
            if _in_range(reader, t):
                assert_frame_matches(src, reader.frame_at(t), t, steps)
        manifest = reader.index.manifest
        assert len(manifest.chunks) > len(whole.index.manifest.chunks)
        span = manifest.window_s
        for chunk in manifest.chunks:  # the starts of a chunk's Gaussians share one slice
            node_start = manifest.scene.start_s + chunk.node * span * (1 << chunk.level)
            assert chunk.start_s >= node_start - 1e-9
            starts = lifespans(_timeline(reader.chunk_scene(chunk.id)))[0]
            inside = starts[starts >= node_start + 1e-3]
            if inside.size:
                assert np.ptp(inside) <= slice_s + 1e-3, chunk.id


def _timeline(scene: Scene) -> Timeline:
    assert scene.timeline is not None
    return scene.timeline


@pytest.mark.parametrize("policy", ["duplicate", "hierarchy"])
@pytest.mark.parametrize("kind", [TimelineType.FRAME, TimelineType.START_DURATION])
def test_every_frame_time_with_windows_in_frames(
    kind: TimelineType, policy: Policy, tmp_path: Path
) -> None:
    """24 fps, 5-frame windows: k * (5/24) and frame times f/24 round differently (35/24 <
    7 * (5/24) in floats); the frame at every f/24 must still be the source's."""
    fps = 24.0
    src = make_scene(kind, fps=fps, background=40, objects=2, per_object=15, seed=5)
    path = tmp_path / "f24.tsogs"
    segment_scene(src, path, SegmentOptions(window_s=5 / fps, policy=policy))
    with open_stream(path) as reader:
        steps = container_steps(reader)
        for f in range(round(DURATION_S * fps) + 1):
            t = f / fps
            frame = reader.frame_at(t)
            if kind is TimelineType.FRAME:
                assert len(frame) == len(src.at(t)), f"frame {f}"
            assert_frame_matches(src, frame, t, steps)


def _chunk_positions(scene: Scene, start: float, end: float, samples: int = 41) -> Iterable[F64]:
    """Positions of the visible Gaussians at many times of [start, end]."""
    for t in np.linspace(start, end, samples):
        g, mask = evaluate_all(scene, float(t))
        yield g.means[mask].astype(np.float64)


@pytest.mark.parametrize("kind", KINDS)
def test_a_single_window_is_split_spatially_under_the_pixel_budget(
    kind: TimelineType, built: Callable[..., tuple[Path, SegmentReport]]
) -> None:
    budget = 16 * 16
    path, report = built(kind, "hybrid", DURATION_S, budget)
    src = scenes(kind)
    assert report.windows == 1
    with open_stream(path) as reader:
        manifest = reader.index.manifest
        assert [n.level for n in manifest.nodes] == [0]
        assert len(manifest.chunks) >= 2 and len(manifest.chunks) == report.chunks
        assert manifest.max_pixels == budget
        steps = container_steps(reader)
        tol = (1 + np.abs(src.gaussians.means).max()) * steps.means_log + 1e-4
        for chunk in manifest.chunks:
            files = read_bundle(reader.chunk_bytes(chunk.id))
            summary = chunk_summary(files, where=f"chunk {chunk.id}")
            assert summary["count"] == chunk.count <= budget
            for name, (w, h) in summary["images"].items():
                assert w * h <= budget, f"chunk {chunk.id} {name} is {w}x{h}"
            lo, hi = np.asarray(chunk.bbox.min), np.asarray(chunk.bbox.max)
            decoded = reader.chunk_scene(chunk.id)
            for means in _chunk_positions(decoded, chunk.start_s, chunk.end_s):
                assert np.all(means >= lo - tol) and np.all(means <= hi + tol), (
                    f"chunk {chunk.id}: a centre lies outside its bounding box"
                )
        assert sum(c.count for c in manifest.chunks) == report.stored
        for t in probe_times(src, DURATION_S):
            if _in_range(reader, t):
                assert_frame_matches(src, reader.frame_at(t), t, steps)


def test_the_budget_also_holds_the_sh_palette_image(tmp_path: Path) -> None:
    """The shN centroid image grows with the bands (64 entries x coefficients per row): the
    chunks must shrink until it fits too, and `tsog verify` must find nothing over budget."""
    spec = SceneSpec(
        timeline_type=TimelineType.START_DURATION,
        background=300,
        objects=1,
        per_object=40,
        duration=DURATION_S,
        fps=5.0,
        sh_bands=1,
        seed=4,
    )
    budget = 16 * 16
    path = tmp_path / "sh.tsogs"
    segment_scene(
        generate_scene(spec), path, SegmentOptions(window_s=DURATION_S, max_pixels=budget)
    )
    with open_stream(path) as reader:
        report = reader.verify()
        assert report.problems == [] and report.exit_code == 0
        for chunk in reader.index.manifest.chunks:
            images = chunk_summary(read_bundle(reader.chunk_bytes(chunk.id)), where="c")["images"]
            assert "shN_centroids.webp" in images
            assert all(w * h <= budget for w, h in images.values()), images
    with pytest.raises(InputError, match="palette") as info:
        segment_scene(
            generate_scene(replace(spec, sh_bands=3)),
            tmp_path / "sh3.tsogs",
            SegmentOptions(max_pixels=512),
        )
    assert info.value.where == "--max-pixels"


def test_bounding_boxes_hold_curved_paths(tmp_path: Path) -> None:
    """A path whose turning point falls between sample times (x = t - 0.4 t^2 peaks at
    t = 1.25 s) must still lie inside its chunk's box at every time."""
    n = 8
    rng = np.random.default_rng(0)
    gaussians = Gaussians.from_arrays(
        rng.normal(0, 0.01, (n, 3)),
        np.full((n, 3), -3.0),
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.full(n, 2.0),
        np.zeros((n, 3)),
    )
    coeffs = np.zeros((n, 3, 3), np.float32)
    coeffs[0, 0, 0], coeffs[0, 1, 0] = 1.0, -0.4
    coeffs[1, :, 1] = [-0.3, 0.9, -0.45]  # cubic in y: extrema at t = 0.21 and 1.12 s
    timeline = Timeline(
        TimelineType.START_DURATION, np.zeros(n), np.full(n, 10.0), fps=5.0, scene_length=2.0
    )
    src = Scene(gaussians, timeline, {"means": coeffs})
    path = tmp_path / "curve.tsogs"
    segment_scene(src, path, SegmentOptions(window_s=DURATION_S))
    with open_stream(path) as reader:
        (chunk,) = reader.index.manifest.chunks
    lo, hi = np.asarray(chunk.bbox.min), np.asarray(chunk.bbox.max)
    for means in _chunk_positions(src, chunk.start_s, chunk.end_s, samples=401):
        assert np.all(means >= lo) and np.all(means <= hi)
    assert hi[0] == pytest.approx(0.625, abs=0.02), "the box is not needlessly loose"


@pytest.mark.parametrize("kind", KINDS)
def test_policies_store_what_they_promise(
    kind: TimelineType, built: Callable[..., tuple[Path, SegmentReport]]
) -> None:
    reports = {p: built(kind, p)[1] for p in POLICIES}
    source = len(scenes(kind))
    inside = source - reports["hierarchy"].dropped
    assert reports["duplicate"].stored >= reports["hybrid"].stored >= reports["hierarchy"].stored
    assert reports["hierarchy"].stored == inside
    assert reports["duplicate"].dropped == reports["hybrid"].dropped == source - inside
    for policy, report in reports.items():
        with open_stream(built(kind, policy)[0]) as reader:
            manifest = reader.index.manifest
            assert manifest.policy == policy
            assert manifest.scene.gaussians == source
            assert manifest.scene.stored == report.stored == sum(c.count for c in manifest.chunks)
            if policy == "duplicate":
                assert {c.level for c in manifest.chunks} == {0}


@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("kind", KINDS)
def test_chunks_for_t_only_returns_nodes_holding_t(
    kind: TimelineType, policy: Policy, built: Callable[..., tuple[Path, SegmentReport]]
) -> None:
    path, _ = built(kind, policy)
    with open_stream(path) as reader:
        index = reader.index
        nodes = {(n.level, n.index): n for n in index.manifest.nodes}
        for chunk in index.manifest.chunks:
            assert chunk.id in nodes[(chunk.level, chunk.node)].chunks
        for t in probe_times(scenes(kind), WINDOW_S):
            chosen = index.chunks_for(t)
            if not _in_range(reader, t):
                assert chosen == [], f"t={t} is outside the scene"
                continue
            for c in chosen:
                node = nodes[(c.level, c.node)]
                assert node.start_s - SLACK_S <= t <= node.end_s + SLACK_S, (t, node)
                assert c.start_s - SLACK_S <= t <= c.end_s + SLACK_S, (t, c.id)
            assert [c.offset for c in chosen] == sorted(c.offset for c in chosen)
            windows = {c.node for c in chosen if c.level == 0}
            assert len(windows) <= 1, f"t={t}: two windows chosen {windows}"
            per_level = [c.level for c in chosen]
            assert all(
                len({c.node for c in chosen if c.level == lv}) == 1 for lv in set(per_level)
            ), f"t={t}: two nodes of one level"


def test_same_input_gives_byte_identical_containers(tmp_path: Path) -> None:
    src = make_scene(TimelineType.CENTER_SCALE, background=200, objects=3, per_object=60, seed=9)
    options = SegmentOptions(window_s=0.5, policy="duplicate", max_pixels=16 * 16, seed=3)
    paths = [tmp_path / f"{n}.tsogs" for n in ("a", "b", "c")]
    segment_scene(src, paths[0], options)
    segment_scene(src, paths[1], options)
    report = segment_scene(src, paths[2], replace(options, workers=2))
    assert report.chunks >= 4
    first = paths[0].read_bytes()
    assert paths[1].read_bytes() == first
    assert paths[2].read_bytes() == first
    assert not list(tmp_path.glob(".*.tmp")), "temporary files left behind"


def test_jobs_are_encoded_costliest_first_and_written_in_order() -> None:
    """With two workers the biggest job starts first (a scene whose biggest chunk comes last
    kept one core idle while it encoded), and the payloads come out in job order, each the
    one the in-order encoder makes."""
    src = make_scene(TimelineType.CENTER_SCALE, background=300, objects=2, per_object=50, seed=4)
    plan = Plan(0.0, 2.0, 2.0, 1, {}, 0)
    cuts = [np.arange(0, 20), np.arange(20, 120), np.arange(120, len(src))]
    jobs = [ChunkJob(NodeKey(0, 0), idx) for idx in cuts]
    started: list[int] = []

    def make(job: ChunkJob) -> Part:
        started.append(next(i for i, j in enumerate(jobs) if j is job))
        return Part(job.key, src.subset(job.indices))

    def by_size(job: ChunkJob) -> float:
        return encode_work(job.indices.size, 0)

    options = SegmentOptions(workers=2)
    parallel = list(encoded(JobParts(jobs, make, by_size), plan, options, Meter(0.0)))
    assert started == [2, 1, 0]
    serial = list(
        encoded(JobParts(jobs, make, by_size), plan, replace(options, workers=1), Meter(0.0))
    )
    assert [p for _, p in parallel] == [p for _, p in serial]
    assert [info.count for info, _ in parallel] == [20, 100, len(src) - 120]
    # the order follows the cost, not the count: a small job with SH bands goes first
    started.clear()
    with_bands = {1: 15}  # 100 Gaussians with SH3 weigh 775, more than the 280 without
    list(
        encoded(
            JobParts(
                jobs,
                make,
                lambda job: encode_work(
                    job.indices.size,
                    with_bands.get(next(i for i, j in enumerate(jobs) if j is job), 0),
                ),
            ),
            plan,
            options,
            Meter(0.0),
        )
    )
    assert started == [1, 2, 0]


def test_progress_reports_every_chunk(tmp_path: Path) -> None:
    src = make_scene(TimelineType.START_DURATION, background=100, objects=2, per_object=40)
    calls: list[tuple[int, int]] = []
    etas: list[float | None] = []
    stages: list[tuple[str, int]] = []

    def on_chunk(done: int, total: int, eta_s: float | None) -> None:
        calls.append((done, total))
        etas.append(eta_s)

    report = segment_scene(
        src,
        tmp_path / "p.tsogs",
        SegmentOptions(window_s=1.0, max_pixels=16 * 16),
        on_chunk=on_chunk,
        on_stage=lambda text: stages.append((text, len(calls))),
    )
    assert [d for d, _ in calls] == list(range(1, report.chunks + 1))
    assert all(total == report.chunks for _, total in calls)
    # encoded here, each chunk's job has finished when it is written: every ETA is known,
    # and none is left after the last
    assert all(eta is not None and eta >= 0.0 for eta in etas)
    assert etas[-1] == pytest.approx(0.0, abs=1e-6)
    # every phase is announced before it starts: the last, encoding, before any chunk
    assert [text.split()[0] for text, _ in stages] == ["choosing", "measuring", "encoding"]
    assert stages[-1] == (f"encoding {report.chunks} chunks ({report.stored} Gaussians stored) "
                          "on one process", 0)  # fmt: skip
    # one layer asked: nothing is measured, and the stage says what runs instead
    stages.clear()
    one = SegmentOptions(window_s=1.0, max_pixels=16 * 16, layers=1)
    segment_scene(src, tmp_path / "one.tsogs", one, on_stage=lambda t: stages.append((t, 0)))
    assert [text.split()[0] for text, _ in stages] == ["choosing", "cutting", "encoding"]
    # a frame sequence likewise: with one layer its sampled frames are read for the view only
    stages.clear()
    for k in range(2):
        (tmp_path / "frames").mkdir(exist_ok=True)
        write_ply(tmp_path / "frames" / f"f_{k}.ply", static_gaussians(64, seed=k))
    seq = open_sequence(tmp_path / "frames", fps=10.0)
    segment_sequence(seq, tmp_path / "seq.tsogs", one, on_stage=lambda t: stages.append((t, 0)))
    assert [text.split()[0] for text, _ in stages] == ["choosing", "reading", "encoding"]


def test_a_failed_segmentation_leaves_the_destination_untouched(tmp_path: Path) -> None:
    src = make_scene(TimelineType.START_DURATION, background=100, objects=2, per_object=40)
    out = tmp_path / "keep.tsogs"
    out.write_bytes(b"keep me")

    def interrupt(done: int, total: int, eta_s: float | None) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        segment_scene(src, out, SegmentOptions(max_pixels=16 * 16), on_chunk=interrupt)
    assert out.read_bytes() == b"keep me"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.tsogs"]


@pytest.mark.parametrize(
    ("options", "where"),
    [
        (SegmentOptions(window_s=0.0), "--window"),
        (SegmentOptions(window_s=float("nan")), "--window"),
        (SegmentOptions(policy="copy"), "--policy"),  # type: ignore[arg-type]  # on purpose
        (SegmentOptions(max_pixels=8), "--max-pixels"),
        (SegmentOptions(max_pixels=16384 * 16384), "--max-pixels"),
    ],
)
def test_impossible_options_are_input_errors(
    options: SegmentOptions, where: str, tmp_path: Path
) -> None:
    src = make_scene(TimelineType.START_DURATION, background=20, objects=1, per_object=10)
    out = tmp_path / "x.tsogs"
    with pytest.raises(InputError) as info:
        segment_scene(src, out, options)
    assert info.value.where == where
    assert not out.exists() and not list(tmp_path.iterdir())


STATIC_SAMPLES = {
    "3dgs/v3dg_donut_fused.ply": DEFAULT_MAX_PIXELS,  # SH0, 45,624: layered
    "3dgs/gs3d_pr477_lod3_tile_0.ply": 64 * 64,  # SH3, 1,971: cut under a small budget
    "3dgs/pc_guitar.compressed.ply": DEFAULT_MAX_PIXELS,  # compressed PLY, 90,854: layered
    "3dgs/pc_playbot_lod6_sog": DEFAULT_MAX_PIXELS,  # an unbundled SOG, SH2
}
"""Real static scenes and the pixel budget each is segmented under."""
STATIC_TIMES = (0.0, 0.37, 7.25, -3.0)
"""Times a static stream is asked for: its moment, inside and outside any range."""
STATIC_SLACK = 1.25
"""A static stream's decoded attributes may be off by up to this times the error of the same
scene decoded from one standalone SOG at the same quality (chunks have their own codebooks,
fitted to fewer Gaussians: 0.7-1.13x measured), plus 1e-4."""


@pytest.mark.parametrize("name", list(STATIC_SAMPLES))
def test_a_static_scene_is_a_stream_of_one_moment(samples: Path, tmp_path: Path, name: str) -> None:
    """A static PLY, compressed PLY or SOG segments as one window at 0 s, split into chunks
    under the pixel budget and into layers like any window; its frame at any time is the
    whole scene, as the codec decodes it."""
    scene = load_scene(samples / name).scene
    assert scene.timeline is None
    out = tmp_path / "static.tsogs"
    options = SegmentOptions(workers=1, quality=100, max_pixels=STATIC_SAMPLES[name])
    report = segment_scene(scene, out, options)
    assert report.static and report.windows == 1 and report.layout is None
    alone = decode_chunk(encode_chunk(scene, quality=100)).gaussians
    expected, unpaired = frame_errors(scene.gaussians, alone)
    assert unpaired == 0
    with open_stream(out) as stream:
        m = stream.index.manifest
        info = m.scene
        assert (info.timeline_type, info.start_s, info.end_s, info.fps) == (None, 0.0, 0.0, None)
        assert not info.duration_assumed and info.temporal == {}
        assert info.gaussians == info.stored == len(scene)
        assert [(n.level, n.index, n.start_s, n.end_s) for n in m.nodes] == [(0, 0, 0.0, 0.0)]
        assert sorted(m.nodes[0].chunks) == list(range(len(m.chunks)))
        assert all((c.start_s, c.end_s) == (0.0, 0.0) for c in m.chunks)
        assert stream.verify().problems == []  # hashes, decoding and the pixel budget
        frames = [stream.frame_at(t) for t in STATIC_TIMES]
        base = stream.frame_at(99.0, layers=1)
    if STATIC_SAMPLES[name] < DEFAULT_MAX_PIXELS:
        assert len(m.chunks) > 1  # cut spatially: one chunk's images would not fit
    if len(scene) >= LAYERED_MIN_GAUSSIANS:
        assert len(m.layers) > 1 and len(base) == m.layers[0].gaussians < len(scene)
    for t, frame in zip(STATIC_TIMES, frames, strict=True):
        assert np.array_equal(frame.means, frames[0].means), t
        assert np.array_equal(frame.sh0, frames[0].sh0) and np.array_equal(frame.shN, frames[0].shN)
    errors, unpaired = frame_errors(scene.gaussians, frames[0])
    assert unpaired == 0 and set(errors) == set(expected)
    for attribute, error in errors.items():
        assert error <= STATIC_SLACK * expected[attribute] + 1e-4, (attribute, error, expected)


def test_a_static_scene_s_layout_and_policy(tmp_path: Path) -> None:
    """A static scene has nothing to choose: one window of STATIC_WINDOW_S (a window given is
    not used), the policy given or the default, and no layout in the report."""
    g = static_gaussians(300, seed=4)
    out = tmp_path / "s.tsogs"
    report = segment_scene(Scene(g), out, SegmentOptions(window_s=0.25, policy="duplicate"))
    with open_stream(out) as stream:
        m = stream.index.manifest
    assert (m.window_s, m.policy) == (options_module.STATIC_WINDOW_S, "duplicate")
    assert report.layout is None and report.dropped == 0 and report.windows == 1
    segment_scene(Scene(g), out, SegmentOptions(layers=1))  # replaces it: no policy given
    with open_stream(out) as stream:
        assert stream.index.manifest.policy == options_module.DEFAULT_POLICY


def test_the_container_s_folder_is_made_and_removed_again_on_failure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """segment_scene("streams/clip.tsogs") works where streams/ does not exist (the README's
    example); a segmentation that fails leaves no folder it made behind."""
    scene = Scene(static_gaussians(200, seed=2))
    out = tmp_path / "streams" / "deeper" / "clip.tsogs"
    segment_scene(scene, out, SegmentOptions(layers=1))
    with open_stream(out) as stream:
        assert len(stream.frame_at(0.0)) == 200

    def broken(*args: Any, **kwargs: Any) -> bytes:
        raise InputError("the encoder broke")

    monkeypatch.setattr(encoding, "encode_job_payload", broken)
    failed = tmp_path / "made" / "for" / "it.tsogs"
    with pytest.raises(InputError, match="the encoder broke"):
        segment_scene(scene, failed, SegmentOptions(layers=1))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["streams"]


def test_no_chunk_holds_more_than_the_job_cap(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The pixel budget allows 8M Gaussians a chunk; a chunk holds at most
    MAX_CHUNK_GAUSSIANS so one job never holds most of a scene (a long-lived scene's whole-clip
    node is split into Morton runs, shared among the workers)."""
    assert (
        options_module.max_gaussians_per_chunk(DEFAULT_MAX_PIXELS)
        == options_module.MAX_CHUNK_GAUSSIANS
    )
    assert options_module.max_gaussians_per_chunk(64 * 64) < options_module.MAX_CHUNK_GAUSSIANS
    monkeypatch.setattr(options_module, "MAX_CHUNK_GAUSSIANS", 700)
    scene = generate_scene(SceneSpec(background=2500, objects=2, per_object=200))
    report = segment_scene(scene, tmp_path / "s.tsogs", SegmentOptions(layers=1))
    with open_stream(tmp_path / "s.tsogs") as stream:
        chunks = stream.index.manifest.chunks
    counts = [c.count for c in chunks]
    assert max(counts) <= 700 and sum(counts) == report.stored and len(counts) >= 4


def test_a_big_node_is_cut_into_an_even_number_of_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two workers finish a big node together: 5 chunks' worth become 6 (the 5M checkpoint's
    last chunk encoded alone for ~40 s); one or two stay as they are, and so do small chunks
    (an extra one costs more than the balance gains)."""
    big = layout.EVEN_FROM
    counts = chunk_counts(np.array([0, 1, 100, 101, 200, 201, 300, 500, 501]) * big // 100, big)
    assert counts.tolist() == [0, 1, 1, 2, 2, 4, 4, 6, 6]
    assert chunk_counts([300, 500], 100).tolist() == [3, 5]
    monkeypatch.setattr(layout, "EVEN_FROM", 700)
    scene = generate_scene(SceneSpec(background=2500, objects=2, per_object=200))
    jobs = jobs_module.chunk_jobs(scene, [(NodeKey(0, 0), np.arange(2900))], 700)
    assert [job.indices.size for job in jobs] == [484] * 2 + [483] * 4


def test_a_job_s_work_is_known_before_its_part_is_made() -> None:
    """The meter's total is summed from the jobs, its progress from the parts encoded: both
    weigh the same (a layered SH scene: bare bases, SH-band chunks, upper layers with bands)."""
    scene = generate_scene(SceneSpec(background=300, objects=2, per_object=50, sh_bands=2))
    layer_of = np.arange(len(scene)) % 2
    jobs = jobs_module.with_sh_jobs(
        jobs_module.chunk_jobs(scene, [(NodeKey(0, 0), np.arange(len(scene)))], 100, layer_of)
    )
    kinds = {(job.layer, job.sh_of is not None) for job in jobs}
    assert kinds == {(0, False), (1, True), (1, False)}
    for job in jobs:
        part = jobs_module.job_part(scene, job, True)
        assert jobs_module.job_work(scene, job, True) == jobs_module.part_work(part)
    bare = [j for j in jobs if j.layer == 0]
    assert all(jobs_module.job_work(scene, j, True) == j.indices.size for j in bare)


class _HeardMeter(Meter):
    """A meter that keeps every report it hears from running jobs."""

    def __init__(self, total: float) -> None:
        super().__init__(total)
        self.heard: list[tuple[int, float]] = []

    def advance(self, token: int, fraction: float) -> None:
        self.heard.append((token, fraction))
        super().advance(token, fraction)


@pytest.mark.parametrize("workers", [1, 2])
def test_running_jobs_report_their_palette_s_progress(workers: int) -> None:
    """The first ETA of a 5M scene came with its first finished job, ~40 s in: a job with SH
    bands reports its palette's progress as it runs, here or from a pool worker."""
    src = generate_scene(SceneSpec(background=600, objects=2, per_object=100, sh_bands=3))
    plan = Plan(0.0, 4.0, 4.0, 1, {}, 0)
    key = NodeKey(0, 0)
    jobs = [ChunkJob(key, np.arange(0, 500)), ChunkJob(key, np.arange(500, 800))]
    coeffs = src.gaussians.shN.shape[1]
    works = {id(job): encode_work(job.indices.size, coeffs) for job in jobs}
    meter = _HeardMeter(sum(works.values()))
    parts = JobParts(
        jobs, lambda job: Part(job.key, src.subset(job.indices)), lambda job: works[id(job)]
    )
    list(encoded(parts, plan, SegmentOptions(workers=workers), meter))
    tokens = sorted({token for token, _ in meter.heard})
    assert len(tokens) == 2
    start, end = palette_progress(coeffs, 0.0), palette_progress(coeffs, 1.0)
    for token in tokens:
        fractions = [done for t, done in meter.heard if t == token]
        assert fractions[0] == 0.0  # the job's start
        # the palette's own steps, from its start to its end (the images come after it)
        assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(end)
        assert any(start < done < end for done in fractions), fractions
    assert meter.eta_s() == pytest.approx(0.0)


def test_the_eta_is_drawn_while_no_chunk_is_written(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Every tick of the meter while jobs run redraws the progress with the chunks written so
    far (0 before the first), never past the chunks finished."""
    monkeypatch.setattr(meter_module, "TICK_S", 0.001)
    monkeypatch.setattr(encoding, "POLL_S", 0.001)
    src = make_scene(TimelineType.START_DURATION, background=400, objects=2, per_object=60)
    calls: list[int] = []
    report = segment_scene(
        src,
        tmp_path / "ticks.tsogs",
        SegmentOptions(window_s=1.0, max_pixels=16 * 16, workers=2),
        on_chunk=lambda done, total, eta_s: calls.append(done),
    )
    assert calls[0] == 0 and calls == sorted(calls) and calls[-1] == report.chunks
    assert set(range(1, report.chunks + 1)) <= set(calls)


def _frames_scene(frames: int, per_frame: int, bands: int) -> Scene:
    """``frames`` frames of ``per_frame`` Gaussians as one type-0 scene (writable arrays)."""
    g = static_gaussians(frames * per_frame, sh_bands=bands, seed=frames)
    ids = np.repeat(np.arange(frames, dtype=np.float64), per_frame)
    timeline = Timeline(TimelineType.FRAME, ids, np.zeros_like(ids), fps=30.0, scene_length=1.0)
    return Scene(g, timeline)


def test_sampled_frames_are_read_once_and_held_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The frames a sequence's opening view and layers are measured on are each read once and
    let go: the view's samples keep no SH bands, and the measured frames are one joined scene
    (each frame its group, its number as its rows' id), not the frames beside their join."""
    for k in range(7):
        write_ply(tmp_path / f"f_{k}.ply", static_gaussians(50 + k, sh_bands=1, seed=k))
    seq = open_sequence(tmp_path)
    reads: list[int] = []
    frames: list[weakref.ref[Scene]] = []
    real = type(seq).read

    def read(self: Any, first: int = 0, stop: int | None = None, progress: Any = None) -> Any:
        loaded = real(self, first, stop, progress)
        reads.append(first)
        frames.append(weakref.ref(loaded.scene))
        return loaded

    monkeypatch.setattr(type(seq), "read", read)
    framing, measured = sequence_module.sampled_frames(seq)
    assert reads == sorted(set(reads)) and len(reads) == len(frames)
    assert all(frame() is None for frame in frames)
    assert framing.shN.shape[1] == 0 and len(framing) == sum(50 + k for k in reads)
    assert measured.numbers == [0, 3, 6]
    monkeypatch.undo()
    for number, rows in zip(measured.numbers, measured.groups, strict=True):
        alone = seq.read(number, number + 1).scene
        for joined, own in zip(measured.scene.subset(rows).arrays(), alone.arrays(), strict=True):
            np.testing.assert_array_equal(joined, own)


# --- the library does all that tsog segment does (issue 56) -----------------------------------


class Heard:
    """A pipeline listener that keeps what it is told."""

    def __init__(self) -> None:
        self.stages: list[str] = []
        self.notes: list[str] = []

    def __call__(self, stage: str) -> None:
        self.stages.append(stage)

    def bar(self, stage: str, fraction: float) -> None:
        self.stages.append(stage)

    def done(self) -> None:
        """Nothing to end."""

    def note(self, text: str) -> None:
        self.notes.append(text)

    def warn(self, text: str) -> None:
        self.notes.append(text)


def _frames(folder: Path, count: int = 8) -> Path:
    """A folder of numbered PLY frames sampled from a generated 4D scene."""
    scene = generate_scene(SceneSpec(seed=5, background=200, objects=2, per_object=60, duration=1))
    folder.mkdir()
    for k in range(count):
        write_ply(folder / f"frame_{k:04d}.ply", scene.at(k / 30))
    return folder


def test_segment_input_writes_what_tsog_segment_writes_and_reports_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One call: the same container and thumbnail bytes as the command, the merge probe's
    outcome, the frame check of a stored merge, and the report the command prints."""
    frames = _frames(tmp_path / "frames")
    heard = Heard()
    options = tsog.SegmentOptions(quality=DEFAULT_QUALITY, workers=1)
    inputs = tsog.InputOptions(reading=tsog.ReadOptions(fps=30))
    made = tsog.segment_input(frames, tmp_path / "lib.tsogs", options, inputs, heard)
    by_cli = tmp_path / "cli.tsogs"
    argv = ["segment", str(frames), "-o", str(by_cli), "--fps", "30", "--workers", "1", "-q"]
    assert cli_main(argv) == 0
    printed = capsys.readouterr().out.splitlines()
    lib = tmp_path / "lib.tsogs"
    assert lib.read_bytes() == by_cli.read_bytes()
    assert made.thumbnail == f"{lib}.thumb.png"
    assert Path(made.thumbnail).read_bytes() == Path(f"{by_cli}.thumb.png").read_bytes()
    assert made.segment.bytes == lib.stat().st_size and made.fps == 30
    assert made.input_bytes == sum(p.stat().st_size for p in frames.iterdir())
    assert made.temporal is not None and made.temporal.mode == "fit"
    assert made.temporal.frames == 8 and made.temporal.gaussians_in > 0
    assert (made.frame_check is not None) == (made.temporal.declined is None)
    if made.frame_check is not None:
        assert made.frame_check.frames == [0, 2, 4, 5, 7]
    assert heard.stages[-1] == "drawing the thumbnail"
    assert any(stage.startswith("chunk ") for stage in heard.stages)
    by_cli_line = f"{by_cli}: {made.segment.bytes} bytes, "
    assert any(line.startswith(by_cli_line) for line in printed)
    assert f"  thumbnail: {by_cli}.thumb.png" in printed


@pytest.mark.parametrize(
    ("inputs", "expected"),
    [
        (
            tsog.InputOptions(window_frames=30),
            "--window: a window in frames needs a frame rate (the input has none)",
        ),
        (
            tsog.InputOptions(format="ply-sequence"),
            "expected a folder of numbered frames or a glob pattern",
        ),
    ],
)
def test_segment_input_refuses_what_the_input_cannot_give(
    tmp_path: Path, inputs: Any, expected: str
) -> None:
    """Options the input cannot honour are one error, and nothing is written."""
    still = tmp_path / "still.ply"
    write_ply(still, static_gaussians(40, seed=1))
    out = tmp_path / "out.tsogs"
    with pytest.raises(tsog.TsogError) as caught:
        tsog.segment_input(still, out, inputs=inputs)
    assert expected in str(caught.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["still.ply"]


def test_segment_input_checks_its_output_before_reading(tmp_path: Path) -> None:
    """An output that exists is refused (unless ``overwrite``) before the input is read: a
    missing input is not even looked at."""
    out = tmp_path / "out.tsogs"
    out.write_bytes(b"kept")
    with pytest.raises(tsog.SourceError, match="already exists"):
        tsog.segment_input(tmp_path / "missing.ply", out)
    assert out.read_bytes() == b"kept"
