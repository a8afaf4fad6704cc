"""Segment a scene into a ``.tsogs`` container: plan, split spatially, encode in parallel, pack.

A 4D scene is cut into time windows; a static scene is a stream of one moment (0 s) in one
window, split spatially and into quality layers like any window.

Chunks are encoded in worker processes (``workers``) and written in a fixed order, so the same
scene and options give a byte-identical container whatever the worker count.
"""

from __future__ import annotations

import contextlib
import itertools
import os
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from .._version import __version__
from ..codec.bundle import bundle_bytes
from ..codec.chunk import encode_chunk
from ..codec.layout import image_size
from ..codec.precision import QUALITY_MAX, faint_at, without_faint
from ..codec.sh_bands import encode_sh_bands, without_sh
from ..columns import down
from ..constants import (
    DEFAULT_MAX_PIXELS,
    GENERATOR,
    SH_BANDS_BY_COEFFS,
    SH_CENTROIDS_PER_ROW,
    SH_COEFFS_BY_BANDS,
    WEBP_MAX_SIDE,
)
from ..container.objects import container_output
from ..errors import InputError
from ..framing import FRAMING_SAMPLE, dense_core, framing_sample, opening_view, vec3
from ..io.objects import size_of
from ..io.sequence import FrameSequence, FrameStack, FrameWindow
from ..machine import release_freed_memory
from ..model import Gaussians, Scene, reference_times
from ..morton import morton_parts
from ..schemas.cameras import CaptureCamera
from ..schemas.manifest import Box, ChunkEntry, Layer, Manifest, Node, Policy
from ..sh_palette import palette_size
from ..temporal import lifespans, time_range
from .engines import Engine, HandOver, engine
from .layers import (
    MEASURE_TIMES,
    ONE_LAYER_ASKED,
    LayerPlan,
    check_layers,
    importance,
    plan_layers,
)
from .layout import (
    Choice,
    Costs,
    Lifespans,
    choose_layout,
    chunk_counts,
    measure_costs,
    time_slices,
    why_not_merged,
)
from .meter import POLL_S, Meter, encode_work, palette_progress, report_progress, share_of
from .plan import DEFAULT_MAX_COPIES, NodeKey, Plan, make_plan, window_count

DEFAULT_POLICY: Policy = "hybrid"
"""The policy of frame sequences stored per frame (nothing crosses a window: any would do)."""
MIN_PIXELS = 16
BOX_SAMPLES = 9
"""Times at which moving centres are sampled for chunk bounding boxes."""
Ints = npt.NDArray[np.int64]
ChunkProgress = Callable[[int, int, float | None], None]
"""Told of each chunk written, every ``meter.TICK_S`` while none is and once the first ETA is
known: chunks written, chunks in all, and the seconds encoding has left by the work done so
far (None until a job has finished or reported progress; segment/meter.py)."""
_Tag = TypeVar("_Tag")
_Result = TypeVar("_Result")
StageProgress = Callable[[str], None]
"""Told what segmenting does next, before each phase that can take a while."""


@dataclass(frozen=True)
class SegmentOptions:
    """How to segment; defaults are the measured choices of docs/design/segmenter.md. A window
    or policy left None is chosen for the scene by the cost model (segment/layout.py)."""

    window_s: float | None = None
    policy: Policy | None = None
    max_pixels: int = DEFAULT_MAX_PIXELS
    max_copies: int = DEFAULT_MAX_COPIES
    workers: int = 1
    seed: int = 0
    slice_s: float | None = None
    """Chunks of a node cut by start time into slices this long: chosen with the layout, or
    used as given with an explicit window (none unless given)."""
    quality: int = QUALITY_MAX
    """Error budgets of the chunks' codes, 0..100 (codec/precision.py; 100: full precision)."""
    layers: int | None = None
    """Quality layers (segment/layers.py): None chooses by measurement, 1 is one layer."""
    sh_apart: bool = True
    """A layered stream keeps its base's SH bands in SH-band chunks (spec §8.7); False keeps
    them in the base (the layout before them, for comparisons)."""
    cluster: str | None = None
    """Encode on Dask (segment/engines.py): ``local`` for a LocalCluster of ``workers``
    processes, or a scheduler address; None encodes here or in a local process pool."""


@dataclass(frozen=True)
class Views:
    """The capture cameras an index stores and the view a player opens the scene from."""

    cameras: list[CaptureCamera]
    view: CaptureCamera | None
    core: dict[str, Any] | None
    why: str = ""
    """Why the view is the one it is (framing.opening_view)."""

    @classmethod
    def of(cls, gaussians: Gaussians, cameras: Sequence[CaptureCamera]) -> Views:
        """``cameras``, the default view and the dense core of a scene whose base (or first
        frame) is ``gaussians`` (measured on a sample of a big scene); no view or core for a
        scene with nothing visible to frame."""
        sample = framing_sample(gaussians)
        try:
            centre, radius = dense_core(sample)
        except InputError:
            return cls(list(cameras), cameras[0] if cameras else None, None, "nothing visible")
        core = {"center": vec3(centre), "radius": radius}
        view, why = opening_view(sample, cameras, (centre, radius))
        return cls(list(cameras), view, core, why)


@dataclass(frozen=True)
class ChunkJob:
    """One chunk to encode: its node, its Gaussians (indices into the scene) and layer; for
    an SH-band chunk, the id of the chunk whose bands it holds."""

    key: NodeKey
    indices: Ints
    layer: int = 0
    sh_of: int | None = None


