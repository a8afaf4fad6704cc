"""Encoding parts into chunk payloads, here or on an engine (segment/engines.py), and handing
them back in container order with what the index records of each (:class:`PartInfo`)."""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from ..codec.bundle import bundle_bytes
from ..codec.chunk import encode_chunk
from ..codec.precision import QUALITY_MAX
from ..codec.sh_bands import encode_sh_bands
from ..columns import down
from ..framing import vec3
from ..model import Scene, reference_times
from ..schemas.manifest import Box
from ..temporal import lifespans
from .engines import REPLACE_AFTER_GAUSSIANS, Engine, HandOver, engine
from .jobs import ChunkJob, Part, part_work
from .meter import POLL_S, Meter, palette_progress, report_progress
from .options import SegmentOptions
from .plan import NodeKey, Plan

BOX_SAMPLES = 9
"""Times at which moving centres are sampled for chunk bounding boxes."""

_Tag = TypeVar("_Tag")

_Result = TypeVar("_Result")


def encode_job_payload(
    scene: Scene, seed: int, quality: int = QUALITY_MAX, sh_bands: bool = False
) -> bytes:
    """A chunk's standalone .sog bytes, or with ``sh_bands`` its SH-band chunk's bytes; the SH
    palette's progress reported as the job's."""
    coeffs = scene.gaussians.shN.shape[1]

    def fitted(fraction: float) -> None:
        report_progress(fraction if sh_bands else palette_progress(coeffs, fraction))

    if sh_bands:
        bands = encode_sh_bands(scene, seed=seed, quality=quality, on_palette=fitted)
        return bundle_bytes(bands)
    files = encode_chunk(scene, seed=seed, quality=quality, on_palette=fitted)
    return bundle_bytes(files)


def _bounds(scene: Scene, start: float, end: float) -> Box:
    """Bounding box of the chunk's centres at every time of [start, end]: moving centres
    sampled at BOX_SAMPLES times (a straight path at its ends), each widened by h^2/8 max|x''|,
    the most a path leaves the chord between samples h apart."""
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
class JobParts:
    """The parts of a scene in memory, known up front as jobs: encoded largest first, written
    in job order."""

    jobs: Sequence[ChunkJob]
    make: Callable[[ChunkJob], Part]
    work: Callable[[ChunkJob], float]
    """What encoding a job costs, known before its part is made."""

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


def encoded(
    parts: Iterable[Part], plan: Plan, options: SegmentOptions, meter: Meter
) -> Generator[tuple[PartInfo, bytes], None, None]:
    """(info, payload) in input order, encoded here (one worker, no cluster) or by the engine
    of ``options`` with at most its slots in flight; the parent keeps only each part's
    :class:`PartInfo`, so memory does not grow with the scene's length."""
    if options.workers <= 1 and options.cluster is None:
        yield from encoded_here(parts, plan, options.seed, options.quality, meter)
        return
    largest = _largest_job(parts)
    with engine(options.workers, options.cluster, meter.advance, largest_job=largest) as running:
        meter.slots = running.slots
        if isinstance(parts, JobParts):
            yield from _largest_first(parts, plan, options, running, meter)
        else:
            started = submitted(parts, plan, options, running, meter)
            yield from in_order(started, running.slots, meter)


def _largest_job(parts: Iterable[Part]) -> int:
    """Gaussians of the largest job among ``parts`` (REPLACE_AFTER_GAUSSIANS when not known up
    front: each in a process of its own)."""
    if isinstance(parts, JobParts):
        return max((len(job.indices) for job in parts.jobs), default=1)
    return REPLACE_AFTER_GAUSSIANS


def encoded_here(
    parts: Iterable[Part], plan: Plan, seed: int, quality: int, meter: Meter | None = None
) -> Iterator[tuple[PartInfo, bytes]]:
    """(info, payload) of each part, encoded in this process."""
    for part in parts:
        info = describe_part(part, plan)
        with meter.job(part_work(part)) if meter else contextlib.nullcontext():
            payload = encode_job_payload(part.scene, seed, quality, part.sh_of is not None)
        yield info, payload


def submitted(
    parts: Iterable[Part], plan: Plan, options: SegmentOptions, running: Engine, meter: Meter
) -> Iterator[tuple[PartInfo, Future[bytes]]]:
    """Each part's info and the future of its payload, submitted as it is asked for."""
    for part in parts:
        info = describe_part(part, plan)
        future = _submit(running, meter, part, part_work(part), options)
        del part
        yield info, future


def in_order(
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
    """Encode ``part`` on the engine as a job of ``work`` (its Gaussians dropped once sent)."""
    has_bands = part.sh_of is not None
    args = (HandOver(part.scene), options.seed, options.quality, has_bands)
    return metered(running, meter, work, encode_job_payload, *args)


def metered(
    running: Engine, meter: Meter, work: float, job: Callable[..., _Result], *args: Any
) -> Future[_Result]:
    """Run ``job(*args)`` on the engine as one job of ``work`` on the meter."""
    token = meter.start(work)
    future = running.submit(token, job, *args)
    meter.ends_with(token, future)
    return future


def _largest_first(
    parts: JobParts, plan: Plan, options: SegmentOptions, running: Engine, meter: Meter
) -> Generator[tuple[PartInfo, bytes], None, None]:
    """(info, payload) in job order, the jobs encoded costliest first with at most
    ``running.slots`` in flight (so no core idles while another encodes the biggest last)."""
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


Encoded = Generator[tuple[PartInfo, bytes], None, None]
"""(what the index records, payload) of each chunk, in container order."""
