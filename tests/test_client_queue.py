"""The client's fetch queue: any prefetch costs at most ``concurrency`` tasks, a frame being
shown goes first, closing cancels everything queued (issue 15, item 9: a 160k-chunk index made
one task per chunk and cancelled them one by one, quadratically)."""

from __future__ import annotations

import asyncio
import tracemalloc
from collections.abc import Sequence

import pytest

from tsog_stream.client import StreamClient
from tsog_stream.client.fetchers import ChunkFetcher
from tsog_stream.container import index as index_module
from tsog_stream.container.sources import ReadStats
from tsog_stream.container.stream_index import StreamIndex, unpacked_index
from tsog_stream.errors import InputError, IntegrityError
from tsog_stream.schemas.manifest import ChunkEntry, Manifest, dump_manifest

BOX = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
STEP = 0.01


def many_chunk_index(count: int, *, size: int = 1000, gap: int = 0) -> StreamIndex:
    """An index of ``count`` one-window chunks of ``size`` bytes, ``gap`` bytes apart."""
    chunks = [
        {
            "id": i,
            "file": f"chunks/{i:06d}.sog",
            "offset": 16384 + i * (size + gap),
            "length": size,
            "sha256": "0" * 64,
            "count": 1,
            "level": 0,
            "node": i,
            "start_s": i * STEP,
            "end_s": (i + 1) * STEP,
            "bbox": BOX,
        }
        for i in range(count)
    ]
    nodes = [
        {"level": 0, "index": i, "start_s": i * STEP, "end_s": (i + 1) * STEP, "chunks": [i]}
        for i in range(count)
    ]
    scene = {
        "gaussians": count,
        "stored": count,
        "start_s": 0.0,
        "end_s": count * STEP,
        "fps": None,
        "timeline_type": 2,
        "temporal": {},
        "sh_bands": 0,
        "bbox": BOX,
    }
    manifest = Manifest.model_validate(
        {
            "generator": "test",
            "policy": "hybrid",
            "window_s": STEP,
            "max_pixels": 4096,
            "scene": scene,
            "nodes": nodes,
            "chunks": chunks,
            "payload_bytes": count * size,
        }
    )
    return unpacked_index(dump_manifest(manifest), where="synthetic")


class HeldFetcher(ChunkFetcher):
    """Records the chunks of each request; answers (with bytes that fail their hash) only
    when released, so requests pile up."""

    name = "held"
    coalesces = True

    def __init__(self, index: StreamIndex) -> None:
        self.index = index
        self.stats = ReadStats()
        self.asked: list[list[int]] = []
        self.in_flight = 0
        self.most_in_flight = 0
        self.release = asyncio.Event()

    async def open(self, after: int | None = None) -> StreamIndex:
        return self.index

    async def fetch(self, group: Sequence[ChunkEntry]) -> list[bytes]:
        self.asked.append([c.id for c in group])
        self.in_flight += 1
        self.most_in_flight = max(self.most_in_flight, self.in_flight)
        try:
            await self.release.wait()
        finally:
            self.in_flight -= 1
        return [b"not the chunk" for _ in group]

    async def aclose(self) -> None:
        pass


async def settle() -> None:
    """Let every runnable task take its steps."""
    for _ in range(5):
        await asyncio.sleep(0)


def test_a_long_prefetch_costs_at_most_concurrency_tasks_and_closes_at_once() -> None:
    index = many_chunk_index(5000)

    async def run() -> None:
        fetcher = HeldFetcher(index)
        client = StreamClient(fetcher, index, concurrency=3, coalesce_gap=None)
        tasks_before = len(asyncio.all_tasks())
        scheduled = await client.prefetch(0.0, 5000 * STEP, wait=False)
        waiter = asyncio.create_task(client.prefetch(0.0, 5000 * STEP))
        await settle()
        assert scheduled == 5000
        assert len(asyncio.all_tasks()) - tasks_before == 3 + 1  # workers + the waiter
        assert fetcher.in_flight == 3
        await client.aclose()
        with pytest.raises(asyncio.CancelledError):
            await waiter
        assert len(asyncio.all_tasks()) == tasks_before
        assert len(fetcher.asked) == 3 and fetcher.most_in_flight == 3

    asyncio.run(run())


def test_a_frame_being_shown_is_fetched_before_queued_prefetches() -> None:
    index = many_chunk_index(100)

    async def run() -> None:
        fetcher = HeldFetcher(index)
        client = StreamClient(fetcher, index, concurrency=1, coalesce_gap=None)
        await client.prefetch(0.0, 100 * STEP, wait=False)
        await settle()
        shown = asyncio.create_task(client.frame_at(77.5 * STEP))
        await settle()
        fetcher.release.set()
        with pytest.raises(IntegrityError, match="chunk 77 "):
            await shown
        assert fetcher.asked[:3] == [[0], [77], [1]]
        await client.aclose()

    asyncio.run(run())


@pytest.mark.parametrize("gap", [0, 40_000, 70_000])
def test_coalescing_joins_exactly_the_chunks_within_the_gap(gap: int) -> None:
    index = many_chunk_index(300, size=10_000, gap=gap)

    async def run() -> list[list[int]]:
        fetcher = HeldFetcher(index)
        client = StreamClient(fetcher, index, concurrency=300, coalesce_gap=64 * 1024)
        await client.prefetch(0.0, 300 * STEP, wait=False)
        await settle()
        await client.aclose()
        return fetcher.asked

    asked = asyncio.run(run())
    expected = [list(range(300))] if gap <= 64 * 1024 else [[i] for i in range(300)]
    assert asked == expected


def test_an_opened_index_keeps_little_per_chunk() -> None:
    """Index records are slotted (a model per chunk kept 3.4 KiB, so a 160k-chunk index held
    543 MiB); the bound leaves room for Python versions, not for a dict per record."""
    manifest_json = dump_manifest(many_chunk_index(20_000).manifest)
    tracemalloc.start()
    try:
        index = unpacked_index(manifest_json, where="synthetic")
        kept = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(index.manifest.chunks) == 20_000
    assert kept / 20_000 < 1536, kept / 20_000


def test_the_writer_refuses_an_index_no_reader_would_open(monkeypatch: pytest.MonkeyPatch) -> None:
    """One cap for writing and reading: an index over it is refused before anything is
    written, naming the chunk count, rather than producing a container nobody can open."""
    manifest = many_chunk_index(100).manifest
    size = len(dump_manifest(manifest))
    monkeypatch.setattr(index_module, "MAX_INDEX_BYTES", size - 1)
    with pytest.raises(InputError, match="index of 100 chunks takes"):
        index_module.encode_index(manifest)
    monkeypatch.setattr(index_module, "MAX_INDEX_BYTES", size)
    assert index_module.encode_index(manifest)[2] == size