@dataclass
class SegmentReport:
    """What segmenting produced."""

    path: str
    bytes: int
    chunks: int
    windows: int
    gaussians: int
    stored: int
    dropped: int
    bytes_per_level: dict[int, int] = field(default_factory=dict)
    bytes_per_window: list[int] = field(default_factory=list)
    """Bytes of the window chunks (level 0) of each window, in time order."""
    layout: Choice | None = None
    """The layout used, its estimates, the others tried and why it was chosen."""
    view: CaptureCamera | None = None
    """Where a player opens the scene (the index's ``view``)."""
    view_why: str = ""
    """Why that view (framing.opening_view)."""
    layers: list[Layer] = field(default_factory=list)
    """The index's quality layers (empty: one layer)."""
    layers_why: str = ""
    """How the layers were chosen (segment/layers.py)."""
    faint: int = 0
    """Gaussians too faint to store at the quality, left out (precision.faint_at)."""
    start_s: float = 0.0
    end_s: float = 0.0
    """The stream's time range (the index's ``scene.start_s``, ``scene.end_s``)."""
    static: bool = False
    """A static scene: a stream of one moment (no timeline)."""
    duration_assumed: bool = False
    """The scene's length was assumed by its reader (the index's ``duration_assumed``)."""


def palette_pixels(count: int, sh_bands: int) -> int:
    """Most pixels the shN centroid image of a ``count``-Gaussian chunk can take (0 without
    SH): one row of SH_CENTROIDS_PER_ROW entries x coefficients per 64 palette entries, the
    palette holding at most palette_size(count) entries (codec/sog_encode.py)."""
    coeffs = SH_COEFFS_BY_BANDS[sh_bands]
    if coeffs == 0 or count < 1:
        return 0
    rows = -(-palette_size(count) // SH_CENTROIDS_PER_ROW)
    return rows * SH_CENTROIDS_PER_ROW * coeffs


MAX_CHUNK_GAUSSIANS = 1 << 20
"""No chunk holds more Gaussians than this, whatever the pixel budget allows (4096^2 pixels
take 8M): one encode job must not hold most of a scene. A generated 5M-Gaussian SH3
FreeTimeGS checkpoint with long lifespans was one 5M chunk: 283 s on one worker while the
other idled, that worker at 10 GB (docs/design/cluster.md). The SH palette saturates at 65536
entries from 65536 Gaussians on, so bigger chunks gain little from sharing one."""


def max_gaussians_per_chunk(max_pixels: int, sh_bands: int = 0) -> int:
    """Largest Gaussian count whose SOG images (the SH palette's included) fit in
    ``max_pixels`` pixels each (and in WebP), at most MAX_CHUNK_GAUSSIANS."""
    if max_pixels < MIN_PIXELS or max_pixels > WEBP_MAX_SIDE * WEBP_MAX_SIDE:
        raise InputError(
            f"pixel budget must be between {MIN_PIXELS} and {WEBP_MAX_SIDE}^2, got {max_pixels}",
            where="--max-pixels",
        )
    if palette_pixels(1, sh_bands) > max_pixels:
        raise InputError(
            f"a chunk with {sh_bands} SH bands needs a {palette_pixels(1, sh_bands)}-pixel "
            f"palette image, over the budget of {max_pixels}",
            where="--max-pixels",
        )
    lo, hi = 1, max_pixels
    while lo < hi:
        mid = (lo + hi + 1) // 2
        try:
            w, h = image_size(mid)
            fits = w * h <= max_pixels and palette_pixels(mid, sh_bands) <= max_pixels
        except InputError:
            fits = False
        lo, hi = (mid, hi) if fits else (lo, mid - 1)
    return min(lo, MAX_CHUNK_GAUSSIANS)


STATIC_WINDOW_S = 1.0
"""The ``window_s`` of a static scene's index: its one window holds the whole scene, a stream
of one moment at 0 s (any positive length would do: every time falls in window 0)."""


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
    """The options with the chosen window and policy filled in (a static scene's: its one
    window, and the policy given or the default; nothing crosses a window)."""
    if choice is None:
        policy = options.policy or DEFAULT_POLICY
        return replace(options, window_s=STATIC_WINDOW_S, policy=policy, slice_s=None)
    layout = choice.chosen.layout
    return replace(options, window_s=layout.window_s, policy=layout.policy, slice_s=layout.slice_s)


def node_groups(
    scene: Scene, plan: Plan, slice_s: float | None = None
) -> list[tuple[NodeKey, Ints]]:
    """Every node's Gaussians, cut by start time into slices of ``slice_s`` when given
    (layout.py), so each chunk's own visible interval is short; ordered by node start time,
    coarser levels first, then by slice, so the chunks one seek needs sit close together."""
    start = lifespans(scene.timeline)[0] if scene.timeline is not None else None
    keys = sorted(plan.buckets, key=lambda k: (plan.node_interval(k)[0], -k.level, k.index))
    return [
        (key, group)
        for key in keys
        for group in _by_slice(plan.buckets[key], start, plan.node_interval(key)[0], slice_s)
    ]


def chunk_jobs(
    scene: Scene,
    groups: Sequence[tuple[NodeKey, Ints]],
    max_count: int,
    layer_of: Ints | None = None,
) -> list[ChunkJob]:
    """Split every group (:func:`node_groups`) into contiguous Morton runs of at most
    ``max_count``, by quality layer (``layer_of``: each Gaussian's; None: one layer). A run's
    members stay in index order: the encoder puts each chunk in its own Morton order.

    Jobs are ordered by layer, then in the groups' order, so the chunks one seek needs at one
    quality sit close together in the file.
    """
    jobs: list[ChunkJob] = []
    layers = int(layer_of.max(initial=0)) + 1 if layer_of is not None else 1
    for layer in range(layers):
        for key, group in groups:
            members = group if layer_of is None else group[layer_of[group] == layer]
            if members.size == 0 and layers > 1:
                continue
            parts = max(1, int(chunk_counts(members.size, max_count)))  # empty: one empty chunk
            runs = morton_parts(scene.gaussians.means[members], parts)
            jobs.extend(ChunkJob(key, members[run], layer) for run in runs)
    return jobs


def with_sh_jobs(jobs: Sequence[ChunkJob], first_id: int = 0) -> list[ChunkJob]:
    """``jobs`` (layer by layer, as :func:`chunk_jobs` orders them, the first to be chunk
    ``first_id``) with the SH bands of every base chunk as a chunk of its own at the start of
    layer 1: the base is stored with DC colour only, so the first picture waits for no SH
    (codec/sh_bands.py)."""
    base = [job for job in jobs if job.layer == 0]
    bands = [ChunkJob(job.key, job.indices, 1, first_id + i) for i, job in enumerate(base)]
    return [*base, *bands, *(job for job in jobs if job.layer > 0)]


def job_part(scene: Scene, job: ChunkJob, split: bool) -> Part:
    """The part a job encodes: its Gaussians, without SH bands for a base chunk whose bands
    are split off."""
    source = without_sh(scene) if _bare(job, split) else scene  # bands never copied
    return Part(job.key, source.subset(job.indices), job.layer, job.sh_of)


def job_work(scene: Scene, job: ChunkJob, split: bool) -> float:
    """What encoding :func:`job_part`'s part costs (segment/meter.py), before it is made."""
    coeffs = 0 if _bare(job, split) else scene.gaussians.shN.shape[1]
    return encode_work(job.indices.size, coeffs)


def _bare(job: ChunkJob, split: bool) -> bool:
    """Whether the job's part is stored without SH bands (a base chunk whose bands are split
    off into an SH-band chunk)."""
    return split and job.layer == 0


def _by_slice(
    members: np.ndarray, start: np.ndarray | None, node_start: float, slice_s: float | None
) -> list[np.ndarray]:
    """A node's members grouped by time slice, in slice order (one group without slices)."""
    if start is None or slice_s is None:
        return [members]
    slices = time_slices(start[members], np.full(members.size, node_start), slice_s)
    order = np.argsort(slices, kind="stable")
    cut = np.flatnonzero(np.diff(slices[order])) + 1
    return np.split(members[order], cut)


def encode_job_payload(
    scene: Scene, seed: int, quality: int = QUALITY_MAX, sh_bands: bool = False
) -> bytes:
    """A chunk's standalone .sog bytes, or with ``sh_bands`` its SH-band chunk's bytes (run
    in worker processes); the SH palette's progress reported as the job's (segment/meter.py).
    ``scene`` is the job's own part, taken over by the encoder (``encode_chunk``'s
    ``given_up``): describe it first."""
    coeffs = scene.gaussians.shN.shape[1]

    def fitted(fraction: float) -> None:
        report_progress(fraction if sh_bands else palette_progress(coeffs, fraction))

    if sh_bands:
        bands = encode_sh_bands(scene, seed=seed, quality=quality, on_palette=fitted, given_up=True)
        return bundle_bytes(bands)
    files = encode_chunk(scene, seed=seed, quality=quality, on_palette=fitted, given_up=True)
    return bundle_bytes(files)


def _bounds(scene: Scene, start: float, end: float) -> Box:
    """Bounding box of the chunk's centres at every time of [start, end].

    Moving centres are sampled at ``BOX_SAMPLES`` times; between two samples h apart a path
    leaves their chord by at most h^2/8 max|x''|, so each Gaussian's samples are widened by
    that bound (|x''| bounded from its coefficients) and the box holds the whole path. A
    straight path (linear motion) needs only its ends: its evaluation is monotone in t, in
    floating point too, so the box is the one all samples give, in less time.
    """
    means = scene.gaussians.means.astype(np.float64)
    coeffs = scene.temporal.get("means")
    if coeffs is None or scene.timeline is None or len(scene) == 0 or end <= start:
        lo, hi = down(np.min, means, initial=np.inf), down(np.max, means, initial=-np.inf)
    else:
        c = coeffs.astype(np.float64)  # (N, order, 3)
        ref = reference_times(scene.timeline)
        k = np.arange(1, c.shape[1] + 1)
        reach = np.maximum(np.abs(start - ref), np.abs(end - ref))  # largest |t - t_ref|
        curvature = np.einsum(
            "nk,nkc->nc", k * (k - 1) * reach[:, None] ** np.maximum(k - 2, 0), np.abs(c)
        )
        samples = BOX_SAMPLES if c.shape[1] > 1 else 2
        step = (end - start) / (samples - 1)
        margin = curvature * step * step / 8
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for t in np.linspace(start, end, samples):
            at = means + np.einsum("nk,nkc->nc", (t - ref)[:, None] ** k, c)
            lo = np.minimum(lo, down(np.min, at - margin))
            hi = np.maximum(hi, down(np.max, at + margin))
    if not np.all(np.isfinite(lo)):
        lo = hi = np.zeros(3)
    return Box(min=vec3(lo), max=vec3(hi))


def _interval(scene: Scene, node: tuple[float, float]) -> tuple[float, float]:
    """Seconds in which any Gaussian of the chunk is visible, clipped to its node."""
    if scene.timeline is None or len(scene) == 0:
        return node
    start, end = lifespans(scene.timeline)
    return max(node[0], float(start.min())), min(node[1], float(end.max()))


@dataclass(frozen=True)
class Part:
    """One chunk to encode: its node, its Gaussians and its quality layer (for an SH-band
    chunk, the host's Gaussians and the host's id)."""

    key: NodeKey
    scene: Scene
    layer: int = 0
    sh_of: int | None = None


@dataclass(frozen=True)
class JobParts:
    """The parts of a scene in memory, known up front as jobs: they may be encoded in any
    order (largest first, see :func:`_largest_first`) and are written in job order."""

    jobs: Sequence[ChunkJob]
    make: Callable[[ChunkJob], Part]
    work: Callable[[ChunkJob], float]
    """What encoding a job costs (segment/meter.py), known before its part is made."""

    def __iter__(self) -> Iterator[Part]:
        return (self.make(job) for job in self.jobs)


@dataclass(frozen=True)
class PartInfo:
    """What the index records of a part, computed before its arrays are handed to a worker."""

    key: NodeKey
    count: int
    start_s: float
    end_s: float
    bbox: Box
    layer: int
    sh_of: int | None


def describe_part(part: Part, plan: Plan) -> PartInfo:
    """A part's count, visible interval (clipped to its node) and bounding box."""
    start, end = _interval(part.scene, plan.node_interval(part.key))
    bbox = _bounds(part.scene, start, end)
    return PartInfo(part.key, len(part.scene), start, end, bbox, part.layer, part.sh_of)


def _encoded(
    parts: Iterable[Part], plan: Plan, options: SegmentOptions, meter: Meter
) -> Generator[tuple[PartInfo, bytes], None, None]:
    """(info, payload) in input order, encoded here (one worker, no cluster) or by the engine
    of ``options`` (segment/engines.py) with at most its slots in flight.

    The parent keeps only each part's small :class:`PartInfo`, so peak memory is the part being
    produced plus the ones being encoded, whatever the scene length. Parts known up front
    (:class:`JobParts`) are encoded costliest first.
    """
    if options.workers <= 1 and options.cluster is None:
        yield from encoded_here(parts, plan, options.seed, options.quality, meter)
        return
    with engine(options.workers, options.cluster, meter.advance) as running:
        meter.slots = running.slots
        if isinstance(parts, JobParts):
            yield from _largest_first(parts, plan, options, running, meter)
        else:
            started = _submitted(parts, plan, options, running, meter)
            yield from _in_order(started, running.slots, meter)


def encoded_here(
    parts: Iterable[Part], plan: Plan, seed: int, quality: int, meter: Meter | None = None
) -> Iterator[tuple[PartInfo, bytes]]:
    """(info, payload) of each part, encoded in this process: the one-process engine, and a
    window job in its worker."""
    for part in parts:
        info = describe_part(part, plan)  # before the encoder, which takes the part over
        with meter.job(part_work(part)) if meter else contextlib.nullcontext():
            payload = encode_job_payload(part.scene, seed, quality, part.sh_of is not None)
        yield info, payload


def part_work(part: Part) -> float:
    """What encoding a part costs (segment/meter.py): its SH bands, if it keeps them, weigh
    most."""
    return encode_work(len(part.scene), part.scene.gaussians.shN.shape[1])


def _submitted(
    parts: Iterable[Part], plan: Plan, options: SegmentOptions, running: Engine, meter: Meter
) -> Iterator[tuple[PartInfo, Future[bytes]]]:
    """Each part's info and the future of its payload, submitted as it is asked for (this
    process keeps no part once it is handed over)."""
    for part in parts:
        info = describe_part(part, plan)
        future = _submit(running, meter, part, part_work(part), options)
        del part
        yield info, future


def _in_order(
    started: Iterable[tuple[_Tag, Future[_Result]]], slots: int, meter: Meter
) -> Iterator[tuple[_Tag, _Result]]:
    """The results of jobs in the order they were started, at most ``slots`` in flight (the
    next job is started, by iterating ``started``, only when a result is taken)."""
    pending: deque[tuple[_Tag, Future[_Result]]] = deque()
    for tag, future in started:
        pending.append((tag, future))
        if len(pending) >= slots:
            done, oldest = pending.popleft()
            yield done, _awaited(oldest, meter)
    while pending:
        done, oldest = pending.popleft()
        yield done, _awaited(oldest, meter)


def _awaited(future: Future[_Result], meter: Meter) -> _Result:
    """The future's result, the meter ticking while it is awaited."""
    while not wait([future], timeout=POLL_S).done:
        meter.tick()
    return future.result()


def _submit(
    running: Engine, meter: Meter, part: Part, work: float, options: SegmentOptions
) -> Future[bytes]:
    """Encode ``part`` on the engine as a job of ``work`` on the meter (its Gaussians dropped
    here once sent)."""
    has_bands = part.sh_of is not None
    args = (HandOver(part.scene), options.seed, options.quality, has_bands)
    return _metered(running, meter, work, encode_job_payload, *args)


def _metered(
    running: Engine, meter: Meter, work: float, job: Callable[..., _Result], *args: Any
) -> Future[_Result]:
    """Run ``job(*args)`` on the engine as one job of ``work`` on the meter, from now until
    its future completes (its progress reports heard by the meter)."""
    token = meter.start(work)
    future = running.submit(token, job, *args)
    meter.ends_with(token, future)
    return future


def _largest_first(
    parts: JobParts, plan: Plan, options: SegmentOptions, running: Engine, meter: Meter
) -> Generator[tuple[PartInfo, bytes], None, None]:
    """(info, payload) in job order, the jobs encoded costliest first with at most
    ``running.slots`` in flight: a scene whose biggest chunk comes last no longer has one core
    encode it while the other idles (measured: docs/design/segmenter.md, "Parallel
    encoding"). Payloads done early wait, compressed, for their turn."""
    jobs = parts.jobs
    order = iter(sorted(range(len(jobs)), key=lambda i: (-parts.work(jobs[i]), i)))
    in_flight: dict[Future[bytes], tuple[int, PartInfo]] = {}
    finished: dict[int, tuple[PartInfo, bytes]] = {}

    def start_next() -> None:
        i = next(order, None)
        if i is not None:
            part = parts.make(jobs[i])
            future = _submit(running, meter, part, parts.work(jobs[i]), options)
            in_flight[future] = (i, describe_part(part, plan))

    for _ in range(running.slots):
        start_next()
    for turn in range(len(jobs)):
        while turn not in finished:
            done, _ = wait(in_flight, timeout=POLL_S, return_when=FIRST_COMPLETED)
            meter.tick()
            for fut in done:
                i, info = in_flight.pop(fut)
                finished[i] = (info, fut.result())
                start_next()
        yield finished.pop(turn)


def _union(boxes: Sequence[Box]) -> dict[str, list[float]]:
    """The box holding every box (zeros when there are none)."""
    if not boxes:
        return {"min": [0.0] * 3, "max": [0.0] * 3}
    lo = np.min([b.min for b in boxes], axis=0)
    hi = np.max([b.max for b in boxes], axis=0)
    return {"min": lo.tolist(), "max": hi.tolist()}


Encoded = Generator[tuple[PartInfo, bytes], None, None]
"""(what the index records, payload) of each chunk, in container order."""


def _write_container(
    path: str | os.PathLike[str],
    chunks: Encoded,
    *,
    total: int,
    plan: Plan,
    scene_fields: dict[str, Any],
    options: SegmentOptions,
    on_chunk: ChunkProgress | None,
    views: Views,
    layering: LayerPlan,
    meter: Meter,
) -> SegmentReport:
    """Append the chunks as they are encoded (in order) and finish the container with its
    index; the encoding stops (engine shut down) whatever ends the writing."""
    entries: list[ChunkEntry] = []
    keys: list[NodeKey] = []
    per_level: dict[int, int] = {}
    if on_chunk is not None:  # the ETA redrawn while no chunk comes (the first takes longest)
        meter.on_tick = lambda: on_chunk(len(entries), max(total, len(entries)), meter.eta_s())
    with container_output(path) as out, contextlib.closing(chunks) as encoded:
        for i, (info, payload) in enumerate(encoded):
            offset, length, digest = out.add(payload)
            entries.append(
                ChunkEntry(
                    id=i,
                    file=f"chunks/{i:06d}.sog",
                    offset=offset,
                    length=length,
                    sha256=digest,
                    count=info.count,
                    level=info.key.level,
                    node=info.key.index,
                    start_s=info.start_s,
                    end_s=info.end_s,
                    bbox=info.bbox,
                    layer=info.layer,
                    sh_of=info.sh_of,
                )
            )
            keys.append(info.key)
            per_level[info.key.level] = per_level.get(info.key.level, 0) + length
            if on_chunk:
                on_chunk(i + 1, max(total, i + 1), meter.eta_s())
                meter.ticked()
        if scene_fields["gaussians"] is None:  # a frame sequence: each stored once
            counted = sum(e.count for e in entries if e.holds_gaussians)
            scene_fields = {**scene_fields, "gaussians": counted, "stored": counted}
        scene = {
            **scene_fields,
            "start_s": plan.start_s,
            "end_s": plan.end_s,
            "bbox": _union([e.bbox for e in entries]),
            "core": views.core,
        }
        manifest = Manifest.model_validate(
            {
                "generator": f"{GENERATOR} {__version__}",
                "policy": options.policy,
                "window_s": plan.window_s,
                "max_pixels": options.max_pixels,
                "scene": scene,
                "nodes": _nodes(plan, keys),
                "chunks": entries,
                "payload_bytes": sum(e.length for e in entries),
                "cameras": views.cameras,
                "view": views.view,
                "layers": _layers(layering, entries),
            }
        )
        size = out.finish(manifest)
    stored = sum(e.count for e in entries if e.holds_gaussians)
    gaussians = int(scene_fields["gaussians"])
    per_window = [0] * plan.windows
    for e in entries:
        if e.level == 0:
            per_window[e.node] += e.length
    return SegmentReport(
        str(path),
        size,
        len(entries),
        plan.windows,
        gaussians,
        stored,
        plan.dropped,
        per_level,
        per_window,
        view=views.view,
        view_why=views.why,
        layers=manifest.layers,
        layers_why=layering.why,
        start_s=manifest.scene.start_s,
        end_s=manifest.scene.end_s,
        static=manifest.scene.timeline_type is None,
        duration_assumed=manifest.scene.duration_assumed,
    )


def _layers(layering: LayerPlan, entries: Sequence[ChunkEntry]) -> list[Layer]:
    """The index's layers (none for one layer): Gaussians (SH-band chunks hold none), bytes
    and measured PSNR of each."""
    if layering.layers == 1:
        return []
    sizes, counts = [0] * layering.layers, [0] * layering.layers
    for e in entries:
        sizes[e.layer] += e.length
        counts[e.layer] += e.count if e.holds_gaussians else 0
    return [
        Layer(index=k, gaussians=count, bytes=size, psnr_db=psnr)
        for k, (count, size, psnr) in enumerate(zip(counts, sizes, layering.psnr_db, strict=True))
    ]


def _layers_stage(layers: int | None, measuring: str, otherwise: str) -> str:
    """The stage line before the quality layers are planned: what renders to measure them, or
    what runs instead when one layer is asked (nothing is measured then)."""
    return otherwise if layers == 1 else f"measuring quality layers ({measuring})"


def segment_scene(
    scene: Scene,
    path: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    *,
    on_chunk: ChunkProgress | None = None,
    layout: Choice | None = None,
    cameras: Sequence[CaptureCamera] = (),
    on_stage: StageProgress | None = None,
    duration_assumed: bool = False,
) -> SegmentReport:
    """Segment an in-memory scene into the container at ``path`` (published atomically; its
    folder made if missing), in ``layout`` when already chosen for these options (see
    :func:`merge_or_frames`; a static scene is a stream of one moment, one window), with its
    capture ``cameras`` and the view a player opens it from (framing.default_view);
    ``on_stage`` hears of each phase before it starts, ``on_chunk`` of each chunk written
    (and of the ETA while none is). ``duration_assumed``: the scene's reader assumed its
    length (``LoadedScene.duration_assumed``); the index says so (``scene.duration_assumed``)."""
    options = options or SegmentOptions()
    stage = on_stage or (lambda _text: None)
    max_count = max_gaussians_per_chunk(options.max_pixels, scene.gaussians.sh_bands)
    check_layers(options.layers)
    if scene.timeline is None:
        stage(f"a static scene of {len(scene)} Gaussians: one moment, one window")
    elif layout is None:
        stage(f"choosing the layout of {len(scene)} Gaussians (encoding samples)")
    with ThreadPoolExecutor(1, "tsog-view") as beside:  # the view on the other core (5M: 1 s)
        viewing = beside.submit(Views.of, scene.gaussians, cameras)
        choice = layout or scene_layout(scene, options, max_count)
        options = _with_layout(options, choice)
        plan = plan_scene(scene, options)
        views = viewing.result()
    groups, faint = without_faint_members(
        node_groups(scene, plan, options.slice_s), scene, options.quality
    )
    if faint:
        stage(f"leaving out {faint} Gaussians too faint to show at quality {options.quality}")
    stored = sum(len(g) for _, g in groups)
    members = [g for _, g in groups]
    stage(_layers_stage(options.layers, "rendering", "cutting the scene into chunks"))
    release_freed_memory()  # the layout's sample encodes
    layering = plan_layers(scene, members, views.view, options.layers, sh_apart=options.sh_apart)
    release_freed_memory()
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
    report = _write_container(
        path,
        _encoded(parts, plan, options, meter),
        total=len(jobs),
        plan=plan,
        scene_fields=fields,
        options=options,
        on_chunk=on_chunk,
        views=views,
        layering=layering,
        meter=meter,
    )
    return replace(report, layout=choice, faint=faint)


def without_faint_members(
    groups: list[tuple[NodeKey, Ints]], scene: Scene, quality: int
) -> tuple[list[tuple[NodeKey, Ints]], int]:
    """The groups (:func:`node_groups`) without the Gaussians too faint to store at
    ``quality`` (precision.faint_at; a group left empty goes), and how many those are:
    indices, not a copy of the scene without them (a 5M scene is 1.2 GiB)."""
    faint = faint_at(scene, quality)
    count = int(np.count_nonzero(faint))
    if count == 0:
        return groups, 0
    kept = [(key, members[~faint[members]]) for key, members in groups]
    return [(key, members) for key, members in kept if len(members)], count


def _encoding(chunks: int, gaussians: int, workers: int, *, faint_left: bool = False) -> str:
    """The encoding phase, as a stage line (``faint_left``: a sequence's windows have yet to
    leave their faint Gaussians out, so the count is a bound)."""
    on = f"{workers} workers" if workers > 1 else "one process"
    stored = f"at most {gaussians}" if faint_left else f"{gaussians}"
    return f"encoding {chunks} chunks ({stored} Gaussians stored) on {on}"


def window_jobs(scene: Scene, w: int, max_count: int, layering: LayerPlan) -> list[ChunkJob]:
    """The chunk jobs of window ``w`` of a frame sequence: its chunks layer by layer, each
    frame's most important Gaussians in its base (and its SH bands, if any, in SH-band chunks
    at the start of layer 1, their hosts numbered from 0 within the window)."""
    layer_of = None
    if layering.layers > 1:
        layer_of = layering.assign(importance(scene.gaussians), _frame_groups(scene))
    window = [(NodeKey(0, w), np.arange(len(scene)))]
    jobs = chunk_jobs(scene, window, max_count, layer_of)
    return with_sh_jobs(jobs) if layering.sh_apart else jobs


def window_parts(scene: Scene, w: int, max_count: int, layering: LayerPlan) -> list[Part]:
    """The parts of :func:`window_jobs`, all at once (``scene`` is left as it is)."""
    jobs = window_jobs(scene, w, max_count, layering)
    return [job_part(scene, job, layering.sh_apart) for job in jobs]


def parts_taking_over(held: list[Scene], jobs: Sequence[ChunkJob], split: bool) -> Iterator[Part]:
    """The parts of ``jobs``, each cut as it is asked for, from the one scene in ``held``
    (the only reference to it, handed over): the scene is let go as the last part is cut, and
    that part is the scene itself, reordered in place, when it holds every Gaussian. A window
    job's worker held its window twice, as the scene and as its parts (four 500k SH3 frames:
    a worker 4.0x its window above a tiny input's)."""
    for number, job in enumerate(jobs):
        if number + 1 < len(jobs):
            yield job_part(held[0], job, split)
            continue
        scene = held.pop()
        if len(job.indices) == len(scene) and not _bare(job, split):
            part = Part(job.key, scene.reordered(job.indices), job.layer, job.sh_of)
        else:
            part = job_part(scene, job, split)
        del scene
        yield part


def _after(sh_of: int | None, written: int) -> int | None:
    """A host id counted within its window, as a container id (``written`` chunks before)."""
    return None if sh_of is None else sh_of + written


def _sequence_parts(
    seq: FrameSequence, per_window: int, max_count: int, layering: LayerPlan, quality: int
) -> Iterator[Part]:
    """Parts of a frame sequence read here, one window of frames in memory at a time (less
    the Gaussians too faint to store at ``quality``)."""
    written = 0
    for w, first in enumerate(range(0, seq.count, per_window)):
        window = seq.read(first, min(seq.count, first + per_window)).scene
        held = [without_faint(window, quality, given_up=True)]  # read here: nobody else's
        del window
        jobs = window_jobs(held[0], w, max_count, layering)
        for part in parts_taking_over(held, jobs, layering.sh_apart):
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
    """Read a window's frames, cut and encode its chunks one at a time (run in worker
    processes; the window's scene is let go as its last part is cut)."""
    held = [without_faint(job.frames.read().scene, job.quality, given_up=True)]
    split = job.layering.sh_apart
    jobs = window_jobs(held[0], job.index, job.max_count, job.layering)
    works = [job_work(held[0], chunk, split) for chunk in jobs]
    total, done = sum(works), 0.0
    encoded: list[tuple[PartInfo, bytes]] = []
    for part, work in zip(parts_taking_over(held, jobs, split), works, strict=True):
        with share_of(done / total, work / total):
            encoded.extend(encoded_here([part], job.plan, job.seed, job.quality))
        del part  # encoded: not held while the next is cut
        done += work
    return encoded


WINDOWS_PER_SLOT = 2
"""Windows per worker slot from which a sequence's jobs are whole windows (fewer: chunks, so
that a short sequence still keeps every worker busy). As many window jobs are kept in flight:
a job is tiny and its result a window's payloads, and with one per slot a worker that
finished waited for the oldest job's result before it got the next."""


def _sequence_encoded(
    seq: FrameSequence,
    per_window: int,
    max_count: int,
    layering: LayerPlan,
    *,
    plan: Plan,
    options: SegmentOptions,
    meter: Meter,
) -> Encoded:
    """A frame sequence's chunks in container order. On an engine with enough windows to
    keep every worker busy, each job is a window that its worker reads itself, so no frame
    passes through this process (the store or disk is read by the workers); otherwise
    windows are read here and their chunks are the jobs."""
    starts = range(0, seq.count, per_window)
    parts = _sequence_parts(seq, per_window, max_count, layering, options.quality)
    if options.workers <= 1 and options.cluster is None:
        yield from _encoded(parts, plan, options, meter)
        return
    with engine(options.workers, options.cluster, meter.advance) as running:
        meter.slots = running.slots
        if len(starts) < WINDOWS_PER_SLOT * running.slots:
            chunks = _submitted(parts, plan, options, running, meter)
            yield from _in_order(chunks, running.slots, meter)
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
        started = ((w, _tracked(running, job, meter)) for w, job in enumerate(jobs))
        written = 0
        for _, results in _in_order(started, WINDOWS_PER_SLOT * running.slots, meter):
            for info, payload in results:
                yield replace(info, sh_of=_after(info.sh_of, written)), payload
            written += len(results)


def _tracked(running: Engine, job: WindowJob, meter: Meter) -> Future[list[tuple[PartInfo, bytes]]]:
    """Start a window job on the engine, counted by the meter."""
    work = sum(_frames_work(job.frames.shapes, job.frames.sh_coeffs, job.layering.sh_apart))
    return _metered(running, meter, work, encode_window, job)


def _frames_work(shapes: Sequence[tuple[int, int]], sh_coeffs: int, sh_apart: bool) -> list[float]:
    """What encoding each frame costs (segment/meter.py), weighed as :func:`job_work` weighs
    its jobs: one chunk, or with its SH bands apart a bare base and an SH-band chunk."""
    jobs = (0, sh_coeffs) if sh_apart and sh_coeffs else (sh_coeffs,)
    return [sum(encode_work(count, coeffs) for coeffs in jobs) for count, _ in shapes]


def _frame_groups(scene: Scene) -> list[Ints]:
    """Index arrays of each frame of a frame-sequence scene (its frames are contiguous)."""
    assert scene.timeline is not None
    cut = np.flatnonzero(np.diff(scene.timeline.t0)) + 1
    return np.split(np.arange(len(scene)), cut)


def _sequence_chunks(
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


def _sequence_layers(
    seq: FrameSequence,
    measured: _Measured,
    view: CaptureCamera | None,
    layers: int | None,
    sh_apart: bool = True,
) -> LayerPlan:
    """The layers of a frame sequence, measured on the MEASURE_TIMES spread frames
    :func:`_sampled_frames` joined, each frame its own group, as when the chunks are cut."""
    check_layers(layers)
    if layers == 1:
        return ONE_LAYER_ASKED
    times = [(k + 0.5) / seq.fps for k in measured.numbers]
    return plan_layers(measured.scene, measured.groups, view, layers, times, sh_apart=sh_apart)


LAYER_CHECK_MAX_GAUSSIANS = 262144
"""Largest sampled frame whose layered chunks are encoded to weigh them against its own SOG
file (:func:`_layers_within_flipbook`): the check costs one frame's encode, before the others."""


def _layers_within_flipbook(
    seq: FrameSequence,
    measured: _Measured,
    layering: LayerPlan,
    max_count: int,
    options: SegmentOptions,
    *,
    stage: StageProgress,
) -> LayerPlan:
    """``layering``, or one layer where layers would make a flipbook (SOG frames) larger than
    the flipbook itself: the middle sampled frame's chunks, encoded in those layers, against
    that frame's own file. Layers cost each frame two more chunks' zip and meta.json and
    sparser positions (12 generated 30k frames: 1.9 %, 0.99x -> 1.01x the flipbook)."""
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


def segment_sequence(
    seq: FrameSequence,
    path: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    *,
    on_chunk: ChunkProgress | None = None,
    layout: Choice | None = None,
    cameras: Sequence[CaptureCamera] = (),
    on_stage: StageProgress | None = None,
) -> SegmentReport:
    """Segment a frame sequence window by window: memory depends on the window, not the length.
    ``layout``: the frames per chunk when already chosen (see :func:`merge_or_frames`);
    ``on_stage`` and ``on_chunk`` as for :func:`segment_scene`.

    Windows are whole frames (``window_s`` rounded to frames; by default the cost model's
    choice, one frame for most flipbooks); a frame's Gaussians live in that frame only, so
    every policy stores each Gaussian once and the policy does not matter.
    """
    options = options or SegmentOptions()
    stage = on_stage or (lambda _text: None)
    max_count = max_gaussians_per_chunk(options.max_pixels, SH_BANDS_BY_COEFFS[seq.sh_coeffs])
    if layout is None:
        stage(f"choosing the layout of {seq.count} frames (encoding the first)")
    choice = layout or sequence_layout(seq, options, max_count)
    per_window = max(1, round(choice.chosen.layout.window_s * seq.fps))
    window_s = per_window / seq.fps
    options = replace(options, window_s=window_s, policy=choice.chosen.layout.policy)
    windows = -(-seq.count // per_window)
    plan = Plan(0.0, seq.count / seq.fps, window_s, windows, {}, 0)
    fields: dict[str, Any] = {
        "gaussians": None,  # what the chunks hold: each window leaves out its faint ones
        "stored": None,
        "fps": seq.fps,
        "timeline_type": 0,
        "temporal": {},
        "sh_bands": SH_BANDS_BY_COEFFS[seq.sh_coeffs],
    }
    stage(
        _layers_stage(
            options.layers, "rendering sampled frames", "reading sampled frames for the view"
        )
    )
    release_freed_memory()  # the layout's sample encodes (and the merge probe's frames)
    framing, measured = _sampled_frames(seq)  # only the layers' frames are kept
    views = Views.of(framing, cameras)
    del framing
    release_freed_memory()
    layering = _sequence_layers(seq, measured, views.view, options.layers, options.sh_apart)
    if options.layers is None:
        layering = _layers_within_flipbook(seq, measured, layering, max_count, options, stage=stage)
    del measured
    release_freed_memory()
    total = _sequence_chunks(seq, per_window, max_count, layering)
    stage(
        _encoding(total, seq.gaussians, options.workers, faint_left=options.quality < QUALITY_MAX)
    )
    meter = Meter(sum(_frames_work(seq.shapes, seq.sh_coeffs, layering.sh_apart)))
    encoded = _sequence_encoded(
        seq, per_window, max_count, layering, plan=plan, options=options, meter=meter
    )
    report = _write_container(
        path,
        encoded,
        total=total,
        plan=plan,
        scene_fields=fields,
        options=options,
        on_chunk=on_chunk,
        views=views,
        layering=layering,
        meter=meter,
    )
    return replace(report, layout=choice, faint=seq.gaussians - report.gaussians)


VIEW_FRAMES = 5
"""Frames of a sequence (evenly spread) whose Gaussians the opening view frames."""


def _spread(count: int, n: int) -> list[int]:
    """At most ``n`` frame numbers of ``count`` spread evenly, first and last included."""
    return sorted({round(k) for k in np.linspace(0, count - 1, min(n, count))})


@dataclass(frozen=True)
class _Measured:
    """The frames a sequence's layers are measured on, joined as one type-0 scene: their
    numbers, in order, and each one's rows (its group)."""

    scene: Scene
    numbers: list[int]
    groups: list[Ints]


def _sampled_frames(seq: FrameSequence) -> tuple[Gaussians, _Measured]:
    """The Gaussians of VIEW_FRAMES frames spread over the sequence joined as Views.of samples
    them (FRAMING_SAMPLE in all, each frame its share, without SH bands: the view does not
    look at colour) for the opening view (a first frame alone can be a launching rocket whose
    explosion fills the later frames), and the MEASURE_TIMES spread frames the layers are
    measured on. Each frame is read once and let go as it is sampled and, for the measured
    ones, copied into the joined scene, so no frame is held twice and no sample keeps its
    bands."""
    picks = _spread(seq.count, VIEW_FRAMES)
    numbers = _spread(seq.count, MEASURE_TIMES)
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
    return Gaussians.concat(samples), _Measured(measured, numbers, groups)


COST_FRAMES = 3
"""Frames of a sequence whose costs the layout model averages: the first, the middle and the
last. Frames of one sequence differ, and a model measured on the first alone chose a worse
layout (docs/design/segmenter.md)."""


def sequence_costs(seq: FrameSequence, options: SegmentOptions, max_count: int) -> Costs:
    """The cost model's bytes per Gaussian and per chunk, the mean over COST_FRAMES frames
    spread over the sequence."""
    picks = np.unique(np.linspace(0, seq.count - 1, min(seq.count, COST_FRAMES)).round())
    measured = [
        measure_costs(seq.read(k, k + 1).scene, max_count, options.seed, options.quality)
        for k in picks.astype(int).tolist()
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


def merge_or_frames(
    seq: FrameSequence, merged: Scene, options: SegmentOptions
) -> tuple[str | None, Choice]:
    """Whether to segment the sequence as ``merged`` (its merge) or frame by frame: why frame
    by frame (None: the merged scene is smaller and seeks as cheaply, layout.py), and the
    layout of the form chosen, to pass to segment_scene or segment_sequence."""
    max_count = max_gaussians_per_chunk(options.max_pixels, merged.gaussians.sh_bands)
    per_frame = sequence_layout(seq, options, max_count)
    whole = scene_layout(merged, options, max_count)
    if whole is None:  # a merge always has a timeline; kept frame by frame if not
        return "the merge has no timeline", per_frame
    why = why_not_merged(per_frame, whole)
    return why, (whole if why is None else per_frame)


def _nodes(plan: Plan, keys: Sequence[NodeKey]) -> list[Node]:
    """Manifest nodes (windows first, then coarser levels), each with its chunk ids."""
    members: dict[NodeKey, list[int]] = {}
    for i, key in enumerate(keys):
        members.setdefault(key, []).append(i)
    ordered = [NodeKey(0, w) for w in range(plan.windows)]
    ordered += sorted((k for k in members if k.level > 0), key=lambda k: (k.level, k.index))
    out = []
    for key in ordered:
        start, end = plan.node_interval(key)
        out.append(
            Node(
                level=key.level,
                index=key.index,
                start_s=start,
                end_s=end,
                chunks=members.get(key, []),
            )
        )
    return out
