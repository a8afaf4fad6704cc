"""``StreamClient``: the one reader of a container, for any origin, at any time.

It opens the container with one request, fetches only the chunks a time needs (through a
:class:`.fetch_queue.FetchQueue`: prefetching ahead in time order, neighbouring chunks merged
into one request, every chunk's SHA-256 checked), keeps decoded chunks in a
:class:`.cache.SceneCache`, and plays simulated playbacks, adaptive or not. It also gives single
chunks, seek costs, a full verification, and both layouts (unpack, pack). Paths, ``file://``
and http(s) URLs of a ``.tsogs`` file or of an unpacked folder are read alike; ``Stream``
(:mod:`.sync`) is its synchronous facade. See docs/client.md.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import AsyncIterator, Sequence
from types import TracebackType

from ..codec.sh_bands import ShBands
from ..container.sources import ByteSource
from ..container.stream_index import StreamIndex, verify_chunk
from ..errors import InputError
from ..model import Gaussians, Scene
from ..schemas.manifest import ChunkEntry
from .adaptive import choose_layers, due_order, layers_shown, startup_allowance
from .cache import CacheStats, Decoded, SceneCache
from .costs import SeekCost, seek_cost
from .fetch_queue import FetchQueue, due_rank
from .fetchers import ChunkFetcher, RangeFetcher, make_fetcher
from .http_options import HttpOptions, with_deadline
from .playback import Playback, PlayedFrame, PlayPlan, PlayStats, plan_playback
from .unpacked import pack, unpack
from .verify import VerifyReport, verify_stream

MiB = 1 << 20
REPLAN_S = 0.5
"""Wall seconds between two choices of the layers an adaptive playback fetches."""


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
        self._fetches = FetchQueue(
            self.source, index, self.cache, concurrency=concurrency, coalesce_gap=coalesce_gap
        )
        self._pending = self._fetches.pending  # the same dict: chunks queued or under way

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

    @property
    def is_live(self) -> bool:
        """The stream is live: its index is republished as windows are encoded, until it ends
        (docs/client.md, "Live streams")."""
        live = self.index.manifest.live
        return live is not None and not live.ended

    @property
    def live_edge_s(self) -> float:
        """The end of the last frame published (of a recorded stream: its end)."""
        return self.index.manifest.scene.end_s

    async def refresh(self) -> bool:
        """Read a live stream's index again, waiting on an origin with the blocking reload
        for a publication after the one held; True when a newer one replaced it (chunks
        already fetched stay: they never change)."""
        live = self.index.manifest.live
        if live is None or live.ended:
            return False
        index = await self.source.open(after=live.sequence)
        fresh = index.manifest.live
        if fresh is None or fresh.sequence <= live.sequence:
            return False
        self.index = index
        self._fetches.index = index
        return True

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
        futures = self._fetches.schedule(chunks, rank=due_rank(t))
        if wait:
            await asyncio.gather(*futures.values())
        return len(futures)

    def _prefetch_due(self, t: float, horizon: float, layers: int) -> bool:
        """Queue the chunks of [t, t + horizon] of the first ``layers`` layers, base layers
        first, each request holding chunks due at the same second only (a chunk due now never
        waits for one due later read with it); True when all are already here."""
        chunks = self.index.chunks_for_interval(t, t + max(horizon, 0.0), layers)
        missing = due_order([c for c in chunks if c.id not in self.cache], t)
        self._fetches.schedule(missing, rank=due_rank(t), apart=due_rank(t))
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
        futures = self._fetches.schedule([c for c in chunks if c.id not in found], urgent=True)
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
        plan = plan_playback(
            self.index.manifest.scene,
            start,
            speed=speed,
            fps=fps,
            duration=duration,
            horizon_s=horizon_s,
            realtime=realtime,
            adaptive=adaptive,
        )
        stats = PlayStats()
        return Playback(self._play(plan, stats), stats)

    async def _play(self, plan: PlayPlan, stats: PlayStats) -> AsyncIterator[PlayedFrame]:
        """The frames of :meth:`play`, updating ``stats`` as they are produced."""
        before, began = self._counters(), time.monotonic()
        level = await self._start_adaptive(plan, stats, began) if plan.adaptive else 0
        replanned = time.monotonic()
        for k in range(plan.count):
            t = plan.start + k * plan.step
            ahead = min(plan.horizon, max(plan.end - t, 0.0))
            if plan.adaptive:
                if time.monotonic() - replanned >= REPLAN_S:
                    level = self._plan_level(plan, t, 0.0, current=level)
                    replanned = time.monotonic()
                self._prefetch_layers(t, ahead, level)
            else:
                await self.prefetch(t, ahead, wait=False)
            needed = self.index.chunks_for(t, 1 if plan.adaptive else None)
            self._look_up(needed)
            asked = time.monotonic()
            await self.chunk_scenes(needed)  # the wait is for data, not for evaluating it
            wait = time.monotonic() - asked
            if k == 0 and not plan.adaptive:
                stats.startup_s = stats.first_picture_s = wait
            elif k > 0 and wait > plan.budget:
                stats.stalls += 1
                stats.stall_s += wait - plan.budget
            shown = self.index.layer_count
            if plan.adaptive:
                shown = max(layers_shown(self.index, t, self.cache.__contains__), 1)
                needed = self.index.chunks_for(t, shown)
            frame = await self._frame(t, needed)
            stats.layers_shown[shown] = stats.layers_shown.get(shown, 0) + 1
            self._count(stats, k, began, before)
            yield PlayedFrame(k, t, frame, wait, shown)
            if plan.realtime:
                due = began + stats.startup_s + (k + 1) * plan.budget
                await asyncio.sleep(max(0.0, due - time.monotonic()))

    async def _start_adaptive(self, plan: PlayPlan, stats: PlayStats, began: float) -> int:
        """The base layer at the start as soon as it arrives (the first picture), then a short
        wait for the layers the link keeps up with; returns how many to keep fetching."""
        await self.chunk_scenes(self.index.chunks_for(plan.start, 1))  # nothing shares the link
        stats.first_picture_s = time.monotonic() - began
        allowance = startup_allowance(stats.first_picture_s)
        level = self._plan_level(plan, plan.start, allowance, current=0)
        wanted = self._fetches.schedule(self.index.chunks_for(plan.start, level), urgent=True)
        self._prefetch_layers(plan.start, plan.horizon, level)
        if wanted:
            await asyncio.wait(list(wanted.values()), timeout=allowance)
        stats.startup_s = time.monotonic() - began
        return level

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

    def _plan_level(self, plan: PlayPlan, t: float, allowance: float, *, current: int) -> int:
        """Layers to keep fetching from ``t`` (:func:`.adaptive.choose_layers`); queued
        fetches of layers given up are dropped."""
        level = choose_layers(
            self.index,
            t,
            plan.end,
            speed=plan.speed,
            rate=self._fetches.throughput.estimate,
            have=self.cache.__contains__,
            current=current,
            allowance=allowance,
        )
        if 0 < level < current:
            self._fetches.drop(level)
        return level

    async def aclose(self) -> None:
        """Cancel queued and running fetches and close the source's connections."""
        await self._fetches.aclose()
        await self.source.aclose()

    async def __aenter__(self) -> StreamClient:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()
