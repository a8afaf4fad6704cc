"""Segment a scene into a ``.tsogs`` container: plan, split spatially, encode in parallel, pack.

A 4D scene is cut into time windows; a static scene is one moment (0 s) in one window. Chunks
are encoded in worker processes and written in a fixed order: the same scene and options give a
byte-identical container whatever the worker count. This module owns the two entry points
(:func:`segment_scene`, :func:`segment_sequence`), a scene's layout and its opening view.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..codec.precision import QUALITY_MAX
from ..constants import SH_BANDS_BY_COEFFS
from ..errors import InputError
from ..framing import dense_core, framing_sample, opening_view, vec3
from ..io.sequence import FrameSequence
from ..model import Gaussians, Scene
from ..schemas.cameras import Camera
from ..temporal import lifespans, time_range
from .encoding import Encoded, JobParts, encoded
from .jobs import chunk_jobs, job_part, job_work, node_groups, with_sh_jobs, without_faint_members
from .layers import LayerPlan, check_layers, importance, plan_layers
from .layout import Choice, Lifespans, choose_layout, measure_costs, why_not_merged
from .meter import Meter
from .options import (
    DEFAULT_POLICY,
    STATIC_WINDOW_S,
    ChunkProgress,
    SegmentOptions,
    SegmentReport,
    StageProgress,
    max_gaussians_per_chunk,
)
from .plan import NodeKey, Plan, make_plan, window_count
from .sequence import (
    frames_work,
    layers_within_flipbook,
    sampled_frames,
    sequence_chunks,
    sequence_encoded,
    sequence_layers,
    sequence_layout,
)
from .write import Views, write_container

__all__ = [
    "merge_or_frames",
    "plan_scene",
    "scene_layout",
    "segment_scene",
    "segment_sequence",
    "static_plan",
    "views_of",
]


def views_of(gaussians: Gaussians, cameras: Sequence[Camera]) -> Views:
    """``cameras``, the default view and the dense core of a scene whose base (or first frame)
    is ``gaussians``; no view or core when nothing is visible."""
    sample = framing_sample(gaussians)
    try:
        centre, radius = dense_core(sample)
    except InputError:
        return Views(list(cameras), cameras[0] if cameras else None, None, "nothing visible")
    core = {"center": vec3(centre), "radius": radius}
    view, why = opening_view(sample, cameras, (centre, radius))
    return Views(list(cameras), view, core, why)


def static_plan(scene: Scene) -> Plan:
    """The plan of a static scene: one moment (0 s), one window holding every Gaussian."""
    everything = np.arange(len(scene), dtype=np.int64)
    return Plan(0.0, 0.0, STATIC_WINDOW_S, 1, {NodeKey(0, 0): everything}, 0)


def plan_scene(scene: Scene, options: SegmentOptions) -> Plan:
    """The time plan of a scene: a dynamic one's under the options' policy and window (both
    set), a static one's :func:`static_plan`."""
    if scene.timeline is None:
        return static_plan(scene)
    if options.window_s is None or options.policy is None:
        raise InputError("the plan needs a window and a policy: choose them with scene_layout")
    start, end = lifespans(scene.timeline)
    first, last = time_range(scene.timeline)
    return make_plan(
        start,
        end,
        scene_start=first,
        scene_end=last,
        window_s=options.window_s,
        policy=options.policy,
        max_copies=options.max_copies,
    )


def scene_layout(scene: Scene, options: SegmentOptions, max_count: int) -> Choice | None:
    """The layout for a 4D scene: the options' window and policy where set, the cost model's
    choice for the rest (None for a static scene: one window, nothing to choose)."""
    if scene.timeline is None:
        return None
    if options.window_s is not None:
        window_count(0.0, 1.0, options.window_s)  # refuses a non-positive window at once
    costs = measure_costs(scene, max_count, options.seed, options.quality)
    life = Lifespans.of_scene(scene)
    return choose_layout(
        life, costs, window_s=options.window_s, policy=options.policy, slice_s=options.slice_s
    )


def _with_layout(options: SegmentOptions, choice: Choice | None) -> SegmentOptions:
    """The options with the chosen window and policy filled in (a static scene's one window)."""
    if choice is None:
        policy = options.policy or DEFAULT_POLICY
        return replace(options, window_s=STATIC_WINDOW_S, policy=policy, slice_s=None)
    layout = choice.chosen.layout
    return replace(options, window_s=layout.window_s, policy=layout.policy, slice_s=layout.slice_s)


def _layers_stage(layers: int | None, measuring: str, otherwise: str) -> str:
    """The stage line before the quality layers are planned (``otherwise`` for one layer)."""
    return otherwise if layers == 1 else f"measuring quality layers ({measuring})"


