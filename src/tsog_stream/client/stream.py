"""``StreamClient``: the one reader of a container, for any origin, at any time.

It opens the container with one request, fetches only the chunks a time needs, keeps decoded
chunks in an LRU cache bounded in bytes, prefetches ahead in time order with a bounded number
of requests in flight, and merges chunks that lie close together in the file into one request
(the body is split back into chunks and every chunk's SHA-256 is checked). It also gives single
chunks, seek costs, a full verification, and both layouts (unpack, pack). Paths, ``file://``
and http(s) URLs of a ``.tsogs`` file or of an unpacked folder are read alike; ``Stream``
(:mod:`.sync`) is its synchronous facade. See docs/client.md.
"""

from __future__ import annotations

import asyncio
import bisect
import heapq
import itertools
import math
import os
import time
from collections import OrderedDict
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from types import TracebackType

from ..codec.chunk import decode_chunk_bytes
from ..codec.sh_bands import ShBands, decode_sh_bands_bytes
from ..container.ranges import ByteRange, coalesce
from ..container.sources import ByteSource
from ..container.stream_index import StreamIndex, verify_chunk
from ..errors import InputError
from ..model import Gaussians, Scene
from ..schemas.manifest import ChunkEntry
from .adaptive import (
    HORIZON_S,
    Throughput,
    choose_layers,
    due_order,
    layers_shown,
    startup_allowance,
)
from .costs import SeekCost, seek_cost
from .fetchers import ChunkFetcher, RangeFetcher, make_fetcher
from .http_options import HttpOptions, with_deadline
from .unpacked import pack, unpack
from .verify import VerifyReport, verify_stream

MiB = 1 << 20
Decoded = Scene | ShBands
"""What a chunk decodes to: Gaussians, or the SH bands of another chunk's Gaussians."""
Rank = tuple[float, float]
URGENT: Rank = (-math.inf, 0.0)
REPLAN_S = 0.5
"""Wall seconds between two choices of the layers an adaptive playback fetches."""
MAX_PLAY_FRAMES = 1_000_000
"""Frames one simulated playback may have (9 hours at 30 fps): a bound, so that no choice of
speed and fps makes one that never ends."""


def _check_playback(
    start: float, speed: float, fps: float, duration: float | None, horizon_s: float
) -> None:
    """Refuse playback options that are not finite, or not positive where they must be."""
    checks = {
        "--start": math.isfinite(start),
        "--speed": math.isfinite(speed) and speed > 0,
        "--fps": math.isfinite(fps) and fps > 0,
        "--duration": duration is None or (math.isfinite(duration) and duration >= 0),
        "horizon_s": math.isfinite(horizon_s) and horizon_s >= 0,
    }
    for name, ok in checks.items():
        if not ok:
            raise InputError("expected a finite number, positive for speed and fps", where=name)


def scene_nbytes(scene: Decoded) -> int:
    """Memory held by a decoded chunk's arrays (the cache's measure of size)."""
    if isinstance(scene, ShBands):
        return scene.nbytes
    return sum(a.nbytes for a in scene.arrays())


@dataclass
class CacheStats:
    """Lookups of chunks a frame needed: found decoded (hits) or not (misses)."""

    hits: int = 0
    misses: int = 0

    @property
    def hit_rate(self) -> float:
        """Fraction of lookups that were hits (0 before any lookup)."""
        total = self.hits + self.misses
        return self.hits / total if total else 0.0


