"""Segment a 4D scene into a ``.tsogs`` container: plan, split spatially, encode in parallel, pack.

Chunks are encoded in worker processes (``workers``) and written in a fixed order, so the same
scene and options give a byte-identical container whatever the worker count.
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .. import __version__
from ..codec.bundle import bundle_bytes
from ..codec.chunk import encode_chunk
from ..codec.layout import image_size
from ..constants import GENERATOR, WEBP_MAX_SIDE
from ..container.writer import ContainerFile
from ..errors import InputError
from ..model import Scene
from ..morton import morton_order
from ..schemas.manifest import Box, ChunkEntry, Manifest, Node, SceneInfo
from ..temporal import evaluate_all, lifespans, time_range
from .plan import DEFAULT_MAX_COPIES, NodeKey, Plan, make_plan

DEFAULT_MAX_PIXELS = 4096 * 4096
DEFAULT_WINDOW_S = 1.0
DEFAULT_POLICY = "hybrid"
MIN_PIXELS = 16
Ints = npt.NDArray[np.int64]
ChunkProgress = Callable[[int, int], None]


@dataclass(frozen=True)
class SegmentOptions:
    """How to segment; defaults are the measured choices of docs/design/segmenter.md."""

    window_s: float = DEFAULT_WINDOW_S
    policy: str = DEFAULT_POLICY
    max_pixels: int = DEFAULT_MAX_PIXELS
    max_copies: int = DEFAULT_MAX_COPIES
    workers: int = 1
    seed: int = 0


@dataclass(frozen=True)
class ChunkJob:
    """One chunk to encode: its node and its Gaussians (indices into the scene)."""

    key: NodeKey
    indices: Ints


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


def max_gaussians_per_chunk(max_pixels: int) -> int:
    """Largest Gaussian count whose SOG images fit in ``max_pixels`` pixels (and in WebP)."""
    if max_pixels < MIN_PIXELS or max_pixels > WEBP_MAX_SIDE * WEBP_MAX_SIDE:
        raise InputError(
            f"pixel budget must be between {MIN_PIXELS} and {WEBP_MAX_SIDE}^2, got {max_pixels}",
            where="--max-pixels",
        )
    lo, hi = 1, max_pixels
    while lo < hi:
        mid = (lo + hi + 1) // 2
        try:
            w, h = image_size(mid)
            fits = w * h <= max_pixels
        except InputError:
            fits = False
        lo, hi = (mid, hi) if fits else (lo, mid - 1)
    return lo


def plan_scene(scene: Scene, options: SegmentOptions) -> Plan:
    """The time plan of a dynamic scene under the options' policy and window."""
    if scene.timeline is None:
        raise InputError("segmenting needs a 4D scene (this input has no timeline)")
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


def chunk_jobs(scene: Scene, plan: Plan, max_count: int) -> list[ChunkJob]:
    """Split every node's Gaussians into contiguous Morton runs of at most ``max_count``.

    Jobs are ordered by node start time, coarser levels first, so the chunks one seek needs
    sit close together in the file.
    """
    jobs: list[ChunkJob] = []
    keys = sorted(plan.buckets, key=lambda k: (plan.node_interval(k)[0], -k.level, k.index))
    for key in keys:
        members = plan.buckets[key]
        ordered = members[morton_order(scene.gaussians.means[members])]
        parts = -(-ordered.size // max_count)
        jobs.extend(ChunkJob(key, run) for run in np.array_split(ordered, parts))
    return jobs


def encode_job_payload(scene: Scene, seed: int) -> bytes:
    """A chunk's standalone .sog bytes (run in worker processes)."""
    return bundle_bytes(encode_chunk(scene, seed=seed))


def _bounds(scene: Scene, start: float, end: float) -> Box:
    """Bounding box of the chunk's centres over [start, end] (5 samples if positions move)."""
    times = np.linspace(start, end, 5) if "means" in scene.temporal else [start]
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for t in times:
        g, _ = evaluate_all(scene, float(t))
        if len(g):
            lo = np.minimum(lo, g.means.min(axis=0))
            hi = np.maximum(hi, g.means.max(axis=0))
    if not np.all(np.isfinite(lo)):
        lo = hi = np.zeros(3)
    return Box.model_validate({"min": lo.tolist(), "max": hi.tolist()})


def _interval(scene: Scene, node: tuple[float, float]) -> tuple[float, float]:
    """Seconds in which any Gaussian of the chunk is visible, clipped to its node."""
    if scene.timeline is None or len(scene) == 0:
        return node
    start, end = lifespans(scene.timeline)
    return max(node[0], float(start.min())), min(node[1], float(end.max()))


def _payloads(
    scene: Scene, jobs: list[ChunkJob], options: SegmentOptions
) -> Iterator[tuple[ChunkJob, Scene, bytes]]:
    """(job, chunk scene, payload) in job order, encoding up to 2 x workers ahead in parallel."""
    if options.workers <= 1:
        for job in jobs:
            part = scene.subset(job.indices)
            yield job, part, encode_job_payload(part, options.seed)
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=options.workers, mp_context=context) as pool:
        pending: deque[tuple[ChunkJob, Scene, Future[bytes]]] = deque()
        queue = iter(jobs)
        for job in queue:
            part = scene.subset(job.indices)
            pending.append((job, part, pool.submit(encode_job_payload, part, options.seed)))
            if len(pending) >= 2 * options.workers:
                done_job, done_part, fut = pending.popleft()
                yield done_job, done_part, fut.result()
        while pending:
            done_job, done_part, fut = pending.popleft()
            yield done_job, done_part, fut.result()