@dataclass(frozen=True)
class _Ready:
    """A scene or frame sequence planned, measured and cut: its chunks, to encode and write in
    order, and what the index and the report say of them."""

    chunks: Encoded
    total: int
    plan: Plan
    fields: dict[str, Any]
    """The index's ``scene`` fields known before writing (a sequence's counts are not)."""
    options: SegmentOptions
    views: Views
    layering: LayerPlan
    meter: Meter
    choice: Choice | None
    gaussians: int
    """The source's Gaussians, the faint ones included (the report counts those left out)."""


def _written(
    ready: _Ready, path: str | os.PathLike[str], on_chunk: ChunkProgress | None
) -> SegmentReport:
    """Encode a ready source's chunks and write the container: the one path of both inputs."""
    report = write_container(
        path,
        ready.chunks,
        total=ready.total,
        plan=ready.plan,
        scene_fields=ready.fields,
        options=ready.options,
        on_chunk=on_chunk,
        views=ready.views,
        layering=ready.layering,
        meter=ready.meter,
    )
    return replace(report, layout=ready.choice, faint=ready.gaussians - report.gaussians)


def segment_scene(
    scene: Scene,
    path: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    *,
    on_chunk: ChunkProgress | None = None,
    layout: Choice | None = None,
    cameras: Sequence[Camera] = (),
    on_stage: StageProgress | None = None,
    duration_assumed: bool = False,
) -> SegmentReport:
    """Segment an in-memory scene into the container at ``path`` (published atomically), in
    ``layout`` when already chosen (:func:`merge_or_frames`), with its capture ``cameras``;
    ``on_stage`` hears of each phase, ``on_chunk`` of each chunk written (and of the ETA).
    ``duration_assumed``: the reader assumed the scene's length (the index says so)."""
    stage = on_stage or _unheard
    ready = _scene_ready(
        scene,
        options or SegmentOptions(),
        layout=layout,
        cameras=cameras,
        stage=stage,
        duration_assumed=duration_assumed,
    )
    return _written(ready, path, on_chunk)


def _unheard(_stage: str) -> None:
    """A stage nobody listens to."""


def _scene_planned(
    scene: Scene,
    options: SegmentOptions,
    *,
    layout: Choice | None,
    cameras: Sequence[Camera],
    stage: StageProgress,
    max_count: int,
) -> tuple[Choice | None, SegmentOptions, Plan, Views]:
    """A scene's layout (given or chosen), the options it sets, its time plan and its views
    (framed on another thread meanwhile)."""
    if scene.timeline is None:
        stage(f"a static scene of {len(scene)} Gaussians: one moment, one window")
    elif layout is None:
        stage(f"choosing the layout of {len(scene)} Gaussians (encoding samples)")
    with ThreadPoolExecutor(1, "tsog-view") as beside:
        viewing = beside.submit(views_of, scene.gaussians, cameras)
        choice = layout or scene_layout(scene, options, max_count)
        options = _with_layout(options, choice)
        plan = plan_scene(scene, options)
        views = viewing.result()
    return choice, options, plan, views


def _scene_ready(
    scene: Scene,
    options: SegmentOptions,
    *,
    layout: Choice | None,
    cameras: Sequence[Camera],
    stage: StageProgress,
    duration_assumed: bool,
) -> _Ready:
    """A scene in memory planned, its faint Gaussians left out, layered and cut into jobs."""
    max_count = max_gaussians_per_chunk(options.max_pixels, scene.gaussians.sh_bands)
    check_layers(options.layers)
    choice, options, plan, views = _scene_planned(
        scene, options, layout=layout, cameras=cameras, stage=stage, max_count=max_count
    )
    groups, faint = without_faint_members(
        node_groups(scene, plan, options.slice_s), scene, options.quality
    )
    if faint:
        stage(f"leaving out {faint} Gaussians too faint to show at quality {options.quality}")
    stored = sum(len(g) for _, g in groups)
    members = [g for _, g in groups]
    stage(_layers_stage(options.layers, "rendering", "cutting the scene into chunks"))
    layering = plan_layers(
        scene, members, views.view, options.layers, sh_apart=options.sh_apart, told=stage
    )
    layer_of = None
    if layering.layers > 1:
        layer_of = layering.assign(importance(scene.gaussians), members)
    jobs = chunk_jobs(scene, groups, max_count, layer_of)
    split = layering.sh_apart
    if split:
        jobs = with_sh_jobs(jobs)
    parts = JobParts(
        jobs, lambda job: job_part(scene, job, split), lambda job: job_work(scene, job, split)
    )
    meter = Meter(sum(parts.work(job) for job in jobs))
    stage(_encoding(len(jobs), stored, options.workers))
    tl = scene.timeline
    fields: dict[str, Any] = {
        "gaussians": len(scene) - faint,
        "stored": stored,
        "fps": tl.fps if tl is not None else None,
        "timeline_type": int(tl.type) if tl is not None else None,
        "temporal": {a: int(c.shape[1]) for a, c in scene.temporal.items()},
        "sh_bands": scene.gaussians.sh_bands,
        "duration_assumed": duration_assumed and tl is not None,
    }
    chunks = encoded(parts, plan, options, meter)
    return _Ready(
        chunks, len(jobs), plan, fields, options, views, layering, meter, choice, len(scene)
    )


