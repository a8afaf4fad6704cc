"""The client, unchanged, against real origins on 127.0.0.1: nginx (static) and our own server.

Both layouts: one ``.tsogs`` file read by ranges, and the unpacked folder read file by file.
nginx runs as a foreground child process (``daemon off``) on an ephemeral port and is always
stopped in a ``finally``; a missing nginx is a failure (scripts/setup installs it).
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from helpers import ThreadedServer, nginx_origin
from tsog_stream.cli.client_commands import add_client_commands, cmd_play
from tsog_stream.client import HttpOptions, Stream, StreamClient, open_stream
from tsog_stream.container.ranges import coalesce
from tsog_stream.errors import IntegrityError, SourceError
from tsog_stream.model import Gaussians, TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server.app import make_app
from tsog_stream.synthetic import small_scene

TIMES = (0.0, 0.3, 0.7, 1.2, 1.9)
FAST = HttpOptions(retries=2, backoff_s=0.01, read_timeout_s=5.0)

needs_nginx = pytest.mark.nginx  # nginx_origin fails when nginx is missing


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``scene.tsogs`` and its unpacked layout ``scene/``."""
    root = tmp_path_factory.mktemp("site")
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0, dynamic=("means",))
    segment_scene(scene, root / "scene.tsogs", SegmentOptions(window_s=0.5, policy="duplicate"))
    with open_stream(root / "scene.tsogs") as reader:
        reader.unpack(root / "scene")
    return root


@pytest.fixture(scope="module")
def expected(site: Path) -> list[Gaussians]:
    """The frames at TIMES read locally."""
    with open_stream(site / "scene.tsogs") as reader:
        return [reader.frame_at(t) for t in TIMES]


@contextmanager
def own_server(root: Path) -> Iterator[str]:
    """Our aiohttp server on 127.0.0.1 in a background loop; yields its ``/files/`` base URL."""
    server = ThreadedServer(make_app(root))
    try:
        yield f"http://127.0.0.1:{server.port}/files/"
    finally:
        server.stop()


ORIGINS = [
    pytest.param("nginx", marks=needs_nginx),
    pytest.param("nginx-max-ranges-1", marks=needs_nginx),
    pytest.param("server"),
]


@pytest.fixture(scope="module", params=ORIGINS)
def base(
    request: pytest.FixtureRequest, site: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    """Base URL of an origin serving ``site`` with byte ranges."""
    kind: str = request.param
    if kind == "server":
        with own_server(site) as url:
            yield url
        return
    prefix = tmp_path_factory.mktemp("nginx")
    with nginx_origin(site, prefix, 1 if kind.endswith("-1") else None) as url:
        yield url


@pytest.fixture(scope="module")
def no_ranges(site: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """nginx with ``max_ranges 0``: every GET is a 200 with the whole file."""
    with nginx_origin(site, tmp_path_factory.mktemp("nginx0"), 0) as url:
        yield url


def same(a: Gaussians, b: Gaussians) -> bool:
    names = ("means", "scales", "quats", "opacities", "sh0", "shN")
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names)


def test_packed_frames_equal_local_and_requests_are_counted(
    base: str, expected: list[Gaussians]
) -> None:
    async def run() -> None:
        async with await StreamClient.open(base + "scene.tsogs", http=FAST) as client:
            assert client.source.stats.requests == 1  # open = one request
            for t, want in zip(TIMES, expected, strict=True):
                runs = coalesce(
                    (
                        client.index.chunk_range(c)
                        for c in client.index.chunks_for(t)
                        if c.id not in client.cache
                    ),
                    client.coalesce_gap or 0,
                )
                before = client.source.stats.requests
                got = await client.frame_at(t)
                assert client.source.stats.requests - before == len(runs), t
                assert same(got, want), t
            before = client.source.stats.requests
            assert same(await client.frame_at(TIMES[0]), expected[0])
            assert client.source.stats.requests == before  # cached: no request

    asyncio.run(run())


def test_unpacked_folder_over_http(base: str, expected: list[Gaussians]) -> None:
    for url in (base + "scene/", base + "scene/manifest.json"):
        with open_stream(url, http=FAST) as sync:
            client = sync.client
            assert not client.source.coalesces
            assert client.source.stats.requests == 1  # manifest.json
            for t, want in zip(TIMES, expected, strict=True):
                missing = [c for c in client.index.chunks_for(t) if c.id not in client.cache]
                before = client.source.stats.requests
                assert same(sync.frame_at(t), want), t
                assert client.source.stats.requests - before == len(missing), t


def test_unpacked_local_folder(site: Path, expected: list[Gaussians]) -> None:
    for target in (site / "scene", site / "scene" / "manifest.json", f"file://{site}/scene/"):
        with open_stream(target) as sync:
            assert sync.client.source.stats.requests == 1
            for t, want in zip(TIMES, expected, strict=True):
                assert same(sync.frame_at(t), want), t


def test_unpacked_chunk_is_verified(site: Path, tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    shutil.copytree(site / "scene", folder)
    with open_stream(folder) as sync:
        chunk = sync.client.index.chunks_for(TIMES[0])[0]
        path = folder / chunk.file
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0x55
        path.write_bytes(bytes(data))
        with pytest.raises(IntegrityError):
            sync.frame_at(TIMES[0])


@needs_nginx
def test_origin_ignoring_ranges_small_file_kept_in_memory(
    no_ranges: str, site: Path, expected: list[Gaussians]
) -> None:
    size = (site / "scene.tsogs").stat().st_size
    http = HttpOptions(retries=0, max_unranged_bytes=size)
    with open_stream(no_ranges + "scene.tsogs", http=http) as sync:
        stats = sync.client.source.stats
        assert stats.requests == 1 and stats.bytes == size
        for t, want in zip(TIMES, expected, strict=True):
            assert same(sync.frame_at(t), want), t
        assert stats.requests == 1  # every read served from memory


@needs_nginx
def test_origin_ignoring_ranges_big_file_refused(no_ranges: str, site: Path) -> None:
    size = (site / "scene.tsogs").stat().st_size
    http = HttpOptions(retries=0, max_unranged_bytes=size - 1)
    with pytest.raises(SourceError, match="origin ignores Range"):
        open_stream(no_ranges + "scene.tsogs", http=http)


def test_cli_play_keeps_no_frames(
    site: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def collect(*args: object, **kwargs: object) -> None:
        raise AssertionError("tsog play must not collect the frames")

    monkeypatch.setattr(Stream, "run_playback", collect)
    parser = argparse.ArgumentParser()
    add_client_commands(parser.add_subparsers(dest="command"))
    lines: list[str] = []
    args = parser.parse_args(["play", str(site / "scene"), "--duration", "0.5", "--fps", "10"])
    assert cmd_play(args, lines.append) == 0
    assert "frames:          6" in capsys.readouterr().out
    assert any("frame 6" in line for line in lines)