def scene_info(scene: Scene, plan: Plan) -> SceneInfo:
    """The manifest's description of the whole scene."""
    tl = scene.timeline
    means = scene.gaussians.means
    lo = means.min(axis=0) if len(scene) else np.zeros(3)
    hi = means.max(axis=0) if len(scene) else np.zeros(3)
    return SceneInfo.model_validate(
        {
            "gaussians": len(scene),
            "stored": plan.stored,
            "start_s": plan.start_s,
            "end_s": plan.end_s,
            "fps": tl.fps if tl is not None else None,
            "timeline_type": int(tl.type) if tl is not None else None,
            "temporal": {a: int(c.shape[1]) for a, c in scene.temporal.items()},
            "sh_bands": scene.gaussians.sh_bands,
            "bbox": {"min": lo.tolist(), "max": hi.tolist()},
        }
    )


def segment_scene(
    scene: Scene,
    path: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    *,
    on_chunk: ChunkProgress | None = None,
) -> SegmentReport:
    """Segment ``scene`` into the container at ``path`` (published atomically)."""
    options = options or SegmentOptions()
    plan = plan_scene(scene, options)
    jobs = chunk_jobs(scene, plan, max_gaussians_per_chunk(options.max_pixels))
    entries: list[ChunkEntry] = []
    per_level: dict[int, int] = {}
    with ContainerFile(path) as out:
        for i, (job, part, payload) in enumerate(_payloads(scene, jobs, options)):
            offset, length, digest = out.add(payload)
            node = plan.node_interval(job.key)
            start, end = _interval(part, node)
            entries.append(
                ChunkEntry(
                    id=i,
                    file=f"chunks/{i:06d}.sog",
                    offset=offset,
                    length=length,
                    sha256=digest,
                    count=len(part),
                    level=job.key.level,
                    node=job.key.index,
                    start_s=start,
                    end_s=end,
                    bbox=_bounds(part, start, end),
                )
            )
            per_level[job.key.level] = per_level.get(job.key.level, 0) + length
            if on_chunk:
                on_chunk(i + 1, len(jobs))
        manifest = Manifest.model_validate(
            {
                "generator": f"{GENERATOR} {__version__}",
                "policy": options.policy,
                "window_s": options.window_s,
                "max_pixels": options.max_pixels,
                "scene": scene_info(scene, plan),
                "nodes": _nodes(plan, jobs),
                "chunks": entries,
                "payload_bytes": sum(e.length for e in entries),
            }
        )
        size = out.finish(manifest)
    return SegmentReport(
        str(path),
        size,
        len(entries),
        plan.windows,
        len(scene),
        plan.stored,
        plan.dropped,
        per_level,
    )


def _nodes(plan: Plan, jobs: list[ChunkJob]) -> list[Node]:
    """Manifest nodes (windows first, then coarser levels), each with its chunk ids."""
    members: dict[NodeKey, list[int]] = {}
    for i, job in enumerate(jobs):
        members.setdefault(job.key, []).append(i)
    keys = [NodeKey(0, w) for w in range(plan.windows)]
    keys += sorted((k for k in members if k.level > 0), key=lambda k: (k.level, k.index))
    out = []
    for key in keys:
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