def _encoding(chunks: int, gaussians: int, workers: int, *, faint_left: bool = False) -> str:
    """The encoding phase, as a stage line (``faint_left``: the count is a bound)."""
    on = f"{workers} workers" if workers > 1 else "one process"
    stored = f"at most {gaussians}" if faint_left else f"{gaussians}"
    return f"encoding {chunks} chunks ({stored} Gaussians stored) on {on}"


def segment_sequence(
    seq: FrameSequence,
    path: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    *,
    on_chunk: ChunkProgress | None = None,
    layout: Choice | None = None,
    cameras: Sequence[Camera] = (),
    on_stage: StageProgress | None = None,
) -> SegmentReport:
    """Segment a frame sequence window by window (memory depends on the window, not the
    length), in windows of whole frames (``layout`` when already chosen); the other arguments
    as for :func:`segment_scene`."""
    stage = on_stage or _unheard
    options = options or SegmentOptions()
    ready = _sequence_ready(seq, options, layout=layout, cameras=cameras, stage=stage)
    return _written(ready, path, on_chunk)


def _sequence_ready(
    seq: FrameSequence,
    options: SegmentOptions,
    *,
    layout: Choice | None,
    cameras: Sequence[Camera],
    stage: StageProgress,
) -> _Ready:
    """A frame sequence planned in whole-frame windows, its view and layers measured on sampled
    frames; its windows are read only as they are encoded."""
    max_count = max_gaussians_per_chunk(options.max_pixels, SH_BANDS_BY_COEFFS[seq.sh_coeffs])
    if layout is None:
        stage(f"choosing the layout of {seq.count} frames (encoding the first)")
    choice = layout or sequence_layout(seq, options, max_count)
    per_window = max(1, round(choice.chosen.layout.window_s * seq.fps))
    window_s = per_window / seq.fps
    options = replace(options, window_s=window_s, policy=choice.chosen.layout.policy)
    plan = Plan(0.0, seq.count / seq.fps, window_s, -(-seq.count // per_window), {}, 0)
    fields: dict[str, Any] = {
        "gaussians": None,  # what the chunks hold: each window leaves out its faint ones
        "stored": None,
        "fps": seq.fps,
        "timeline_type": 0,
        "temporal": {},
        "sh_bands": SH_BANDS_BY_COEFFS[seq.sh_coeffs],
    }
    views, layering = _sequence_measured(
        seq, options, cameras=cameras, stage=stage, max_count=max_count
    )
    total = sequence_chunks(seq, per_window, max_count, layering)
    faint_left = options.quality < QUALITY_MAX
    stage(_encoding(total, seq.gaussians, options.workers, faint_left=faint_left))
    meter = Meter(sum(frames_work(seq.shapes, seq.sh_coeffs, layering.sh_apart)))
    chunks = sequence_encoded(
        seq, per_window, max_count, layering, plan=plan, options=options, meter=meter
    )
    return _Ready(
        chunks, total, plan, fields, options, views, layering, meter, choice, seq.gaussians
    )


def _sequence_measured(
    seq: FrameSequence,
    options: SegmentOptions,
    *,
    cameras: Sequence[Camera],
    stage: StageProgress,
    max_count: int,
) -> tuple[Views, LayerPlan]:
    """A sequence's views and layers, measured on frames spread over it."""
    measuring = "rendering sampled frames"
    stage(_layers_stage(options.layers, measuring, "reading sampled frames for the view"))
    framing, measured = sampled_frames(seq)
    views = views_of(framing, cameras)
    del framing
    layering = sequence_layers(
        seq, measured, views.view, options.layers, options.sh_apart, told=stage
    )
    if options.layers is None:
        layering = layers_within_flipbook(seq, measured, layering, max_count, options, stage=stage)
    del measured
    return views, layering


def merge_or_frames(
    seq: FrameSequence, merged: Scene, options: SegmentOptions
) -> tuple[str | None, Choice]:
    """Why to segment the sequence frame by frame rather than as ``merged`` (None: as merged),
    and the layout of the form chosen, for segment_scene or segment_sequence."""
    max_count = max_gaussians_per_chunk(options.max_pixels, merged.gaussians.sh_bands)
    per_frame = sequence_layout(seq, options, max_count)
    whole = scene_layout(merged, options, max_count)
    if whole is None:  # a merge always has a timeline; kept frame by frame if not
        return "the merge has no timeline", per_frame
    why = why_not_merged(per_frame, whole)
    return why, (whole if why is None else per_frame)