class SceneCache:
    """Decoded chunks by id, least recently used evicted first, bounded in bytes."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.nbytes = 0
        self._items: OrderedDict[int, tuple[Decoded, int]] = OrderedDict()

    def __contains__(self, chunk_id: int) -> bool:
        return chunk_id in self._items

    def get(self, chunk_id: int) -> Decoded | None:
        """The chunk if cached (and mark it recently used)."""
        item = self._items.get(chunk_id)
        if item is None:
            return None
        self._items.move_to_end(chunk_id)
        return item[0]

    def put(self, chunk_id: int, scene: Decoded) -> None:
        """Add a chunk, evicting the least recently used ones beyond the byte budget."""
        if chunk_id in self._items:
            return
        size = scene_nbytes(scene)
        self._items[chunk_id] = (scene, size)
        self.nbytes += size
        while self.nbytes > self.max_bytes and len(self._items) > 1:
            _, (_, dropped) = self._items.popitem(last=False)
            self.nbytes -= dropped


@dataclass
class PlayStats:
    """What a playback cost: startup latency, stalls, transfer and cache behaviour; for an
    adaptive one also when the first picture came and how many layers each frame showed."""

    frames: int = 0
    startup_s: float = 0.0
    first_picture_s: float = 0.0
    """Wait for the first picture (the base layer at the start time; = startup_s when not
    adaptive)."""
    layers_shown: dict[int, int] = field(default_factory=dict)
    """Frames shown with each number of layers."""
    stalls: int = 0
    stall_s: float = 0.0
    requests: int = 0
    bytes: int = 0
    hit_rate: float = 0.0
    elapsed_s: float = 0.0


@dataclass(frozen=True)
class PlayedFrame:
    """One frame of a playback: its number, scene time, Gaussians and wait for data."""

    index: int
    t: float
    gaussians: Gaussians
    wait_s: float
    layers: int = 1
    """Quality layers drawn (all of the stream's when not adaptive)."""


@dataclass(frozen=True)
class _PlayPlan:
    """Frame times and budget of one playback."""

    start: float
    end: float
    count: int
    step: float
    budget: float
    horizon: float
    realtime: bool
    speed: float = 1.0


@dataclass
class Playback:
    """An async iterator of played frames; ``stats`` fills in as it runs."""

    frames: AsyncIterator[PlayedFrame]
    stats: PlayStats = field(default_factory=PlayStats)

    def __aiter__(self) -> AsyncIterator[PlayedFrame]:
        return self.frames


@dataclass
class _Job:
    """One queued fetch: a run of chunks read with one request, and their futures."""

    group: list[ChunkEntry]
    futures: dict[int, asyncio.Future[Decoded]]
    started: bool = False
    rank: Rank = (0.0, 0.0)
    """Fetched in rank order (then in order queued): (layer, second due) for a prefetch, so
    every queued base chunk goes before any enhancement; a frame being shown ranks first."""


def _due_rank(t: float) -> Callable[[ChunkEntry], Rank]:
    """A prefetch's rank of a chunk from ``t`` on: its layer, then the second it is due."""
    return lambda c: (float(c.layer), max(c.start_s, t))


def _settle_failed(futures: dict[int, asyncio.Future[Decoded]], exc: BaseException) -> None:
    """Fail the unsettled futures with ``exc`` (an error) or cancel them (a cancellation)."""
    for fut in futures.values():
        if fut.done():
            continue
        if isinstance(exc, Exception):
            fut.set_exception(exc)
            fut.exception()  # a failed prefetch nobody awaits is not an error
        else:
            fut.cancel()


class StreamClient:
    """An opened container: frames at any time, prefetching and simulated playback.

    ``source`` is the :class:`ChunkFetcher` of the source kind (ranges of one ``.tsogs`` file
    or whole files of the unpacked layout); a plain :class:`ByteSource` is read by ranges.
    """

    def __init__(
        self,
        source: ChunkFetcher | ByteSource,
        index: StreamIndex,
        *,
        cache_bytes: int = 256 * MiB,
        concurrency: int = 4,
        coalesce_gap: int | None = 64 * 1024,
    ) -> None:
        if concurrency < 1 or cache_bytes < 0 or (coalesce_gap is not None and coalesce_gap < 0):
            raise InputError("concurrency must be >= 1, cache_bytes and coalesce_gap >= 0")
        self.source: ChunkFetcher = (
            source if isinstance(source, ChunkFetcher) else RangeFetcher(source)
        )
        self.index = index
        self.cache = SceneCache(cache_bytes)
        self.cache_stats = CacheStats()
        self.coalesce_gap = coalesce_gap
        self.concurrency = concurrency
        self.throughput = Throughput(time.monotonic)
        self._queue: list[tuple[Rank, tuple[int, int], _Job]] = []
        self._order = itertools.count()
        self._pending: dict[int, _Job] = {}
        self._workers: set[asyncio.Task[None]] = set()

    @classmethod
    async def open(
        cls,
        target: str | os.PathLike[str] | ByteSource,
        *,
        cache_bytes: int = 256 * MiB,
        concurrency: int = 4,
        coalesce_gap: int | None = 64 * 1024,
        http: HttpOptions | None = None,
        timeout: float | None = None,
    ) -> StreamClient:
        """Open a container by URL, ``file://`` URL, path or byte source.

        A URL ending with ``/`` or ``/manifest.json``, or a local folder, is read as the
        unpacked layout; anything else as one ``.tsogs`` file (see :func:`make_fetcher`).
        ``timeout``: seconds one read over HTTP may take, its retries included (the opening
        request, a chunk or a run of chunks; default ``http.deadline_s``, 60 s).
        """
        source = (
            make_fetcher(target, with_deadline(http, timeout))
            if isinstance(target, str | os.PathLike)
            else RangeFetcher(target)
        )
        try:
            index = await source.open()
        except BaseException:
            await source.aclose()
            raise
        return cls(
            source,
            index,
            cache_bytes=cache_bytes,
            concurrency=concurrency,
            coalesce_gap=coalesce_gap,
        )

    async def frame_at(self, t: float, layers: int | None = None) -> Gaussians:
        """The Gaussians visible at ``t`` with the first ``layers`` quality layers (None: all),
        fetching only the chunks that needs."""
        chunks = self.index.chunks_for(t, layers)
        self._look_up(chunks)
        return await self._frame(t, chunks)

    def _look_up(self, chunks: Sequence[ChunkEntry]) -> None:
        """Count the chunks a frame needs as cache hits or misses."""
        for c in chunks:
            if c.id in self.cache:
                self.cache_stats.hits += 1
            else:
                self.cache_stats.misses += 1

    async def _frame(self, t: float, chunks: Sequence[ChunkEntry]) -> Gaussians:
        """The Gaussians of ``chunks`` visible at ``t``."""
        scenes = await self.chunk_scenes(chunks)
        bands = self.index.manifest.scene.sh_bands
        return Gaussians.concat([s.at(t) for s in scenes], sh_bands=bands)

    async def prefetch(
        self, t: float, horizon: float, *, wait: bool = True, layers: int | None = None
    ) -> int:
        """Fetch the chunks of [t, t + horizon] (of the first ``layers`` quality layers; None:
        all) in the order they are due; returns how many were scheduled.

        With ``wait=False`` the fetches run in the background (a failure there is not raised:
        the chunk is fetched again, and the error raised, when a frame needs it).
        """
        chunks = due_order(self.index.chunks_for_interval(t, t + max(horizon, 0.0), layers), t)
        futures = self._schedule(chunks, rank=_due_rank(t))
        if wait:
            await asyncio.gather(*futures.values())
        return len(futures)

    def _prefetch_due(self, t: float, horizon: float, layers: int) -> bool:
        """Queue the chunks of [t, t + horizon] of the first ``layers`` layers, base layers
        first, each request holding chunks due at the same second only (a chunk due now never
        waits for one due later read with it); True when all are already here."""
        chunks = self.index.chunks_for_interval(t, t + max(horizon, 0.0), layers)
        missing = due_order([c for c in chunks if c.id not in self.cache], t)
        self._schedule(missing, rank=_due_rank(t), apart=_due_rank(t))
        return not missing

    def _prefetch_layers(self, t: float, horizon: float, level: int) -> None:
        """Queue [t, t + horizon]: the base first, the ``level`` layers kept once it is in,
        and, once those are in too, one layer more: a link with room to spare fetches the
        next layer before the plan counts on it (the plan then takes it on, as it is here)."""
        for layers in (1, level, min(level + 1, self.index.layer_count)):
            if not self._prefetch_due(t, horizon, layers):
                return

    async def chunk_scenes(self, chunks: Sequence[ChunkEntry]) -> list[Scene]:
        """The decoded chunks of Gaussians among ``chunks``, each with its SH bands where its
        SH-band chunk is among them too, from the cache or fetched ahead of any queued
        prefetch (in-flight fetches are shared)."""
        found = {c.id: s for c in chunks if (s := self.cache.get(c.id)) is not None}
        futures = self._schedule([c for c in chunks if c.id not in found], urgent=True)
        for cid, fut in futures.items():
            found[cid] = await fut
        bands = {c.sh_of: found[c.id] for c in chunks if c.sh_of is not None}
        return [
            self._with_bands(c, found[c.id], bands.get(c.id)) for c in chunks if c.holds_gaussians
        ]

    def _with_bands(self, chunk: ChunkEntry, scene: Decoded, bands: Decoded | None) -> Scene:
        """A decoded chunk of Gaussians with its decoded SH bands, if given."""
        where = f"{self.source.name} chunk {chunk.id}"
        if not isinstance(scene, Scene) or not (bands is None or isinstance(bands, ShBands)):
            raise InputError("the index pairs a chunk of Gaussians with another", where=where)
        return scene if bands is None else bands.attach(scene, where=where)

    def _schedule(
        self,
        chunks: Sequence[ChunkEntry],
        *,
        urgent: bool = False,
        rank: Callable[[ChunkEntry], Rank] | None = None,
        apart: Callable[[ChunkEntry], object] | None = None,
    ) -> dict[int, asyncio.Future[Decoded]]:
        """Futures of the given chunks, queueing coalesced fetches for those not under way.

        Fetches wait in one queue served by at most ``concurrency`` workers, so a prefetch of
        any length costs one future per chunk, not one task. ``urgent`` ones (a frame being
        shown) go to the front, queued ones included: a job queued twice is fetched once.
        Others are fetched by ``rank`` (scene second they are due), then in order queued;
        chunks with a different ``apart`` key are never read with one request.
        """
        waiting = {c.id: self._pending[c.id] for c in chunks if c.id in self._pending}
        out = {cid: job.futures[cid] for cid, job in waiting.items()}
        todo = [c for c in chunks if c.id not in out and c.id not in self.cache]
        loop = asyncio.get_running_loop()
        jobs = list({id(job): job for job in waiting.values() if not job.started}.values())
        if not urgent:
            jobs = []  # already queued: they keep their place
        for group in self._groups(todo, apart):
            first = URGENT if urgent else min(map(rank, group)) if rank else (0.0, 0.0)
            job = _Job(group, {c.id: loop.create_future() for c in group}, rank=first)
            self._pending.update(dict.fromkeys(job.futures, job))
            out.update(job.futures)
            jobs.append(job)
        batch = next(self._order)
        for i, job in enumerate(jobs):
            # urgent ones (queued ones moved up too): the newest batch first, in its own order
            if urgent:
                job.rank = URGENT
            order = (-batch, i) if urgent else (batch, i)
            heapq.heappush(self._queue, (job.rank, order, job))
        self._start_workers()
        for c in chunks:
            if c.id not in out and (s := self.cache.get(c.id)) is not None:
                done: asyncio.Future[Decoded] = loop.create_future()
                done.set_result(s)
                out[c.id] = done
        return out

    def _start_workers(self) -> None:
        """Start workers until ``concurrency`` run or each queued job has one (a worker that
        has returned counts as gone before its done-callback runs)."""
        running = sum(1 for task in self._workers if not task.done())
        for _ in range(min(self.concurrency - running, len(self._queue))):
            task = asyncio.get_running_loop().create_task(self._work())
            self._workers.add(task)
            task.add_done_callback(self._workers.discard)

    async def _work(self) -> None:
        """Fetch queued jobs, front first, until the queue is empty."""
        while self._queue:
            _, _, job = heapq.heappop(self._queue)
            if not job.started:
                job.started = True
                await self._fetch_group(job)

    def _groups(
        self, chunks: Sequence[ChunkEntry], apart: Callable[[ChunkEntry], object] | None = None
    ) -> list[list[ChunkEntry]]:
        """Chunks split into runs of one quality layer (and one ``apart`` key) whose byte
        ranges are at most ``coalesce_gap`` apart (a base chunk never waits for an
        enhancement read with it).

        Runs keep the order in which their first chunk was asked for (time order); a gap of
        None fetches every chunk on its own.
        """
        if self.coalesce_gap is None or not self.source.coalesces:
            return [[c] for c in chunks]
        kinds: dict[object, list[ChunkEntry]] = {}
        for c in chunks:
            kinds.setdefault((c.layer, apart(c) if apart else None), []).append(c)
        run_of: dict[int, tuple[object, ByteRange]] = {}
        for kind, members in kinds.items():
            spans = coalesce((self.index.chunk_range(c) for c in members), self.coalesce_gap)
            starts = [s.start for s in spans]
            for c in members:
                run_of[c.id] = (kind, spans[bisect.bisect_right(starts, c.offset) - 1])
        groups: dict[tuple[object, ByteRange], list[ChunkEntry]] = {}
        for c in chunks:
            groups.setdefault(run_of[c.id], []).append(c)
        return list(groups.values())

    async def _fetch_group(self, job: _Job) -> None:
        """Fetch one run with one request, verify and decode each chunk, settle its future."""
        futures = job.futures
        try:
            group = sorted(job.group, key=lambda c: c.offset)
            self.throughput.started()
            received = 0
            try:
                bodies = await self.source.fetch(group)
                received = sum(len(body) for body in bodies)
            finally:
                self.throughput.finished(received)
            for c, body in zip(group, bodies, strict=True):
                where = f"{self.source.name} chunk {c.id}"
                data = verify_chunk(c, body, where=where)
                decode = decode_chunk_bytes if c.holds_gaussians else decode_sh_bands_bytes
                scene: Decoded = await asyncio.to_thread(decode, data, where=where)
                self.cache.put(c.id, scene)
                futures[c.id].set_result(scene)
        except BaseException as exc:
            _settle_failed(futures, exc)
            if not isinstance(exc, Exception):
                raise
        finally:
            for cid in futures:
                self._pending.pop(cid, None)

    async def chunk_bytes(self, chunk_id: int) -> bytes:
        """The verified bytes of one chunk (a standalone ``.sog``); not cached."""
        chunk = self.index.chunk(chunk_id)
        [body] = await self.source.fetch([chunk])
        return verify_chunk(chunk, body, where=f"{self.source.name} chunk {chunk.id}")

    async def chunk_scene(self, chunk_id: int) -> Scene:
        """One chunk of Gaussians, decoded (through the cache), with its SH bands where they
        are a chunk of their own; an SH-band chunk's id is refused (it holds no Gaussians)."""
        chunk = self.index.chunk(chunk_id)
        if chunk.sh_of is not None:
            raise InputError(
                f"chunk {chunk_id} holds the SH bands of chunk {chunk.sh_of}, not Gaussians "
                "(read that chunk: its bands come with it)"
            )
        bands = self.index.bands_of.get(chunk_id)
        [scene] = await self.chunk_scenes([chunk] if bands is None else [chunk, bands])
        return scene

    async def seek_cost(self, t: float) -> SeekCost:
        """What showing ``t`` costs against what is visible (see :mod:`.costs`)."""
        chunks = self.index.chunks_for(t)
        return seek_cost(self.index, t, chunks, await self.chunk_scenes(chunks))

    async def verify(self) -> VerifyReport:
        """Check every chunk (hash, decode, pixel budget, agreement with the index) and, for a
        ``.tsogs`` file, that its unused bytes are zero."""
        return await verify_stream(self.source, self.index)

    async def unpack(self, folder: str | os.PathLike[str], *, overwrite: bool = False) -> int:
        """Write the unpacked layout into ``folder``; returns the number of chunks."""
        return await unpack(self.index, self.chunk_bytes, folder, overwrite=overwrite)

    async def pack(self, path: str | os.PathLike[str]) -> int:
        """Write the container as one ``.tsogs`` file at ``path``; returns its size."""
        return await pack(self.index, self.chunk_bytes, path)

    def play(
        self,
        start: float = 0.0,
        *,
        speed: float = 1.0,
        fps: float = 30.0,
        duration: float | None = None,
        horizon_s: float = 1.0,
        realtime: bool = False,
        adaptive: bool = False,
    ) -> Playback:
        """Simulated playback from ``start`` at ``speed``, ``fps`` frames per wall second.

        Each frame keeps ``horizon_s`` of scene time (clipped to the end) prefetched. Without
        ``realtime`` nothing sleeps: a stall is a frame whose data took longer than its budget
        (1 / fps) to arrive; the first frame's wait is the startup latency. ``adaptive`` (in
        real time) draws the base layer first and fetches as many quality layers as the
        measured throughput keeps up with (:mod:`.adaptive`); a stall is then a frame whose
        base layer was late.
        """
        _check_playback(start, speed, fps, duration, horizon_s)
        scene = self.index.manifest.scene
        if not scene.start_s <= start <= scene.end_s:
            raise InputError(
                f"{start:g} s is outside the scene, which runs from {scene.start_s:g} to "
                f"{scene.end_s:g} s",
                where="--start",
            )
        end = start + duration * speed if duration is not None else scene.end_s
        frames = max((end - start) * fps / speed + 1e-9, 0.0) + 1
        if frames > MAX_PLAY_FRAMES:
            raise InputError(
                f"{frames:.3g} frames to play (at most {MAX_PLAY_FRAMES}): raise --speed, or "
                "lower --fps or --duration"
            )
        plan = _PlayPlan(
            start, end, int(frames), speed / fps, 1.0 / fps, horizon_s, realtime or adaptive, speed
        )
        stats = PlayStats()
        frames_of = self._play_adaptive if adaptive else self._play
        return Playback(frames_of(plan, stats), stats)

    async def _play(self, plan: _PlayPlan, stats: PlayStats) -> AsyncIterator[PlayedFrame]:
        """The frames of :meth:`play`, updating ``stats`` as they are produced."""
        before = self._counters()
        began = time.monotonic()
        budget = plan.budget
        for k in range(plan.count):
            t = plan.start + k * plan.step
            await self.prefetch(t, min(plan.horizon, max(plan.end - t, 0.0)), wait=False)
            chunks = self.index.chunks_for(t)
            self._look_up(chunks)
            asked = time.monotonic()
            await self.chunk_scenes(chunks)  # the wait is for data, not for evaluating it
            wait = time.monotonic() - asked
            frame = await self._frame(t, chunks)
            if k == 0:
                stats.startup_s = stats.first_picture_s = wait
            elif wait > budget:
                stats.stalls += 1
                stats.stall_s += wait - budget
            layers = self.index.layer_count
            stats.layers_shown[layers] = stats.layers_shown.get(layers, 0) + 1
            self._count(stats, k, began, before)
            yield PlayedFrame(k, t, frame, wait, layers)
            if plan.realtime:
                await asyncio.sleep(
                    max(0.0, began + stats.startup_s + (k + 1) * budget - time.monotonic())
                )

    def _counters(self) -> tuple[int, int, int, int]:
        """Requests, bytes, cache hits and misses so far (a playback counts from these)."""
        stats = self.source.stats
        return stats.requests, stats.bytes, self.cache_stats.hits, self.cache_stats.misses

    def _count(
        self, stats: PlayStats, k: int, began: float, before: tuple[int, int, int, int]
    ) -> None:
        """Frames, transfer and cache figures of a playback after its frame ``k``."""
        requests, nbytes, hits, misses = before
        stats.frames = k + 1
        stats.requests = self.source.stats.requests - requests
        stats.bytes = self.source.stats.bytes - nbytes
        looked = self.cache_stats.hits - hits + self.cache_stats.misses - misses
        stats.hit_rate = (self.cache_stats.hits - hits) / looked if looked else 0.0
        stats.elapsed_s = time.monotonic() - began

    async def _play_adaptive(self, plan: _PlayPlan, stats: PlayStats) -> AsyncIterator[PlayedFrame]:
        """The frames of an adaptive :meth:`play`: the base layer at the start as soon as it
        arrives (the first picture), then as many layers as the link keeps up with."""
        before = self._counters()
        began = time.monotonic()
        horizon = max(plan.horizon, HORIZON_S * plan.speed)
        await self.chunk_scenes(self.index.chunks_for(plan.start, 1))  # nothing shares the link
        stats.first_picture_s = time.monotonic() - began
        allowance = startup_allowance(stats.first_picture_s)
        level = self._plan_level(plan, plan.start, allowance, current=0)
        wanted = self._schedule(self.index.chunks_for(plan.start, level), urgent=True)
        self._prefetch_layers(plan.start, horizon, level)
        if wanted:
            await asyncio.wait(list(wanted.values()), timeout=allowance)
        playing = time.monotonic()
        stats.startup_s = playing - began
        replanned = playing
        for k in range(plan.count):
            t = plan.start + k * plan.step
            if time.monotonic() - replanned >= REPLAN_S:
                level = self._plan_level(plan, t, 0.0, current=level)
                replanned = time.monotonic()
            self._prefetch_layers(t, min(horizon, max(plan.end - t, 0.0)), level)
            base = self.index.chunks_for(t, 1)
            self._look_up(base)
            asked = time.monotonic()
            await self.chunk_scenes(base)
            wait = time.monotonic() - asked
            if k > 0 and wait > plan.budget:
                stats.stalls += 1
                stats.stall_s += wait - plan.budget
            shown = max(layers_shown(self.index, t, self.cache.__contains__), 1)
            frame = await self._frame(t, self.index.chunks_for(t, shown))
            stats.layers_shown[shown] = stats.layers_shown.get(shown, 0) + 1
            self._count(stats, k, began, before)
            yield PlayedFrame(k, t, frame, wait, shown)
            await asyncio.sleep(max(0.0, playing + (k + 1) * plan.budget - time.monotonic()))

    def _plan_level(self, plan: _PlayPlan, t: float, allowance: float, *, current: int) -> int:
        """Layers to keep fetching from ``t`` (:func:`.adaptive.choose_layers`); queued
        fetches of layers given up are dropped."""
        level = choose_layers(
            self.index,
            t,
            plan.end,
            speed=plan.speed,
            rate=self.throughput.estimate,
            have=self.cache.__contains__,
            current=current,
            allowance=allowance,
        )
        if 0 < level < current:
            self._drop_queued(level)
        return level

    def _drop_queued(self, layers: int) -> None:
        """Forget queued (not started) fetches holding only chunks of layer ``layers`` or up."""
        for _, _, job in self._queue:
            if not job.started and all(c.layer >= layers for c in job.group):
                job.started = True
                _settle_failed(job.futures, asyncio.CancelledError())
                for cid in job.futures:
                    self._pending.pop(cid, None)

    async def aclose(self) -> None:
        """Cancel queued and running fetches and close the source's connections."""
        while self._queue:
            _, _, job = heapq.heappop(self._queue)
            _settle_failed(job.futures, asyncio.CancelledError())
            for cid in job.futures:
                self._pending.pop(cid, None)
        workers = list(self._workers)
        for task in workers:
            task.cancel()
        await asyncio.gather(*workers, return_exceptions=True)
        await self.source.aclose()

    async def __aenter__(self) -> StreamClient:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()
