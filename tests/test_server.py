"""The HTTP server on loopback: raw files with byte ranges, conditionals, CORS, safety, API."""

from __future__ import annotations

import argparse
import asyncio
import email.message
import email.parser
import hashlib
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from helpers import Resp, ThreadedServer, fetch, nginx_origin, wait_until
from tsog_stream.cli.main import main
from tsog_stream.cli.progress import Progress
from tsog_stream.cli.serve_commands import add_serve_command, cmd_serve
from tsog_stream.client import open_stream
from tsog_stream.container.ranges import ByteRange
from tsog_stream.errors import InputError
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import Limits, make_app, respond
from tsog_stream.server.respond import LOAD
from tsog_stream.synthetic import small_scene

SECRET = b"TOP-SECRET-OUTSIDE-THE-ROOT"
DATA = bytes(range(256)) * 400 + b"tail"  # 102 404 bytes


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with a data file, a container, its unpacked layout and a symlink out of it."""
    base = tmp_path_factory.mktemp("srv")
    (base / "secret.txt").write_bytes(SECRET)
    root = base / "root"
    (root / "sub").mkdir(parents=True)
    (root / "data.bin").write_bytes(DATA)
    (root / "sub" / "note.txt").write_bytes(b"hello")
    (root / "escape.txt").symlink_to(base / "secret.txt")
    (root / "escape_dir").symlink_to(base)
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0)
    segment_scene(scene, root / "clip.tsogs", SegmentOptions(window_s=0.5))
    with open_stream(root / "clip.tsogs") as reader:
        reader.unpack(root / "unpacked")
    return root


@pytest.fixture(scope="module")
def port(tree: Path) -> Iterator[int]:
    """A running server on the tree."""
    server = ThreadedServer(make_app(tree))
    try:
        yield server.port
    finally:
        server.stop()


def test_whole_file(port: int) -> None:
    r = fetch(port, "/files/data.bin")
    assert r.status == 200 and r.body == DATA
    assert r.headers["Content-Length"] == str(len(DATA))
    assert r.headers["Accept-Ranges"] == "bytes"
    assert r.headers["ETag"] == f'"{hashlib.sha256(DATA).hexdigest()}"'
    assert r.headers["Cache-Control"] == "public, max-age=0, must-revalidate"
    assert r.headers["Last-Modified"].endswith("GMT")
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    assert "Content-Range" in r.headers["Access-Control-Expose-Headers"]
    assert "Content-Encoding" not in r.headers


@pytest.mark.parametrize(
    ("value", "start", "end"),
    [
        ("bytes=0-0", 0, 1),
        ("bytes=100-199", 100, 200),
        ("bytes=102000-", 102000, len(DATA)),
        ("bytes=-4", len(DATA) - 4, len(DATA)),
        ("bytes=102400-999999", 102400, len(DATA)),
    ],
)
def test_single_ranges(port: int, value: str, start: int, end: int) -> None:
    r = fetch(port, "/files/data.bin", headers={"Range": value, "Accept-Encoding": "gzip"})
    assert r.status == 206 and r.body == DATA[start:end]
    assert r.headers["Content-Range"] == f"bytes {start}-{end - 1}/{len(DATA)}"
    assert r.headers["Content-Length"] == str(end - start)


def test_unsatisfiable(port: int) -> None:
    for value in ("bytes=102404-", "bytes=-0", "bytes=200000-300000"):
        r = fetch(port, "/files/data.bin", headers={"Range": value})
        assert r.status == 416, value
        assert r.headers["Content-Range"] == f"bytes */{len(DATA)}"


def parse_multipart(r: Resp) -> list[tuple[str, str, bytes]]:
    """(Content-Type, Content-Range, body) of each part of a multipart/byteranges response."""
    raw = f"Content-Type: {r.headers['Content-Type']}\r\n\r\n".encode() + r.body
    msg = email.parser.BytesParser().parsebytes(raw)
    assert msg.is_multipart()
    out = []
    for part in msg.get_payload():
        assert isinstance(part, email.message.Message)
        payload = part.get_payload(decode=True)
        assert isinstance(payload, bytes)
        out.append((str(part["Content-Type"]), str(part["Content-Range"]), payload))
    return out


def test_multiple_ranges(port: int) -> None:
    r = fetch(port, "/files/data.bin", headers={"Range": "bytes=-4, 0-9,5-19,20-29, 500-599"})
    assert r.status == 206
    assert r.headers["Content-Type"].startswith("multipart/byteranges; boundary=")
    assert int(r.headers["Content-Length"]) == len(r.body)
    parts = parse_multipart(r)
    n = len(DATA)
    assert [(p[1], p[2]) for p in parts] == [
        (f"bytes 0-29/{n}", DATA[0:30]),
        (f"bytes 500-599/{n}", DATA[500:600]),
        (f"bytes {n - 4}-{n - 1}/{n}", DATA[-4:]),
    ]
    assert all(p[0] == "application/octet-stream" for p in parts)


def test_malformed_ranges_never_fail(port: int) -> None:
    too_many = "bytes=" + ",".join("0-0" for _ in range(1500))  # within aiohttp's 8 KiB
    for value in (
        "bytes=abc",
        "bytes=5-2",
        "bytes=1-2-3",
        "items=0-1",
        too_many,
        "bytes=é-1".encode(),
        b"bytes=\xff\xfe-1",
    ):
        r = fetch(port, "/files/data.bin", headers={"Range": value})
        assert r.status == 200 and r.body == DATA, value[:30]


def test_head_equals_get_without_body(port: int) -> None:
    for headers in ({}, {"Range": "bytes=10-20"}, {"Range": "bytes=0-1,5-6"}):
        get = fetch(port, "/files/data.bin", headers=headers)
        head = fetch(port, "/files/data.bin", "HEAD", headers)
        assert head.status == get.status and head.body == b""
        skip = {"Date", "Content-Type"}  # multipart boundaries are random per response
        assert {k: v for k, v in head.headers.items() if k not in skip} == {
            k: v for k, v in get.headers.items() if k not in skip
        }


def test_conditionals(port: int) -> None:
    first = fetch(port, "/files/data.bin")
    etag, date = first.headers["ETag"], first.headers["Last-Modified"]
    assert fetch(port, "/files/data.bin", headers={"If-None-Match": etag}).status == 304
    assert fetch(port, "/files/data.bin", "HEAD", {"If-None-Match": etag}).status == 304
    assert fetch(port, "/files/data.bin", headers={"If-Match": '"nope"'}).status == 412
    assert fetch(port, "/files/data.bin", headers={"If-Match": etag}).status == 200
    assert fetch(port, "/files/data.bin", headers={"If-Modified-Since": date}).status == 304
    rng = {"Range": "bytes=0-9"}
    assert fetch(port, "/files/data.bin", headers={**rng, "If-Range": etag}).status == 206
    assert fetch(port, "/files/data.bin", headers={**rng, "If-Range": date}).status == 206
    for other in ('"stale"', f"W/{etag}", "Mon, 01 Jan 2001 00:00:00 GMT"):
        r = fetch(port, "/files/data.bin", headers={**rng, "If-Range": other})
        assert r.status == 200 and r.body == DATA, other


def test_cors_preflight(port: int) -> None:
    r = fetch(
        port,
        "/files/data.bin",
        "OPTIONS",
        {
            "Origin": "https://viewer.example",
            "Access-Control-Request-Method": "GET",
            "Access-Control-Request-Headers": "range, if-range",
        },
    )
    assert r.status == 204
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    allowed = r.headers["Access-Control-Allow-Headers"]
    for name in ("Range", "If-Match", "If-None-Match", "If-Range"):
        assert name in allowed
    assert "GET" in r.headers["Access-Control-Allow-Methods"]


@pytest.mark.parametrize(
    "path",
    [
        "/files/../secret.txt",
        "/files/%2e%2e/secret.txt",
        "/files/sub/%2e%2e/%2e%2e/secret.txt",
        "/files/..%2Fsecret.txt",
        "/files/sub%2F..%2F..%2Fsecret.txt",
        "/files//etc/passwd",
        "/files/%2Fetc%2Fpasswd",
        "/files/escape.txt",
        "/files/escape_dir/secret.txt",
        "/files/data.bin%00",
        "/files/sub%5C..%5C..%5Csecret.txt",
        "/files/nope.bin",
        "/files/sub",
        "/files/./data.bin",
    ],
)
def test_path_safety(port: int, path: str) -> None:
    r = fetch(port, path)
    assert r.status in (400, 404), (path, r.status)
    assert SECRET not in r.body and b"root:" not in r.body


def test_subfolder_file(port: int) -> None:
    assert fetch(port, "/files/sub/note.txt").body == b"hello"


def test_container_etag_is_identity(port: int, tree: Path) -> None:
    with open_stream(tree / "clip.tsogs") as reader:
        identity = reader.index.identity
    r = fetch(port, "/files/clip.tsogs", headers={"Range": "bytes=0-127"})
    assert r.status == 206 and r.headers["ETag"] == f'"{identity}"'
    assert r.body == (tree / "clip.tsogs").read_bytes()[:128]
    assert r.headers["Content-Type"] == "application/vnd.tsog-stream"


def get_json(port: int, path: str, status: int = 200) -> Any:
    """The JSON body of a response with the expected status."""
    r = fetch(port, path)
    assert r.status == status, (path, r.status, r.body[:200])
    assert r.headers["Content-Type"].startswith("application/json")
    return json.loads(r.body)


def test_healthz_and_scene_list(port: int, tree: Path) -> None:
    assert get_json(port, "/healthz") == {"status": "ok"}
    with open_stream(tree / "clip.tsogs") as reader:
        identity = reader.index.identity
    items = {s["id"]: s for s in get_json(port, "/v1/scenes")["scenes"]}
    assert set(items) == {"clip", "unpacked"}
    assert items["clip"]["url"] == "/files/clip.tsogs"
    assert items["clip"]["bytes"] == (tree / "clip.tsogs").stat().st_size
    assert items["clip"]["identity"] == items["unpacked"]["identity"] == identity
    assert items["clip"]["duration_s"] > 0


@pytest.mark.parametrize("scene", ["clip", "unpacked"])
def test_manifest_and_chunks(port: int, tree: Path, scene: str) -> None:
    r = fetch(port, f"/v1/scenes/{scene}/manifest")
    identity = hashlib.sha256(r.body).hexdigest()
    assert r.status == 200 and r.headers["ETag"] == f'"{identity}"'
    assert r.body == (tree / "unpacked" / "manifest.json").read_bytes()
    again = fetch(port, f"/v1/scenes/{scene}/manifest", headers={"If-None-Match": f'"{identity}"'})
    assert again.status == 304
    listing = get_json(port, f"/v1/scenes/{scene}/chunks?t=0.25&horizon=1")
    with open_stream(tree / "clip.tsogs") as reader:
        expected = reader.index.chunks_for_interval(0.25, 1.25)
        assert [c["id"] for c in listing["chunks"]] == [c.id for c in expected]
        assert expected
        for c in listing["chunks"][:3]:
            got = fetch(port, c["url"])
            assert got.status == 200 and got.body == reader.chunk_bytes(c["id"])
            assert got.headers["Cache-Control"] == "public, max-age=31536000, immutable"
            assert got.headers["ETag"] == f'"{c["sha256"]}"'
            plain = fetch(
                port, f"/v1/scenes/{scene}/chunks/{c['id']}.sog", headers={"Range": "bytes=-22"}
            )
            assert plain.status == 206 and plain.body == reader.chunk_bytes(c["id"])[-22:]
            assert plain.headers["Content-Type"] == "application/x-sog"


def test_api_errors(port: int) -> None:
    assert get_json(port, "/v1/scenes/nope/manifest", 404)["error"]["status"] == 404
    assert get_json(port, "/v1/scenes/../clip/manifest", 404)
    assert get_json(port, "/v1/scenes/%2e%2e%2froot%2fclip/manifest", 404)
    assert get_json(port, "/v1/scenes/clip/chunks/99999.sog", 404)
    assert get_json(port, "/v1/scenes/clip/chunks/0.sog?v=deadbeef", 404)
    for query, name in (
        ("", "t"),
        ("?t=abc", "t"),
        ("?t=nan", "t"),
        ("?t=1&horizon=-1", "horizon"),
        ("?t=inf", "t"),
    ):
        body = get_json(port, f"/v1/scenes/clip/chunks{query}", 400)
        assert name in body["error"]["message"], query
    assert get_json(port, "/nowhere", 404)["error"]["status"] == 404


def test_concurrency_cap(tree: Path) -> None:
    server = ThreadedServer(make_app(tree, limits=Limits(max_concurrent=1)))
    try:
        load = server.runner.app[LOAD]
        server.loop.call_soon_threadsafe(load.enter, "127.0.0.9")  # one request in flight
        time.sleep(0.1)
        r = fetch(server.port, "/files/sub/note.txt")
        assert r.status == 503 and r.headers["Retry-After"] == "1"
        assert fetch(server.port, "/healthz").status == 200  # answered whatever the load
        server.loop.call_soon_threadsafe(load.leave, "127.0.0.9")
        time.sleep(0.1)
        assert fetch(server.port, "/files/sub/note.txt").status == 200
    finally:
        server.stop()


def test_one_client_cannot_take_every_slot(tree: Path) -> None:
    server = ThreadedServer(make_app(tree, limits=Limits(max_concurrent=8, max_per_client=2)))
    load = server.runner.app[LOAD]

    def hold(client: str, count: int) -> None:
        """``count`` requests of ``client`` in flight, as the server counts them."""
        for _ in range(count):
            server.loop.call_soon_threadsafe(load.enter, client)
        time.sleep(0.1)

    try:
        hold("127.0.0.1", 2)  # its share, but the server is far from half busy: more may come
        assert fetch(server.port, "/files/sub/note.txt").status == 200
        hold("127.0.0.3", 2)  # now half busy: over its share, 127.0.0.1 waits
        r = fetch(server.port, "/files/sub/note.txt")
        assert r.status == 503 and r.headers["Retry-After"] == "1"
        assert b"from this client" in r.body
        assert fetch(server.port, "/files/sub/note.txt", source="127.0.0.2").status == 200
        assert fetch(server.port, "/healthz").status == 200
    finally:
        server.stop()


@pytest.mark.nginx
def test_agrees_with_nginx(port: int, tree: Path, tmp_path: Path) -> None:
    with nginx_origin(tree, tmp_path / "nginx") as url:
        ngx = urlsplit(url).port or 80
        for value in (
            "bytes=0-0",
            "bytes=100-199",
            "bytes=102000-",
            "bytes=-4",
            "bytes=-0",
            "bytes=102404-",
            "bytes=0-999999",
        ):  # malformed values differ: nginx says 416 where RFC 9110 §14.2 says ignore (200)
            ours = fetch(port, "/files/data.bin", headers={"Range": value})
            theirs = fetch(ngx, "/data.bin", headers={"Range": value})
            assert ours.status == theirs.status, value
            if ours.status < 300:
                assert ours.body == theirs.body, value
            assert ours.headers.get("Content-Range") == theirs.headers.get("Content-Range"), value


def test_serve_command_arguments(tree: Path) -> None:
    parser = argparse.ArgumentParser()
    add_serve_command(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["serve", str(tree / "clip.tsogs")])
    assert (args.host, args.port, args.func) == ("127.0.0.1", 8080, cmd_serve)
    bad = parser.parse_args(["serve", str(tree / "missing"), "--port", "1"])
    with pytest.raises(InputError):
        cmd_serve(bad, Progress(quiet=True))
    with pytest.raises(SystemExit):  # a usage error naming the range 0-65535
        parser.parse_args(["serve", str(tree), "--port", "70000"])


class SendfileSpy:
    """Wraps a loop's ``sendfile`` and records (offset, count) of each call."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.inner = loop.sendfile
        self.calls: list[tuple[int, int | None]] = []

    async def __call__(
        self, transport: Any, file: Any, offset: int = 0, count: int | None = None, **kw: Any
    ) -> int:
        self.calls.append((offset, count))
        return await self.inner(transport, file, offset, count, **kw)


