"""Frame sequences, window by window (memory depends on the window, not the length): the
layout's costs, the frames sampled for the view and the layers, and the window jobs."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, replace

import numpy as np

from ..codec.precision import without_faint
from ..codec.sh_bands import without_sh
from ..errors import InputError
from ..framing import FRAMING_SAMPLE, framing_sample
from ..io.objects import size_of
from ..io.sequence import FrameSequence, FrameStack, FrameWindow
from ..model import Gaussians, Scene
from ..schemas.cameras import Camera
from .encoding import (
    Encoded,
    PartInfo,
    encode_job_payload,
    encoded,
    encoded_here,
    in_order,
    metered,
    submitted,
)
from .engines import Engine, engine
from .jobs import Ints, Part, job_part, job_work, window_jobs, window_parts
from .layers import MEASURE_TIMES, ONE_LAYER_ASKED, LayerPlan, check_layers, plan_layers
from .layout import Choice, Costs, Lifespans, choose_layout, chunk_counts, measure_costs
from .meter import Meter, encode_work, share_of
from .options import DEFAULT_POLICY, SegmentOptions, StageProgress
from .plan import Plan, window_count


def _after(sh_of: int | None, written: int) -> int | None:
    """A host id counted within its window, as a container id (``written`` chunks before)."""
    return None if sh_of is None else sh_of + written


def _sequence_parts(
    seq: FrameSequence, per_window: int, max_count: int, layering: LayerPlan, quality: int
) -> Iterator[Part]:
    """Parts of a frame sequence read here, one window in memory at a time (its faint
    Gaussians left out)."""
    written = 0
    for w, first in enumerate(range(0, seq.count, per_window)):
        window = seq.read(first, min(seq.count, first + per_window)).scene
        scene = without_faint(window, quality)
        del window
        jobs = window_jobs(scene, w, max_count, layering)
        for job in jobs:
            part = job_part(scene, job, layering.sh_apart)
            yield replace(part, sh_of=_after(part.sh_of, written))
        written += len(jobs)


@dataclass(frozen=True)
class WindowJob:
    """One window of a frame sequence, read and encoded where the job runs: only the frames'
    locations travel to the worker, only the chunks' payloads and index facts come back."""

    frames: FrameWindow
    index: int
    max_count: int
    layering: LayerPlan
    plan: Plan
    seed: int
    quality: int


def encode_window(job: WindowJob) -> list[tuple[PartInfo, bytes]]:
    """Read a window's frames, cut and encode its chunks one at a time (in a worker)."""
    scene = without_faint(job.frames.read().scene, job.quality)
    split = job.layering.sh_apart
    jobs = window_jobs(scene, job.index, job.max_count, job.layering)
    works = [job_work(scene, chunk, split) for chunk in jobs]
    total, done = sum(works), 0.0
    encoded: list[tuple[PartInfo, bytes]] = []
    for chunk, work in zip(jobs, works, strict=True):
        part = job_part(scene, chunk, split)
        with share_of(done / total, work / total):
            encoded.extend(encoded_here([part], job.plan, job.seed, job.quality))
        del part  # encoded: not held while the next is cut
        done += work
    return encoded


WINDOWS_PER_SLOT = 2
"""Windows per worker slot from which a sequence's jobs are whole windows (fewer: chunks, so a
short sequence keeps every worker busy); as many window jobs are kept in flight per slot."""


