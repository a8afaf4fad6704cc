"""The streaming client against a real, fault-injecting aiohttp origin on 127.0.0.1."""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from aiohttp import web

from peers import Behaviour, Peer, drip, http_error, silent, unavailable
from tsog_stream.cli.client_commands import add_client_commands, cmd_fetch, cmd_play
from tsog_stream.cli.main import main
from tsog_stream.cli.progress import Progress
from tsog_stream.client import (
    HttpOptions,
    HttpSource,
    SceneCache,
    StreamClient,
    open_stream,
)
from tsog_stream.client.cache import scene_nbytes
from tsog_stream.container.header import PREFIX_SIZE
from tsog_stream.container.ranges import ByteRange, coalesce
from tsog_stream.errors import InputError, IntegrityError, SourceError
from tsog_stream.model import Gaussians, TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import small_scene

TIMES = (0.0, 0.3, 0.7, 1.2, 1.9, 5.0)
FAST = HttpOptions(retries=3, backoff_s=0.01, read_timeout_s=5.0)


class Origin:
    """Serves one file with single-range 206 answers, ETag and If-Match; faults switchable."""

    def __init__(self) -> None:
        self.data = b""
        self.etag = ""
        self.faults: set[str] = set()
        self.corrupt_at = 0
        self.log: list[tuple[str | None, str | None]] = []
        self.sent = 0
        self.port = 0

    def reset(self, data: bytes) -> None:
        """Serve ``data`` with no faults and a fresh log."""
        self.data = data
        self.etag = f'"{hashlib.sha256(data).hexdigest()[:16]}"'
        self.faults = set()
        self.log = []
        self.sent = 0

    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/scene.tsogs"

    async def handle(self, request: web.Request) -> web.StreamResponse:
        rng, if_match = request.headers.get("Range"), request.headers.get("If-Match")
        self.log.append((rng, if_match))
        if "slow" in self.faults:
            await asyncio.sleep(0.3)
        if "error_once" in self.faults:
            self.faults.discard("error_once")
            return web.Response(status=503)
        if if_match is not None and if_match != self.etag:
            return web.Response(status=412)
        data = self.data
        m = re.fullmatch(r"bytes=(\d+)-(\d+)", rng or "")
        if m is None or "ignore_range" in self.faults:
            self.sent += len(data)
            return web.Response(body=data, headers={"ETag": self.etag})
        a, b = int(m.group(1)), min(int(m.group(2)), len(data) - 1)
        if a >= len(data):
            return web.Response(status=416, headers={"Content-Range": f"bytes */{len(data)}"})
        return await self._partial(request, a, b)

    async def _partial(self, request: web.Request, a: int, b: int) -> web.StreamResponse:
        body = bytearray(self.data[a : b + 1])
        if "corrupt" in self.faults and a <= self.corrupt_at <= b:
            body[self.corrupt_at - a] ^= 0x55
        shift = 1 if "bad_range" in self.faults else 0
        resp = web.StreamResponse(status=206)
        resp.headers["Content-Range"] = f"bytes {a + shift}-{b + shift}/{len(self.data)}"
        resp.headers["ETag"] = self.etag
        resp.content_length = len(body)
        await resp.prepare(request)
        # a byte every 0.2 s: never silent long enough to time out (trickle_chunks: past the
        # opening request's bytes only)
        if "trickle" in self.faults or ("trickle_chunks" in self.faults and a >= PREFIX_SIZE):
            for byte in bytes(body):
                self.sent += 1  # counted before the client can have it: tests read it after
                await resp.write(bytes([byte]))
                await asyncio.sleep(0.2)
            return resp
        if "drop_once" in self.faults and len(body) > 1:
            self.faults.discard("drop_once")
            self.sent += len(body) // 2
            await resp.write(bytes(body[: len(body) // 2]))
            assert request.transport is not None
            request.transport.close()
            return resp
        # counted before it is written: the client may have every byte (and the test read
        # ``sent``) before this coroutine runs again after the write
        self.sent += len(body)
        await resp.write(bytes(body))
        await resp.write_eof()
        return resp


@pytest.fixture(scope="module")
def container(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("client") / "scene.tsogs"
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0, dynamic=("means",))
    segment_scene(scene, path, SegmentOptions(window_s=0.5, policy="duplicate"))
    return path


@pytest.fixture(scope="module")
def server() -> Iterator[Origin]:
    origin = Origin()
    loop = asyncio.new_event_loop()
    started = threading.Event()

    def run() -> None:
        asyncio.set_event_loop(loop)
        app = web.Application()
        app.router.add_get("/scene.tsogs", origin.handle)
        runner = web.AppRunner(app)
        loop.run_until_complete(runner.setup())
        loop.run_until_complete(web.TCPSite(runner, "127.0.0.1", 0).start())
        origin.port = runner.addresses[0][1]
        started.set()
        loop.run_forever()
        loop.run_until_complete(runner.cleanup())
        loop.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    assert started.wait(10)
    yield origin
    loop.call_soon_threadsafe(loop.stop)
    thread.join(10)


@pytest.fixture
def origin(server: Origin, container: Path) -> Origin:
    server.reset(container.read_bytes())
    return server


def same(a: Gaussians, b: Gaussians) -> bool:
    names = ("means", "scales", "quats", "opacities", "sh0", "shN")
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names)


def local_frames(path: Path, times: tuple[float, ...]) -> list[Gaussians]:
    with open_stream(path) as reader:
        return [reader.frame_at(t) for t in times]


def wire_bytes(client: StreamClient, times: list[float], gap: int) -> int:
    """Bytes of the coalesced runs of the chunks the given times need, less what the opening
    request already brought (a compact container's first chunks start inside it)."""
    chunks = {c.id: c for t in times for c in client.index.chunks_for(t)}.values()
    runs = coalesce((client.index.chunk_range(c) for c in chunks), gap)
    return sum(max(r.end - max(r.start, PREFIX_SIZE), 0) for r in runs)


def test_frames_match_the_local_reader_and_open_is_one_request(
    origin: Origin, container: Path
) -> None:
    expected = local_frames(container, TIMES)

    async def run() -> int:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            assert client.source.stats.requests == 1
            assert client.source.stats.bytes == min(PREFIX_SIZE, len(origin.data))
            for t, want in zip(TIMES, expected, strict=True):
                requests = client.source.stats.requests
                assert same(await client.frame_at(t), want)
                runs = coalesce(client.index.chunk_range(c) for c in client.index.chunks_for(t))
                assert client.source.stats.requests - requests <= len(runs)
            return client.source.stats.bytes

    assert asyncio.run(run()) == origin.sent
    assert origin.log[0] == (f"bytes=0-{PREFIX_SIZE - 1}", None)
    assert all(if_match == origin.etag for _, if_match in origin.log[1:])


def test_bytes_on_the_wire_are_the_chunks_needed(origin: Origin) -> None:
    async def run() -> tuple[int, int, int]:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            await client.frame_at(0.7)
            stats = client.source.stats
            return stats.requests, stats.bytes, wire_bytes(client, [0.7], 64 * 1024)

    requests, nbytes, needed = asyncio.run(run())
    assert nbytes == PREFIX_SIZE + needed
    assert origin.sent == nbytes
    assert requests == len(origin.log)


def test_the_opening_request_serves_the_start_of_the_first_chunk(origin: Origin) -> None:
    """In a compact container the first chunk starts inside the first 16 KiB: only its bytes
    past them are asked for, and it decodes the same."""

    async def run() -> tuple[int, list[str]]:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            first = min(client.index.manifest.chunks, key=lambda c: c.offset)
            assert first.offset < PREFIX_SIZE < first.offset + first.length
            await client.chunk_bytes(first.id)  # checked against its SHA-256
            return first.offset + first.length, [str(r) for r, _ in origin.log]

    end, log = asyncio.run(run())
    assert log[0] == f"bytes=0-{PREFIX_SIZE - 1}"
    assert all(int(r.split("=")[1].split("-")[0]) >= PREFIX_SIZE for r in log[1:]), log
    assert origin.sent == end, "no byte asked for twice"


def test_coalescing_reduces_requests(origin: Origin, container: Path) -> None:
    async def count(gap: int | None) -> tuple[int, Gaussians]:
        async with await StreamClient.open(origin.url(), coalesce_gap=gap, http=FAST) as client:
            await client.prefetch(0.0, 2.0)
            requests = client.source.stats.requests
            return requests, await client.frame_at(1.2)

    merged, frame_merged = asyncio.run(count(64 * 1024))
    alone, frame_alone = asyncio.run(count(None))
    assert merged < alone
    want = local_frames(container, (1.2,))[0]
    assert same(frame_merged, want) and same(frame_alone, want)


def test_a_changed_file_is_detected_by_if_match(origin: Origin) -> None:
    async def run() -> None:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            origin.reset(origin.data + b"\0")
            with pytest.raises(SourceError, match="changed on the server"):
                await client.frame_at(0.7)

    asyncio.run(run())


def test_a_truncated_body_is_resumed(origin: Origin, container: Path) -> None:
    async def run() -> Gaussians:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            origin.faults.add("drop_once")
            return await client.frame_at(0.7)

    assert same(asyncio.run(run()), local_frames(container, (0.7,))[0])
    resumed = [r for r, _ in origin.log[1:]]
    assert len(resumed) == 2
    first, second = (re.fullmatch(r"bytes=(\d+)-(\d+)", r or "") for r in resumed)
    assert first and second and int(second.group(1)) > int(first.group(1))
    assert second.group(2) == first.group(2)


def test_server_errors_are_retried(origin: Origin, container: Path) -> None:
    origin.faults.add("error_once")
    with open_stream(origin.url(), http=FAST) as client:
        assert same(client.frame_at(1.2), local_frames(container, (1.2,))[0])
    assert origin.log[0] == origin.log[1]


@pytest.mark.parametrize(
    ("fault", "error", "message"),
    [
        ("bad_range", SourceError, "Content-Range"),
        ("corrupt", IntegrityError, "SHA-256"),
    ],
)
def test_bad_answers_raise_the_right_error(
    origin: Origin, fault: str, error: type[Exception], message: str
) -> None:
    async def run() -> None:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            chunk = client.index.chunks_for(0.7)[0]
            origin.corrupt_at = chunk.offset + chunk.length // 2
            origin.faults.add(fault)
            with pytest.raises(error, match=message):
                await client.frame_at(0.7)

    asyncio.run(run())


def test_an_origin_ignoring_ranges(origin: Origin, container: Path) -> None:
    origin.faults.add("ignore_range")
    with pytest.raises(SourceError, match="ignores Range"):
        open_stream(origin.url(), http=HttpOptions(max_unranged_bytes=1000))
    assert len(origin.data) <= 1 << 20
    with open_stream(origin.url(), http=FAST) as client:
        assert same(client.frame_at(0.3), local_frames(container, (0.3,))[0])
        assert client.client.source.stats.requests == 1


def test_slow_answers_time_out(origin: Origin) -> None:
    origin.faults.add("slow")
    options = HttpOptions(retries=1, backoff_s=0.01, read_timeout_s=0.05)
    with pytest.raises(SourceError, match="2 attempts"):
        open_stream(origin.url(), http=options)


@pytest.mark.parametrize(
    ("behaviour", "tries", "message"),
    [(unavailable, 3, "failed after 3 attempts: HTTP 503"), (http_error, 1, "expected HTTP 206")],
)
def test_a_5xx_is_retried_with_capped_doubling_waits_and_a_4xx_never(
    behaviour: Behaviour, tries: int, message: str
) -> None:
    """retries=2: a 503 is asked three times, after waits of 0.2 then 0.3 s (0.4 capped); a
    400 once. Either way one line naming the URL."""
    options = HttpOptions(retries=2, backoff_s=0.2, max_backoff_s=0.3)
    with Peer(behaviour) as peer:
        began = time.monotonic()
        with pytest.raises(SourceError, match=message) as caught:
            open_stream(f"http://127.0.0.1:{peer.port}/s.tsogs", http=options)
        took = time.monotonic() - began
        assert peer.accepted == tries
    assert (0.5 <= took < 0.5 + SLACK) if tries > 1 else took < 0.2
    assert "\n" not in str(caught.value) and "s.tsogs" in str(caught.value)


@pytest.mark.parametrize("size", [0, 10])
def test_tiny_files(origin: Origin, size: int) -> None:
    origin.reset(bytes(range(size)))

    async def run() -> None:
        source = HttpSource(origin.url(), FAST)
        try:
            assert await source.size() == size
            assert await source.read(ByteRange(0, size)) == bytes(range(size))
            assert source.stats.requests == 1
            with pytest.raises(SourceError):
                await source.read(ByteRange(0, size + 1))
        finally:
            await source.aclose()

    asyncio.run(run())


def test_the_cache_counts_hits_and_misses(origin: Origin) -> None:
    async def run() -> None:
        async with await StreamClient.open(origin.url(), http=FAST) as client:
            n = len(client.index.chunks_for(0.7))
            await client.frame_at(0.7)
            requests = client.source.stats.requests
            await client.frame_at(0.7)
            assert (client.cache_stats.misses, client.cache_stats.hits) == (n, n)
            assert client.source.stats.requests == requests
            assert client.cache.nbytes > 0

    asyncio.run(run())


def test_play_yields_the_local_frames_and_fetches_little_more(
    origin: Origin, container: Path
) -> None:
    with open_stream(origin.url(), http=FAST) as client:
        frames, stats = client.play(0.25, fps=10.0, duration=1.0)
        times = [f.t for f in frames]
        needed = wire_bytes(client.client, times, 0)
    assert len(frames) == stats.frames == 11
    for frame, want in zip(frames, local_frames(container, tuple(times)), strict=True):
        assert same(frame.gaussians, want)
    assert stats.bytes <= 1.25 * needed
    assert stats.requests >= 1 and stats.startup_s > 0 and 0 < stats.hit_rate < 1


def test_local_paths_and_file_urls(container: Path) -> None:
    want = local_frames(container, (1.2,))[0]
    for target in (str(container), container.as_uri()):
        with open_stream(target) as client:
            assert same(client.frame_at(1.2), want)


def test_the_sync_facade_works_inside_a_running_event_loop(origin: Origin, container: Path) -> None:
    """Made where a loop already runs (a Jupyter cell, async code), the facade runs its own
    loop on a thread of its own: the same frames from a file and over HTTP, and closing it
    leaves no thread behind."""
    want = local_frames(container, TIMES)

    async def in_a_loop() -> list[list[Gaussians]]:
        got = []
        for target in (str(container), origin.url()):
            with open_stream(target, http=FAST) as clip:
                got.append([clip.frame_at(t) for t in TIMES])
        return got

    before = {t.ident for t in threading.enumerate()}
    for frames in asyncio.run(in_a_loop()):
        assert all(same(a, b) for a, b in zip(frames, want, strict=True))
    left = [t.name for t in threading.enumerate() if t.ident not in before]
    assert not [name for name in left if name == "tsog-stream-loop"], left


def test_cli_fetch_and_play(
    origin: Origin, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    add_client_commands(parser.add_subparsers(dest="command"))
    lines: list[str] = []
    args = parser.parse_args(["fetch", origin.url(), "--t", "0.7", "-o", str(tmp_path / "f.ply")])
    assert cmd_fetch(args, Progress(quiet=True)) == 0
    assert (tmp_path / "f.ply").is_file()
    assert "requests" in capsys.readouterr().out
    args = parser.parse_args(["play", origin.url(), "--duration", "0.5", "--fps", "10", "-v"])
    assert cmd_play(args, lines.append) == 0
    out = capsys.readouterr().out
    assert "startup latency" in out and "cache hit rate" in out
    assert any("frame 6" in line for line in lines)


def test_the_cache_evicts_least_recently_used(container: Path) -> None:
    with open_stream(container) as reader:
        scenes = [reader.chunk_scene(i) for i in range(3)]
    cache = SceneCache(scene_nbytes(scenes[0]) + scene_nbytes(scenes[1]))
    cache.put(0, scenes[0])
    cache.put(1, scenes[1])
    assert cache.get(0) is scenes[0]
    cache.put(2, scenes[2])
    assert 0 in cache and 1 not in cache and cache.nbytes <= cache.max_bytes


def test_a_chunk_over_the_whole_cache_budget_is_returned_but_not_kept(container: Path) -> None:
    """The byte bound holds: a chunk larger than the whole budget evicts nothing and is not
    kept, yet every frame that needs it still comes (fetched again when needed again)."""
    with open_stream(container) as reader:
        chunks = reader.index.manifest.chunks
        scenes = sorted((reader.chunk_scene(c.id) for c in chunks), key=scene_nbytes)
    small, big = scenes[0], scenes[-1]
    assert scene_nbytes(small) < scene_nbytes(big)
    cache = SceneCache(scene_nbytes(small))
    cache.put(0, small)
    cache.put(1, big)
    assert 1 not in cache and cache.get(0) is small and cache.nbytes == scene_nbytes(small)
    want = local_frames(container, TIMES)
    with open_stream(container, cache_bytes=scene_nbytes(small) - 1) as reader:
        for _ in range(2):
            assert all(same(reader.frame_at(t), w) for t, w in zip(TIMES, want, strict=True))
        assert reader.client.cache.nbytes == 0
        assert reader.client.cache_stats.hits == 0


DEADLINE = 2.0
"""The deadline of one read in the tests of the deadline (60 s by default)."""
SLACK = 1.0
"""How late after the deadline a read may give up: a cancelled attempt's clean-up."""
DRIP_S = 0.25
"""A dripping server's pause between bytes: never silent long enough for a read timeout."""
HEAD_206 = (
    b"HTTP/1.1 206 Partial Content\r\nContent-Range: bytes 0-16383/100000\r\n"
    b"Content-Length: 16384\r\n\r\n"
)
HEAD_200 = b"HTTP/1.1 200 OK\r\nContent-Length: 100000\r\n\r\n"
SERVERS = {
    "drips the opening answer's head": (drip(HEAD_206, DRIP_S, drip_head=True), "/s.tsogs"),
    "drips the opening answer's body": (drip(HEAD_206, DRIP_S), "/s.tsogs"),
    "drips an unpacked manifest": (drip(HEAD_200, DRIP_S), "/scene/"),
    "answers 503 to every attempt": (unavailable, "/s.tsogs"),
    "accepts and says nothing": (silent, "/s.tsogs"),
}
"""Servers that never finish an answer, and where the client reads from them."""


@pytest.mark.parametrize("server", list(SERVERS))
def test_a_read_gives_up_at_its_deadline_whatever_the_server_does(server: str) -> None:
    """One deadline for a read, every attempt and wait included: at it the attempt running is
    cut off and no other begins (a drip of a byte every 2 s took 607 s to give up on)."""
    behaviour, path = SERVERS[server]
    options = HttpOptions(retries=1000, backoff_s=0.05, max_backoff_s=0.2)
    with Peer(behaviour, lifetime_s=DEADLINE + 10) as peer:
        began = time.monotonic()
        with pytest.raises(SourceError, match=rf"not received within {DEADLINE:g} s") as caught:
            open_stream(f"http://127.0.0.1:{peer.port}{path}", http=options, timeout=DEADLINE)
        took = time.monotonic() - began
        attempts = peer.accepted
        time.sleep(0.3)
        assert peer.accepted == attempts  # nothing more after giving up
    assert DEADLINE - 0.3 <= took < DEADLINE + SLACK
    assert "\n" not in str(caught.value) and "see --timeout" in str(caught.value)


def test_a_chunk_dripped_after_a_good_opening_gives_up_at_its_deadline(origin: Origin) -> None:
    """Each chunk read has the deadline of its own: opening is quick, the chunk is dripped."""
    origin.faults.add("trickle_chunks")
    with open_stream(origin.url(), timeout=DEADLINE) as client:
        began = time.monotonic()
        with pytest.raises(
            SourceError, match=r"bytes \[\d+, \d+\)( \(\d+ came\))? not received within 2 s"
        ):
            client.frame_at(0.3)
        assert DEADLINE - 0.1 <= time.monotonic() - began < DEADLINE + SLACK
        assert client.stats.requests == 2  # the opening, then one cut-off chunk read


@pytest.mark.parametrize("command", ["fetch", "play", "info", "frame", "verify"])
def test_cli_timeout_is_one_line_at_the_deadline(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = {
        "fetch": ["--t", "0", "-o", str(tmp_path / "f.ply")],
        "frame": ["--t", "0", "-o", str(tmp_path / "f.ply")],
    }.get(command, [])
    with Peer(drip(HEAD_206, DRIP_S), lifetime_s=DEADLINE + 10) as peer:
        url = f"http://127.0.0.1:{peer.port}/s.tsogs"
        began = time.monotonic()
        assert main([command, url, *argv, "--timeout", f"{DEADLINE:g}", "-q"]) == 1
        took = time.monotonic() - began
    err = capsys.readouterr().err
    assert err.startswith("tsog: error: ") and len(err.strip().splitlines()) == 1, err
    assert "not received within 2 s" in err and took < DEADLINE + SLACK
    assert not (tmp_path / "f.ply").exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_a_timeout_that_is_not_a_positive_time_is_refused(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["info", "http://127.0.0.1:9/s.tsogs", "--timeout", value])
    assert exited.value.code == 2 and "--timeout" in capsys.readouterr().err
    with pytest.raises(InputError, match="seconds > 0"):
        open_stream("http://127.0.0.1:9/s.tsogs", timeout=float(value) if value != "soon" else 0)
