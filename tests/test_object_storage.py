"""Object storage: inputs, containers and unpacked layouts in an S3 bucket on loopback.

The S3 API is moto's threaded server (the only S3 implementation installable from the
registries here) on 127.0.0.1; s3fs talks to it through ``AWS_ENDPOINT_URL``, as it would to
MinIO or a cloud region. Every result is compared byte for byte with the local run.
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import random
import re
import socket
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import fsspec
import pytest
from fsspec import AbstractFileSystem

from helpers import ThreadedServer, fetch, loopback_s3
from peers import Peer, random_bytes, silent
from tsog_stream import server as server_module
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.container.header import PREFIX_SIZE
from tsog_stream.container.objects import (
    MAX_PARTS,
    MIN_PART_SIZE,
    PART_SIZE,
    MultipartObject,
    ObjectSource,
    container_output,
    part_size,
)
from tsog_stream.container.ranges import ByteRange
from tsog_stream.container.sources import read_index
from tsog_stream.errors import SourceError
from tsog_stream.io import sequence as sequence_module
from tsog_stream.io.objects import ObjectPath, is_object_url
from tsog_stream.io.readers import load_scene
from tsog_stream.io.sequence import open_sequence
from tsog_stream.schemas.manifest import Manifest
from tsog_stream.segment import SegmentOptions, segment_sequence
from tsog_stream.server import make_app

s3fs = pytest.importorskip("s3fs")  # extra tsog-stream[s3]

DATA = Path(__file__).parent / "data" / "real" / "4d"
FRAMES = DATA / "tztechno_fireworks_frames"
CLIP = sorted(FRAMES.iterdir())[:3]
"""The frames the bucket and the local reference hold: three are a sequence, and quick."""
BUCKET = "studio"


@pytest.fixture(scope="module")
def s3() -> Iterator[Any]:
    """A bucket on a loopback S3 server; the environment points s3fs at it."""
    with loopback_s3(BUCKET) as fs:
        for frame in CLIP:
            fs.pipe_file(f"{BUCKET}/frames/{frame.name}", frame.read_bytes())
        yield fs


def _cli(*args: str) -> int:
    return main(list(args))


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The clip's frames in a local folder."""
    folder = tmp_path_factory.mktemp("clip")
    for frame in CLIP:
        (folder / frame.name).write_bytes(frame.read_bytes())
    return folder