@pytest.fixture
def spied(
    tree: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[tuple[ThreadedServer, SendfileSpy]]:
    """A server on the tree whose loop's sendfile is spied on (the direct first attempt is
    off here: test_a_body_goes_out_directly_and_the_rest_by_the_loop covers it)."""
    monkeypatch.setattr(respond, "sendfile_now", lambda *_: 0)
    server = ThreadedServer(make_app(tree))
    spy = SendfileSpy(server.loop)
    server.loop.sendfile = spy  # type: ignore[method-assign]
    try:
        yield server, spy
    finally:
        server.stop()


def test_sendfile_for_large_single_span(
    spied: tuple[ThreadedServer, SendfileSpy], caplog: pytest.LogCaptureFixture
) -> None:
    server, spy = spied
    with caplog.at_level(logging.INFO, logger="aiohttp.access"):
        r = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=100-90099"})
        assert r.status == 206 and r.body == DATA[100:90100]
        assert spy.calls == [(100, 90000)]
        r = fetch(server.port, "/files/data.bin")
        assert r.status == 200 and r.body == DATA and spy.calls[-1] == (0, len(DATA))
        small = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=0-99"})
        multi = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=0-70000,80000-"})
        head = fetch(server.port, "/files/data.bin", "HEAD", headers={"Range": "bytes=5-"})
    assert small.body == DATA[:100] and multi.status == 206 and len(multi.body) > 90000
    assert head.body == b"" and head.headers["Content-Length"] == str(len(DATA) - 5)
    assert len(spy.calls) == 2  # small, multipart and HEAD bodies do not use sendfile
    logged = [rec.getMessage() for rec in caplog.records if rec.name == "aiohttp.access"]
    sizes = [int(line.split('" ')[1].split()[1]) for line in logged[:2]]
    assert sizes[0] >= 90000 and sizes[1] >= len(DATA)  # %b counts sendfile bytes too


def test_a_body_goes_out_directly_and_the_rest_by_the_loop(
    tree: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One non-blocking os.sendfile sends what fits at once; what it leaves (here it may send
    only 1000 bytes) goes through loop.sendfile; the body is exact either way."""
    real = respond.sendfile_now
    direct: list[tuple[int, int]] = []

    def limited(transport: Any, file: Any, span: ByteRange) -> int:
        sent = real(transport, file, ByteRange.sized(span.start, min(span.length, limit[0])))
        direct.append((span.start, sent))
        return sent

    limit = [1 << 30]
    monkeypatch.setattr(respond, "sendfile_now", limited)
    server = ThreadedServer(make_app(tree))
    spy = SendfileSpy(server.loop)
    server.loop.sendfile = spy  # type: ignore[method-assign]
    try:
        r = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=100-90099"})
        assert r.status == 206 and r.body == DATA[100:90100]
        # the server thread records the send after the client has the bytes
        wait_until(lambda: len(direct) == 1, 5, "the direct send to be recorded")
        assert direct == [(100, 90000)] and spy.calls == []  # all of it at once
        limit[0] = 1000
        r = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=50-"})
        assert r.status == 206 and r.body == DATA[50:]
        wait_until(lambda: len(direct) == 2 and len(spy.calls) == 1, 5, "both sends to be recorded")
        assert direct[-1] == (50, 1000) and spy.calls == [(1050, len(DATA) - 1050)]
    finally:
        server.stop()


def test_sendfile_chunk_slices_and_switch(
    spied: tuple[ThreadedServer, SendfileSpy], tree: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    server, spy = spied
    monkeypatch.setattr(respond, "SENDFILE_MIN", 1)
    listing = get_json(server.port, "/v1/scenes/clip/chunks?t=0&horizon=100")
    container = (tree / "clip.tsogs").read_bytes()
    for c in listing["chunks"]:
        r = fetch(server.port, c["url"])
        assert r.status == 200 and r.body == container[c["offset"] : c["offset"] + c["length"]]
        assert spy.calls[-1] == (c["offset"], c["length"])
    off = ThreadedServer(make_app(tree, limits=Limits(sendfile=False)))
    try:
        before = len(spy.calls)
        r = fetch(off.port, "/files/data.bin", headers={"Range": "bytes=10-"})
        assert r.body == DATA[10:] and len(spy.calls) == before
    finally:
        off.stop()


def test_single_file_root(tree: Path) -> None:
    server = ThreadedServer(make_app(tree / "clip.tsogs"))
    try:
        listing = get_json(server.port, "/v1/scenes")
        assert [s["id"] for s in listing["scenes"]] == ["clip"]
        whole = fetch(server.port, "/files/clip.tsogs")
        assert whole.status == 200 and whole.body == (tree / "clip.tsogs").read_bytes()
        assert fetch(server.port, "/v1/scenes/clip/manifest").status == 200
        chunks = get_json(server.port, "/v1/scenes/clip/chunks?t=0")["chunks"]
        assert chunks and fetch(server.port, chunks[0]["url"]).status == 200
        for path in ["/files/data.bin", "/files/sub/note.txt", "/v1/scenes/unpacked/manifest"]:
            assert fetch(server.port, path).status == 404
    finally:
        server.stop()
    other = ThreadedServer(make_app(tree / "data.bin"))
    try:
        assert fetch(other.port, "/files/data.bin").body == DATA
        assert get_json(other.port, "/v1/scenes") == {"scenes": []}
        assert fetch(other.port, "/files/clip.tsogs").status == 404
    finally:
        other.stop()


def test_other_methods_are_405_and_a_busy_port_is_one_line(
    tree: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    server = ThreadedServer(make_app(tree))
    try:
        for method in ("POST", "PUT", "DELETE", "PATCH", "CONNECT", "TRACE"):
            target = "127.0.0.1:443" if method == "CONNECT" else "/files/sub/note.txt"
            r = fetch(server.port, target, method=method)
            assert r.status == 405 and r.headers["Allow"] == "GET, HEAD, OPTIONS", method
        argv = ["serve", str(tree), "--port", str(server.port), "-q"]
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert f"port {server.port} is in use; try --port 0" in err and "Traceback" not in err
    finally:
        server.stop()