def sequence_encoded(
    seq: FrameSequence,
    per_window: int,
    max_count: int,
    layering: LayerPlan,
    *,
    plan: Plan,
    options: SegmentOptions,
    meter: Meter,
) -> Encoded:
    """A frame sequence's chunks in container order: with enough windows to keep every worker
    busy (WINDOWS_PER_SLOT per worker), each job is a window its worker reads itself; otherwise
    windows are read here and their chunks are the jobs."""
    parts = _sequence_parts(seq, per_window, max_count, layering, options.quality)
    starts = range(0, seq.count, per_window)
    if options.workers <= 1 and options.cluster is None:
        yield from encoded(parts, plan, options, meter)
        return
    by_window = len(starts) >= WINDOWS_PER_SLOT * options.workers
    frames = [count for count, _ in seq.shapes]
    largest = max(sum(frames[first : first + per_window]) for first in starts)
    largest = largest if by_window else min(largest, max_count)
    with engine(options.workers, options.cluster, meter.advance, largest_job=largest) as running:
        meter.slots = running.slots
        if not by_window:
            started = submitted(parts, plan, options, running, meter)
            yield from in_order(started, running.slots, meter)
            return
        jobs = (
            WindowJob(
                seq.window(first, min(seq.count, first + per_window)),
                w,
                max_count,
                layering,
                plan,
                options.seed,
                options.quality,
            )
            for w, first in enumerate(starts)
        )
        tracked = ((w, _tracked(running, job, meter)) for w, job in enumerate(jobs))
        written = 0
        for _, results in in_order(tracked, WINDOWS_PER_SLOT * running.slots, meter):
            for info, payload in results:
                yield replace(info, sh_of=_after(info.sh_of, written)), payload
            written += len(results)


def _tracked(running: Engine, job: WindowJob, meter: Meter) -> Future[list[tuple[PartInfo, bytes]]]:
    """Start a window job on the engine, counted by the meter."""
    work = sum(frames_work(job.frames.shapes, job.frames.sh_coeffs, job.layering.sh_apart))
    return metered(running, meter, work, encode_window, job)


def frames_work(shapes: Sequence[tuple[int, int]], sh_coeffs: int, sh_apart: bool) -> list[float]:
    """What encoding each frame costs, weighed as :func:`job_work` weighs its jobs."""
    jobs = (0, sh_coeffs) if sh_apart and sh_coeffs else (sh_coeffs,)
    return [sum(encode_work(count, coeffs) for coeffs in jobs) for count, _ in shapes]


def sequence_chunks(
    seq: FrameSequence, per_window: int, max_count: int, layering: LayerPlan
) -> int:
    """How many chunks :func:`_sequence_parts` yields (for progress), from the frames' sizes."""
    total = 0
    split = layering.sh_apart
    for first in range(0, seq.count, per_window):
        sizes = layering.sizes([c for c, _ in seq.shapes[first : first + per_window]])
        runs = chunk_counts(sizes, max_count).tolist()
        total += max(1, sum(runs)) if layering.layers == 1 else sum(runs) + split * runs[0]
    return total


def sequence_layers(
    seq: FrameSequence,
    measured: Measured,
    view: Camera | None,
    layers: int | None,
    sh_apart: bool = True,
    *,
    told: Callable[[str], None] = lambda _: None,
) -> LayerPlan:
    """The layers of a frame sequence, measured on the frames :func:`sampled_frames` joined,
    each frame its own group (``told``: as :func:`plan_layers`)."""
    check_layers(layers)
    if layers == 1:
        return ONE_LAYER_ASKED
    times = [(k + 0.5) / seq.fps for k in measured.numbers]
    return plan_layers(
        measured.scene, measured.groups, view, layers, times, sh_apart=sh_apart, told=told
    )


LAYER_CHECK_MAX_GAUSSIANS = 262144
"""Largest sampled frame whose layered chunks are weighed against its own SOG file."""


def layers_within_flipbook(
    seq: FrameSequence,
    measured: Measured,
    layering: LayerPlan,
    max_count: int,
    options: SegmentOptions,
    *,
    stage: StageProgress,
) -> LayerPlan:
    """``layering``, or one layer where layers would make a flipbook (SOG frames) larger than
    itself: the middle sampled frame's layered chunks against that frame's own file."""
    if layering.layers == 1 or seq.frames.kind != "sog" or not measured.numbers:
        return layering
    middle = len(measured.numbers) // 2
    number, rows = measured.numbers[middle], measured.groups[middle]
    if len(rows) > LAYER_CHECK_MAX_GAUSSIANS:
        return layering
    try:
        own = size_of(seq.frames.paths[number])
    except OSError:  # gone since it was read: the windows' reads will say so
        return layering
    stage("weighing the layers against the flipbook's own files")
    parts = window_parts(measured.scene.subset(rows), 0, max_count, layering)
    layered = sum(
        len(encode_job_payload(part.scene, options.seed, options.quality, part.sh_of is not None))
        for part in parts
    )
    if layered <= own:
        return layering
    return LayerPlan.single(
        f"one layer: in {layering.layers} layers a sampled frame takes {layered / own:.3f}x "
        "its own SOG file (a flipbook's layers are kept within its bytes; --layers N forces them)"
    )