@pytest.fixture(scope="module")
def local(clip: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The frames segmented locally: what every remote run must equal."""
    path = tmp_path_factory.mktemp("local") / "fireworks.tsogs"
    assert _cli("segment", str(clip), "-o", str(path), "-q") == 0
    return path


def test_urls_are_told_apart() -> None:
    assert is_object_url("s3://bucket/key") and is_object_url("gs://b/k")
    assert not is_object_url("http://host/x") and not is_object_url("file:///tmp/x")
    assert not is_object_url("/tmp/x") and not is_object_url("C:/x")


def test_a_frame_glob_in_a_bucket_reads_as_the_local_frames(s3: Any, clip: Path) -> None:
    remote = load_scene(f"s3://{BUCKET}/frames/frame_*.ply")
    local = load_scene(str(clip / "frame_*.ply"))
    assert remote.format == local.format == "ply-sequence"
    assert remote.notes == local.notes
    a, b = remote.scene.gaussians, local.scene.gaussians
    assert len(a.means) == len(b.means) > 0
    for name in ("means", "scales", "quats", "opacities", "sh0", "shN"):
        assert (getattr(a, name) == getattr(b, name)).all(), name


def test_segment_from_and_to_a_bucket_equals_the_local_run(
    s3: Any, local: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"s3://{BUCKET}/out/fireworks.tsogs"
    assert _cli("segment", f"s3://{BUCKET}/frames/", "-o", url, "-q") == 0
    assert s3.cat_file(f"{BUCKET}/out/fireworks.tsogs") == local.read_bytes()
    assert s3.exists(f"{BUCKET}/out/fireworks.tsogs.thumb.png")  # the thumbnail beside it
    capsys.readouterr()
    # an existing object is refused like an existing file, before any work
    assert _cli("segment", str(FRAMES), "-o", url, "-q") != 0
    assert "already exists" in capsys.readouterr().err


def test_a_stored_container_opens_with_one_ranged_get(s3: Any, local: Path) -> None:
    s3.pipe_file(f"{BUCKET}/c.tsogs", local.read_bytes())
    source = ObjectSource(f"s3://{BUCKET}/c.tsogs")
    index = asyncio.run(read_index(source))
    assert source.stats.requests == 1 and source.stats.bytes <= PREFIX_SIZE
    chunk = index.manifest.chunks[-1]
    data = asyncio.run(source.read(ByteRange(chunk.offset, chunk.offset + chunk.length)))
    assert data == local.read_bytes()[chunk.offset : chunk.offset + chunk.length]
    with pytest.raises(SourceError, match="no such object"):
        asyncio.run(ObjectSource(f"s3://{BUCKET}/missing.tsogs").size())


def test_unpack_to_a_bucket_and_back(
    s3: Any, local: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    prefix = f"s3://{BUCKET}/cdn/fireworks/"
    assert _cli("unpack", str(local), "-o", prefix) == 0
    names = s3.find(f"{BUCKET}/cdn/fireworks")
    assert f"{BUCKET}/cdn/fireworks/manifest.json" in names
    assert any(n.endswith("chunks/000000.sog") for n in names)
    assert _cli("verify", prefix) == 0
    back = tmp_path / "back.tsogs"
    assert _cli("pack", prefix, "-o", str(back)) == 0
    assert back.read_bytes() == local.read_bytes()
    capsys.readouterr()
    assert _cli("unpack", str(local), "-o", prefix) != 0  # exists: --force replaces it
    assert "already exists" in capsys.readouterr().err
    assert _cli("unpack", str(local), "-o", prefix, "--force") == 0


def _big_container(out: Any, sizes: list[int]) -> None:
    """Random (incompressible) payloads of ``sizes`` and an index listing them."""
    entries = []
    rng = random.Random(5)
    for i, size in enumerate(sizes):
        offset, length, digest = out.add(rng.randbytes(size))
        box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
        entries.append(
            {
                "id": i,
                "file": f"chunks/{i:06d}.sog",
                "offset": offset,
                "length": length,
                "sha256": digest,
                "count": 1,
                "level": 0,
                "node": 0,
                "start_s": float(i),
                "end_s": float(i + 1),
                "bbox": box,
            }
        )
    out.finish(_manifest(entries))


def _manifest(entries: list[dict[str, Any]]) -> Manifest:
    box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
    return Manifest.model_validate(
        {
            "format": "tsogs",
            "version": 1,
            "generator": "test",
            "policy": "duplicate",
            "window_s": 1.0,
            "max_pixels": 256,
            "scene": {
                "gaussians": len(entries),
                "stored": len(entries),
                "start_s": 0.0,
                "end_s": float(len(entries)),
                "fps": None,
                "timeline_type": None,
                "temporal": {},
                "sh_bands": 0,
                "bbox": box,
            },
            "nodes": [],
            "chunks": entries,
            "payload_bytes": sum(int(e["length"]) for e in entries),
        }
    )


SIZES = [3 << 20] * 7 + [12345]
"""About 21 MiB: three parts, the first held back."""


def test_a_large_container_goes_up_in_parts_with_the_head_last(
    s3: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    local = tmp_path / "big.tsogs"
    with container_output(local) as out:
        _big_container(out, SIZES)
    calls: list[tuple[str, int]] = []
    seen_early: list[bool] = []
    call = MultipartObject._call

    def recorded(self: MultipartObject, method: str, **kwargs: Any) -> dict[str, Any]:
        calls.append((method, int(kwargs.get("PartNumber", 0))))
        if method == "complete_multipart_upload":
            s3.invalidate_cache()
            seen_early.append(s3.exists(f"{BUCKET}/big.tsogs"))
        return call(self, method, **kwargs)

    monkeypatch.setattr(MultipartObject, "_call", recorded)
    with container_output(f"s3://{BUCKET}/big.tsogs") as out:
        _big_container(out, SIZES)
    parts = [n for m, n in calls if m == "upload_part"]
    assert calls[0][0] == "create_multipart_upload" and calls[-1][0] == "complete_multipart_upload"
    assert parts[-1] == 1 and sorted(parts) == list(range(1, len(parts) + 1)) and len(parts) >= 3
    assert seen_early == [False]  # nothing at the destination until the upload completes
    s3.invalidate_cache()
    assert s3.cat_file(f"{BUCKET}/big.tsogs") == local.read_bytes()
    assert local.stat().st_size > 2 * PART_SIZE


def test_an_interrupted_upload_leaves_nothing(s3: Any) -> None:
    key = f"{BUCKET}/broken.tsogs"
    with (
        pytest.raises(KeyboardInterrupt),
        container_output(f"s3://{key}") as out,
    ):
        for _ in range(6):
            out.add(os.urandom(3 << 20))  # two parts went up
        raise KeyboardInterrupt
    s3.invalidate_cache()
    assert not s3.exists(key)
    pending = s3.call_s3("list_multipart_uploads", Bucket=BUCKET).get("Uploads", [])
    assert [u for u in pending if u["Key"] == "broken.tsogs"] == []


def test_store_failures_are_one_line_errors(
    s3: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = [
        (["info", f"s3://{BUCKET}/nothing.tsogs"], "no such"),
        (["segment", f"s3://{BUCKET}/nothing/*.ply", "-o", str(tmp_path / "x.tsogs")], "no"),
        (["segment", str(FRAMES), "-o", "s3://no-such-bucket/x.tsogs", "-q"], "no bucket"),
        (["info", "nosuchscheme://x/y.tsogs"], "nosuchscheme"),
        (["info", "gs://bucket/y.tsogs"], "gcsfs"),  # its backend is not installed here
    ]
    for args, words in cases:
        assert _cli(*args) != 0, args
        err = capsys.readouterr().err
        assert "Traceback" not in err and words in err, (args, err)
        assert len(err.strip().splitlines()) <= 2, err
    assert ObjectPath.from_url(f"s3://{BUCKET}/frames").is_dir()


def test_serve_a_bucket_prefix(s3: Any, local: Path, tmp_path: Path) -> None:
    """tsog serve s3://...: scene list, manifest, chunks and ranges as from a folder."""
    data = local.read_bytes()
    s3.pipe_file(f"{BUCKET}/media/fireworks.tsogs", data)
    assert _cli("unpack", str(local), "-o", f"s3://{BUCKET}/media/loose/") == 0
    s3.pipe_file(f"{BUCKET}/media/fireworks.tsogs.thumb.png", b"\x89PNG-not-really")
    server = ThreadedServer(make_app(f"s3://{BUCKET}/media/"))
    try:
        listed = json.loads(fetch(server.port, "/v1/scenes").body)["scenes"]
        assert [s["id"] for s in listed] == ["fireworks", "loose"]
        assert listed[0]["thumbnail"] and listed[1]["thumbnail"] is None
        whole = fetch(server.port, "/files/fireworks.tsogs")
        assert whole.status == 200 and whole.body == data
        etag = whole.headers["ETag"]
        assert (
            fetch(server.port, "/files/fireworks.tsogs", headers={"If-None-Match": etag}).status
            == 304
        )
        part = fetch(server.port, "/files/fireworks.tsogs", headers={"Range": "bytes=100-199"})
        assert part.status == 206 and part.body == data[100:200]
        multi = fetch(server.port, "/files/fireworks.tsogs", headers={"Range": "bytes=0-9,50-59"})
        assert multi.status == 206 and data[50:60] in multi.body
        index = asyncio.run(read_index(ObjectSource(f"s3://{BUCKET}/media/fireworks.tsogs")))
        for scene in ("fireworks", "loose"):
            for entry in index.manifest.chunks:
                got = fetch(server.port, f"/v1/scenes/{scene}/chunks/{entry.id}.sog")
                assert got.status == 200
                assert got.body == data[entry.offset : entry.offset + entry.length], scene
        assert fetch(server.port, "/files/nothing.tsogs").status == 404
        assert fetch(server.port, "/files/../secret").status in (400, 404)
        assert fetch(server.port, "/v1/scenes/nothing/manifest").status == 404
        # the client plays the served scene as it plays the local file
        served = f"http://127.0.0.1:{server.port}/files/fireworks.tsogs"
        with open_stream(served) as remote, open_stream(local) as here:
            assert (remote.frame_at(0.05).means == here.frame_at(0.05).means).all()
    finally:
        server.stop()


def test_the_client_reads_a_stored_container_and_folder(s3: Any, local: Path) -> None:
    s3.pipe_file(f"{BUCKET}/play/fireworks.tsogs", local.read_bytes())
    assert _cli("unpack", str(local), "-o", f"s3://{BUCKET}/play/loose/") == 0
    with open_stream(local) as here:
        expected = here.frame_at(0.1).means
    for url in (
        f"s3://{BUCKET}/play/fireworks.tsogs",
        f"s3://{BUCKET}/play/loose/",
        f"s3://{BUCKET}/play/loose",
    ):
        with open_stream(url) as stream:
            assert (stream.frame_at(0.1).means == expected).all(), url


def test_part_sizes_grow_so_hours_of_capture_fit_one_upload() -> None:
    sizes = [part_size(n) for n in range(1, MAX_PARTS + 1)]
    assert sizes[0] == PART_SIZE and min(sizes) >= MIN_PART_SIZE
    assert sizes == sorted(sizes) and sum(sizes) > 400 * 2**30  # 400 GiB in 10000 parts
    assert max(sizes) <= 128 << 20  # two parts in memory stay bounded


def test_cluster_workers_read_their_own_frames_from_the_bucket(
    s3: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame sequence in the bucket segmented on a LocalCluster: each job is a window its
    worker reads from the store itself, so this process reads only the frames it samples
    (layout, opening view, layers), and the container equals the one-process run."""
    distributed = pytest.importorskip("distributed")
    for k in range(4):  # 4 windows: 2 a worker, the least that makes windows the jobs
        s3.pipe_file(f"{BUCKET}/long/f_{k:03d}.ply", CLIP[k % len(CLIP)].read_bytes())
    seq = open_sequence(f"s3://{BUCKET}/long/")
    options = SegmentOptions(window_s=1 / 30, layers=1, max_pixels=64 * 64)
    reads: list[str] = []
    read_frame = sequence_module._read_frame

    def counting(kind: str, path: Any) -> Any:
        reads.append(str(path))
        return read_frame(kind, path)

    monkeypatch.setattr(sequence_module, "_read_frame", counting)
    alone = tmp_path / "one.tsogs"
    segment_sequence(seq, alone, replace(options, workers=1))
    here = len(reads)
    reads.clear()
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        url = f"s3://{BUCKET}/long.tsogs"
        segment_sequence(seq, url, replace(options, cluster=cluster.scheduler_address))
    assert reads and len(reads) == here - seq.count  # the samples only: no window read here
    s3.invalidate_cache()
    assert s3.cat_file(f"{BUCKET}/long.tsogs") == alone.read_bytes()


class _FailingStore(AbstractFileSystem):  # type: ignore[misc]
    """A store whose every call fails with ``error`` (an S3 403, a stalled backend ...)."""

    error: Exception = PermissionError("403 AccessDenied")

    def _fail(self, *args: Any, **kwargs: Any) -> Any:
        raise self.error

    info = ls = cat_file = _open = du = glob = pipe_file = put_file = rm_file = _fail
    exists = isdir = isfile = _fail


class _DeniedStore(_FailingStore):
    protocol = "denied"


class _StalledStore(_FailingStore):
    protocol = "stalled"
    error = TimeoutError("read timed out after 60 s")


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then closed)."""
    with socket.create_server(("127.0.0.1", 0)) as sock:
        return int(sock.getsockname()[1])


def _no_lookup(host: str, *args: Any, **kwargs: Any) -> Any:
    """getaddrinfo for a test of names that do not resolve: no lookup leaves the machine."""
    raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")


STORE_FAILURES = {
    "ftp, connection refused": ("ftp://127.0.0.1:{closed}/x.tsogs", "ConnectionRefusedError"),
    "ftp, a server that says nothing": ("ftp://127.0.0.1:{silent}/x.tsogs", "timed out"),
    "ftp, a server that sends noise": ("ftp://127.0.0.1:{noise}/x.tsogs", "cannot connect: "),
    "ftp, a name that does not resolve": ("ftp://no-such-host.invalid/x.tsogs", "gaierror"),
    "webhdfs (HTTP through fsspec), refused": ("webhdfs://127.0.0.1:{closed}/d/x.tsogs", "refused"),
    "s3, endpoint refused": ("s3://bucket/x.tsogs", "Could not connect to the endpoint"),
    "memory, nothing there": ("memory://nothing/x.tsogs", "no such|no bucket 'nothing'"),
    "file, nothing there": ("file:///nonexistent-55/x.tsogs", "(?i)no such (file|folder)"),
    "an unknown protocol": ("nosuchproto://x/y.tsogs", "Protocol not known: nosuchproto"),
    "a backend not installed": ("gs://bucket/x.tsogs", "gs:// is not available here"),
    "a protocol missing its settings": ("dbfs://x/y.tsogs", "not a storage URL fsspec can open"),
    "a port out of range": ("ftp://127.0.0.1:99999/x.tsogs", "Port out of range"),
    "access denied": ("denied://bucket/x.tsogs", "access denied|no access"),
    "a store that times out": ("stalled://bucket/x.tsogs", "timed out|no access"),
}
"""Failures at the object-store boundary: (URL, what the one error line says)."""


def _store_argv(command: str, url: str, tmp_path: Path) -> list[str]:
    out = str(tmp_path / "out.ply")
    return {
        "info": ["info", url],
        "frame": ["frame", url, "--t", "0", "-o", out],
        "verify": ["verify", url],
        "serve": ["serve", url, "--port", "0", "--workers", "1"],
        "segment": ["segment", url, "-o", str(tmp_path / "o.tsogs")],
        "segment -o": ["segment", str(FRAMES), "-o", url, "-q"],
    }[command]


STORE_COMMANDS = ["info", "frame", "verify", "serve", "segment", "segment -o"]
STORE_CASES = [
    (failure, command)
    for failure in STORE_FAILURES
    for command in STORE_COMMANDS
    if (failure, command) != ("file, nothing there", "segment -o")  # a missing folder is made
]


@pytest.mark.parametrize(("failure", "command"), STORE_CASES)
def test_a_store_that_fails_is_one_line_for_every_command(
    failure: str,
    command: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Every way a store can fail (refused, silent, noise, no such name, unknown or missing
    protocol, denied, timed out) is one line naming the URL, for every command reaching it."""
    url, expected = STORE_FAILURES[failure]
    if failure == "a backend not installed" and importlib.util.find_spec("gcsfs"):
        pytest.skip("gcsfs is installed here")
    fsspec.register_implementation("denied", _DeniedStore, clobber=True)
    fsspec.register_implementation("stalled", _StalledStore, clobber=True)
    monkeypatch.setitem(fsspec.config.conf, "ftp", {"timeout": 1.0})
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{_closed_port()}")
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")
    for key in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.setenv(key, "loopback")
    if "resolve" in failure:
        monkeypatch.setattr(socket, "getaddrinfo", _no_lookup)
    for name in ("run_server", "run_workers"):  # a test that wrongly served would never end
        monkeypatch.setattr(server_module, name, _never_serve)
    s3fs.S3FileSystem.clear_instance_cache()
    with Peer(silent, lifetime_s=20) as quiet, Peer(random_bytes, lifetime_s=20) as noisy:
        url = url.format(closed=_closed_port(), silent=quiet.port, noise=noisy.port)
        began = time.monotonic()
        code = main(_store_argv(command, url, tmp_path))
        took = time.monotonic() - began
    s3fs.S3FileSystem.clear_instance_cache()
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("tsog: error: ") and url.split("://")[1] in lines[-1], err
    assert len([line for line in lines if "error" in line]) == 1, err
    assert re.search(expected, lines[-1]), (expected, err)
    assert took < 20 and not (tmp_path / "o.tsogs").exists() and not (tmp_path / "out.ply").exists()


def _never_serve(*args: Any, **kwargs: Any) -> None:
    raise AssertionError("the server started on a store that fails")
