"""``FetchQueue``: which chunks the client fetches next, how many at once, in how few requests.

Fetches wait in one queue served by at most ``concurrency`` workers, so a prefetch of any
length costs one future per chunk, not one task. Chunks close together in the file (and of one
quality layer) are read with one request, split back into chunks, each checked against its
SHA-256, decoded off the event loop and put in the cache.
"""

from __future__ import annotations

import asyncio
import bisect
import heapq
import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..codec.chunk import decode_chunk_bytes
from ..codec.sh_bands import decode_sh_bands_bytes
from ..container.ranges import ByteRange, coalesce
from ..container.stream_index import StreamIndex, verify_chunk
from ..schemas.manifest import ChunkEntry
from .adaptive import Throughput
from .cache import Decoded, SceneCache
from .fetchers import ChunkFetcher

Rank = tuple[float, float]
URGENT: Rank = (-math.inf, 0.0)


@dataclass
class _Job:
    """One queued fetch: a run of chunks read with one request, and their futures."""

    group: list[ChunkEntry]
    futures: dict[int, asyncio.Future[Decoded]]
    started: bool = False
    rank: Rank = (0.0, 0.0)
    """Fetched in rank order (then in order queued): (layer, second due) for a prefetch, so
    every queued base chunk goes before any enhancement; a frame being shown ranks first."""


def due_rank(t: float) -> Callable[[ChunkEntry], Rank]:
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


class FetchQueue:
    """Chunk fetches of one source, ranked, coalesced and run by a bounded pool of workers."""

    def __init__(
        self,
        source: ChunkFetcher,
        index: StreamIndex,
        cache: SceneCache,
        *,
        concurrency: int,
        coalesce_gap: int | None,
    ) -> None:
        self.source = source
        self.index = index
        self.cache = cache
        self.concurrency = concurrency
        self.coalesce_gap = coalesce_gap
        self.throughput = Throughput(time.monotonic)
        self.pending: dict[int, _Job] = {}
        """Jobs queued or under way, by chunk id."""
        self._heap: list[tuple[Rank, tuple[int, int], _Job]] = []
        self._order = itertools.count()
        self._workers: set[asyncio.Task[None]] = set()

    def schedule(
        self,
        chunks: Sequence[ChunkEntry],
        *,
        urgent: bool = False,
        rank: Callable[[ChunkEntry], Rank] | None = None,
        apart: Callable[[ChunkEntry], object] | None = None,
    ) -> dict[int, asyncio.Future[Decoded]]:
        """Futures of the given chunks, queueing coalesced fetches for those not under way.

        ``urgent`` ones (a frame being shown) go to the front, queued ones included: a job
        queued twice is fetched once. Others are fetched by ``rank``, then in order queued;
        chunks with a different ``apart`` key are never read with one request.
        """
        waiting = {c.id: self.pending[c.id] for c in chunks if c.id in self.pending}
        out = {cid: job.futures[cid] for cid, job in waiting.items()}
        todo = [c for c in chunks if c.id not in out and c.id not in self.cache]
        loop = asyncio.get_running_loop()
        # queued jobs keep their place unless urgent (then the newest batch goes first)
        jobs = [job for job in {id(j): j for j in waiting.values()}.values() if not job.started]
        jobs = jobs if urgent else []
        for group in self._groups(todo, apart):
            first = URGENT if urgent else min(map(rank, group)) if rank else (0.0, 0.0)
            job = _Job(group, {c.id: loop.create_future() for c in group}, rank=first)
            self.pending.update(dict.fromkeys(job.futures, job))
            out.update(job.futures)
            jobs.append(job)
        batch = next(self._order)
        for i, job in enumerate(jobs):
            job.rank = URGENT if urgent else job.rank
            heapq.heappush(self._heap, (job.rank, (-batch, i) if urgent else (batch, i), job))
        self._start_workers()
        for c in chunks:
            if c.id not in out and (s := self.cache.get(c.id)) is not None:
                done: asyncio.Future[Decoded] = loop.create_future()
                done.set_result(s)
                out[c.id] = done
        return out

    def drop(self, layers: int) -> None:
        """Forget queued (not started) fetches holding only chunks of layer ``layers`` or up."""
        for _, _, job in self._heap:
            if not job.started and all(c.layer >= layers for c in job.group):
                job.started = True
                self._forget(job)

    async def aclose(self) -> None:
        """Cancel queued and running fetches."""
        while self._heap:
            self._forget(heapq.heappop(self._heap)[2])
        workers = list(self._workers)
        for task in workers:
            task.cancel()
        await asyncio.gather(*workers, return_exceptions=True)

    def _forget(self, job: _Job) -> None:
        _settle_failed(job.futures, asyncio.CancelledError())
        for cid in job.futures:
            self.pending.pop(cid, None)

    def _start_workers(self) -> None:
        """Start workers until ``concurrency`` run or each queued job has one (a worker that
        has returned counts as gone before its done-callback runs)."""
        running = sum(1 for task in self._workers if not task.done())
        for _ in range(min(self.concurrency - running, len(self._heap))):
            task = asyncio.get_running_loop().create_task(self._work())
            self._workers.add(task)
            task.add_done_callback(self._workers.discard)

    async def _work(self) -> None:
        """Fetch queued jobs, front first, until the queue is empty."""
        while self._heap:
            _, _, job = heapq.heappop(self._heap)
            if not job.started:
                job.started = True
                await self._fetch(job)

    def _groups(
        self, chunks: Sequence[ChunkEntry], apart: Callable[[ChunkEntry], object] | None
    ) -> list[list[ChunkEntry]]:
        """Chunks split into runs of one quality layer (and one ``apart`` key) whose byte
        ranges are at most ``coalesce_gap`` apart (a base chunk never waits for an
        enhancement read with it), in the order their first chunk was asked for; a gap of
        None fetches every chunk on its own."""
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

    async def _fetch(self, job: _Job) -> None:
        """Fetch one run with one request, verify and decode each chunk, settle its future."""
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
                job.futures[c.id].set_result(scene)
        except BaseException as exc:
            _settle_failed(job.futures, exc)
            if not isinstance(exc, Exception):
                raise
        finally:
            for cid in job.futures:
                self.pending.pop(cid, None)