VIEW_FRAMES = 5
"""Frames of a sequence (evenly spread) whose Gaussians the opening view frames."""


def spread(count: int, n: int) -> list[int]:
    """At most ``n`` frame numbers of ``count`` spread evenly, first and last included."""
    return sorted({round(k) for k in np.linspace(0, count - 1, min(n, count))})


@dataclass(frozen=True)
class Measured:
    """The frames a sequence's layers are measured on, joined as one type-0 scene: their
    numbers, in order, and each one's rows (its group)."""

    scene: Scene
    numbers: list[int]
    groups: list[Ints]


def sampled_frames(seq: FrameSequence) -> tuple[Gaussians, Measured]:
    """A framing sample of VIEW_FRAMES frames spread over the sequence (FRAMING_SAMPLE in all,
    without SH bands) for the opening view, and the MEASURE_TIMES spread frames the layers are
    measured on, joined; each frame is read once."""
    picks = spread(seq.count, VIEW_FRAMES)
    numbers = spread(seq.count, MEASURE_TIMES)
    share = max(1, FRAMING_SAMPLE // max(len(picks), 1))
    sizes = [seq.shapes[k][0] for k in numbers]
    joined = FrameStack(sizes, [seq.shapes[k][1] for k in numbers], seq.sh_coeffs)
    samples: list[Gaussians] = []
    for k in sorted({*picks, *numbers}):
        frame = seq.read(k, k + 1).scene
        if k in picks:
            samples.append(framing_sample(without_sh(frame).gaussians, share))
        if k in numbers:
            joined.put(numbers.index(k), frame.gaussians, str(seq.frames.paths[k]))
        del frame
    bounds = np.cumsum([0, *sizes]).tolist()
    groups = [np.arange(a, b) for a, b in itertools.pairwise(bounds)]
    measured = joined.scene(seq.fps, total=seq.count, numbers=numbers)
    return Gaussians.concat(samples), Measured(measured, numbers, groups)


COST_FRAMES = 3
"""Frames of a sequence whose costs the layout model averages: the first, the middle and the
last (docs/design/segmenter.md)."""


def sequence_costs(seq: FrameSequence, options: SegmentOptions, max_count: int) -> Costs:
    """The cost model's bytes per Gaussian and per chunk, the mean over COST_FRAMES frames."""
    measured = [
        measure_costs(seq.read(k, k + 1).scene, max_count, options.seed, options.quality)
        for k in spread(seq.count, COST_FRAMES)
    ]
    return Costs(
        per_gaussian=float(np.mean([c.per_gaussian for c in measured])),
        per_chunk=float(np.mean([c.per_chunk for c in measured])),
        max_count=max_count,
    )


def sequence_layout(seq: FrameSequence, options: SegmentOptions, max_count: int) -> Choice:
    """Frames per chunk for a frame sequence: the options' window rounded to frames, else the
    cost model's choice (:func:`sequence_costs`)."""
    window_s = options.window_s
    if window_s is not None:
        window_count(0.0, 1.0, window_s)
        window_s = max(1, round(window_s * seq.fps)) / seq.fps
    if seq.count == 0:
        raise InputError("the sequence has no frames")
    costs = sequence_costs(seq, options, max_count)
    life = Lifespans.of_frames([c for c, _ in seq.shapes], seq.fps)
    return choose_layout(life, costs, window_s=window_s, policy=options.policy or DEFAULT_POLICY)
