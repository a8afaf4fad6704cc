"""A short bounded load test: 50 players at random t against `tsog serve` as a real process.

Each player fetches the chunks ``chunks_for_interval(t, t+1)`` chooses, with Range GETs on the
``.tsogs`` file and with the API's chunk URLs, over keep-alive connections, for about 3 s.
Every body is compared with the file's bytes; no request may fail, and the server's RSS may
grow only a little. Figures for 200 clients beside nginx are in docs/benchmarks.md
(benchmarks/bench_load.py).
"""

from __future__ import annotations

import asyncio
import random
import time
from pathlib import Path

import aiohttp
import pytest

from serve_process import tsog_serve
from tsog_stream.container.sources import FileSource, read_index
from tsog_stream.container.stream_index import StreamIndex
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene

CLIENTS = 50
SECONDS = 3.0


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A container whose chunks are above and below the 64 KiB sendfile threshold."""
    root = tmp_path_factory.mktemp("load")
    spec = SceneSpec(background=20000, objects=8, per_object=1000, duration=4.0, sh_bands=0, seed=3)
    segment_scene(generate_scene(spec), root / "clip.tsogs", SegmentOptions(window_s=0.5))
    return root / "clip.tsogs"


async def play(base: str, index: StreamIndex, data: bytes, seed: int) -> tuple[int, list[str]]:
    """One player for SECONDS: (requests done, errors)."""
    rng = random.Random(seed)
    info = index.manifest.scene
    done, errors = 0, []
    deadline = time.monotonic() + SECONDS
    timeout = aiohttp.ClientTimeout(total=30)
    async with aiohttp.ClientSession(timeout=timeout) as session:  # one keep-alive connection
        for _ in range(10_000):
            if time.monotonic() > deadline:
                break
            t = rng.uniform(info.start_s, info.end_s)
            for c in index.chunks_for_interval(t, t + 1.0):
                want = data[c.offset : c.offset + c.length]
                if rng.random() < 0.5:
                    url, headers = (
                        f"{base}/files/clip.tsogs",
                        {"Range": f"bytes={c.offset}-{c.offset + c.length - 1}"},
                    )
                    status = 206
                else:
                    url, headers, status = (
                        f"{base}/v1/scenes/clip/chunks/{c.id}.sog?v={c.sha256}",
                        {},
                        200,
                    )
                try:
                    async with session.get(url, headers=headers) as r:
                        body = await r.read()
                        if (r.status, body) != (status, want):
                            errors.append(f"{url} {headers} -> {r.status}, {len(body)} bytes")
                except (aiohttp.ClientError, TimeoutError) as exc:
                    errors.append(f"{url}: {exc!r}")
                done += 1
    return done, errors


async def load(port: int, clip: Path) -> tuple[int, list[str]]:
    """CLIENTS players at once."""
    index = await read_index(FileSource(clip))
    data = clip.read_bytes()
    base = f"http://127.0.0.1:{port}"
    results = await asyncio.gather(*(play(base, index, data, i) for i in range(CLIENTS)))
    return sum(n for n, _ in results), [e for _, errs in results for e in errs]


@pytest.mark.slow
def test_fifty_players_get_exact_bytes(clip: Path) -> None:
    with tsog_serve(clip.parent) as srv:
        rss0 = srv.rss_mib()
        requests, errors = asyncio.run(load(srv.port, clip))
        assert errors == []
        assert requests >= CLIENTS  # every player got at least one round through
        assert srv.rss_mib() - rss0 < 50
        assert "Traceback" not in srv.stderr()
