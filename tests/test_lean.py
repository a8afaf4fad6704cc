"""The lean path (server/lean.py): every request it answers gets the status, headers and body
the full aiohttp handler gives; everything else is handed to that handler, on the same
connection, with nothing lost or reordered."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from helpers import Resp, ThreadedServer, fetch, wait_until
from tsog_stream.container.ranges import ByteRange
from tsog_stream.model import TimelineType
from tsog_stream.segment.segmenter import SegmentOptions, segment_scene
from tsog_stream.server import Limits, lean, make_app, respond
from tsog_stream.server.lean import LeanSite, may_be_lean, parse_head
from tsog_stream.server.private import Privacy
from tsog_stream.synthetic import small_scene

DATA = bytes(range(256)) * 800  # 204 800 bytes
SECRET = b"0123456789abcdef0123456789abcdef"


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with a data file, a private folder, a symlink, a container and its unpacked form."""
    root = tmp_path_factory.mktemp("lean")
    (root / "data.bin").write_bytes(DATA)
    (root / "empty.bin").write_bytes(b"")
    (root / "paid").mkdir()
    (root / "paid" / "show.bin").write_bytes(b"paid content")
    (root / "link.bin").symlink_to(root / "data.bin")
    segment_scene(
        small_scene(TimelineType.CENTER_SCALE, sh_bands=0),
        root / "clip.tsogs",
        SegmentOptions(window_s=0.5),
    )
    return root


def _server(tree: Path, lean_on: bool) -> ThreadedServer:
    privacy = Privacy(("paid",), SECRET)
    return ThreadedServer(make_app(tree, limits=Limits(lean=lean_on), privacy=privacy))


@pytest.fixture(scope="module")
def both(tree: Path) -> Iterator[tuple[ThreadedServer, ThreadedServer]]:
    """The same root served with the lean path on, and with every request on the full path."""
    on, off = _server(tree, True), _server(tree, False)
    try:
        yield on, off
    finally:
        on.stop()
        off.stop()


def lean_of(server: ThreadedServer) -> lean.Lean:
    """The lean path of a running server."""
    site = next(iter(server.runner.sites))
    assert isinstance(site, LeanSite) and site.lean is not None
    return site.lean


def comparable(r: Resp) -> tuple[int, dict[str, str], bytes]:
    """Status, headers but Date (and a multipart boundary), body."""
    headers = {k: v for k, v in r.headers.items() if k != "Date"}
    body = r.body
    if headers.get("Content-Type", "").startswith("multipart/"):
        boundary = headers.pop("Content-Type").split("boundary=")[1]
        body = body.replace(boundary.encode(), b"B")
    return r.status, headers, body


def _etag() -> str:
    return f'"{hashlib.sha256(DATA).hexdigest()}"'


REQUESTS: list[tuple[str, dict[str, Any]]] = [
    ("/files/data.bin", {}),
    ("/files/data.bin", {"Range": "bytes=100-65635"}),
    ("/files/data.bin", {"Range": "bytes=-4"}),
    ("/files/data.bin", {"Range": "bytes=200000-"}),
    ("/files/data.bin", {"Range": "bytes=0-9999999"}),
    ("/files/data.bin", {"Range": "bytes=0-0,5-9"}),
    ("/files/data.bin", {"Range": "bytes=999999-"}),
    ("/files/data.bin", {"Range": "lines=1-2"}),
    ("/files/data.bin", {"Range": "bytes=1-2", "If-Range": "_etag"}),
    ("/files/data.bin", {"Range": "bytes=1-2", "If-Range": '"other"'}),
    ("/files/data.bin", {"If-None-Match": "_etag"}),
    ("/files/data.bin", {"If-Match": '"other"'}),
    ("/files/data.bin", {"If-Modified-Since": "Tue, 01 Jan 2999 00:00:00 GMT"}),
    ("/files/data.bin", {"Accept-Encoding": "gzip", "User-Agent": "test"}),
    ("/files/empty.bin", {}),
    ("/files/link.bin", {"Range": "bytes=0-9"}),
    ("/files/paid/show.bin", {}),
    ("/files/nothing.bin", {}),
    ("/files/../data.bin", {}),
    ("/files/data.bin?x=1", {"Range": "bytes=0-9"}),
    ("/files/data.bin", {"X-Other": "1"}),
    ("/v1/scenes/clip/chunks/0.sog", {}),
    ("/v1/scenes/clip/chunks/1.sog", {"Range": "bytes=10-20"}),
    ("/v1/scenes/clip/chunks/999.sog", {}),
    ("/v1/scenes/nope/chunks/0.sog", {}),
    ("/v1/scenes/clip/chunks/0.sog?v=" + "0" * 64, {}),
]


def test_every_answer_matches_the_full_handler(
    both: tuple[ThreadedServer, ThreadedServer],
) -> None:
    on, off = both
    listed = fetch(on.port, "/v1/scenes/clip/chunks?t=0&horizon=100")
    assert listed.status == 200
    urls = [c["url"] for c in json.loads(listed.body)["chunks"]]
    requests = REQUESTS + [(u, {}) for u in urls[:3]]
    before = lean_of(on).answered
    for path, given in requests:
        headers = {k: _etag() if v == "_etag" else v for k, v in given.items()}
        for _ in range(2):  # the first may teach the catalog (ETag, scene), the second is lean
            ours = fetch(on.port, path, headers=headers)
            full = fetch(off.port, path, headers=headers)
            assert comparable(ours) == comparable(full), (path, headers)
    answered = lean_of(on).answered - before
    assert answered >= 20  # most of the above were answered on the lean path
    assert not any(isinstance(site, LeanSite) for site in off.runner.sites)


def test_a_connection_keeps_its_order_across_the_hand_over(
    both: tuple[ThreadedServer, ThreadedServer],
) -> None:
    """Pipelined on one connection: lean, lean, one the full handler must answer (If-None-Match
    gives 304), then one the lean path could have answered: four answers, in order, exact."""
    on, _ = both
    fetch(on.port, "/files/data.bin", headers={"Range": "bytes=0-0"})  # the ETag is known
    reqs = [
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=0-99\r\n\r\n",
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=100000-170000\r\n\r\n",
        f"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nIf-None-Match: {_etag()}\r\n\r\n",
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=5-9\r\n\r\n",
    ]
    answers = exchange(on.port, "".join(reqs).encode(), 4)
    assert [a[0] for a in answers] == [206, 206, 304, 206]
    assert answers[0][1] == DATA[:100] and answers[1][1] == DATA[100000:170001]
    assert answers[2][1] == b"" and answers[3][1] == DATA[5:10]


def test_many_pipelined_requests_are_answered_in_order(
    both: tuple[ThreadedServer, ThreadedServer],
) -> None:
    """A burst of 2000 one-byte ranges in one write: each answer exact and in order (the
    buffer drops answered heads without copying the rest)."""
    on, _ = both
    fetch(on.port, "/files/data.bin", headers={"Range": "bytes=0-0"})
    offsets = [(k * 7919) % len(DATA) for k in range(2000)]
    raw = "".join(
        f"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes={k}-{k}\r\n\r\n" for k in offsets
    )
    answers = exchange(on.port, raw.encode(), len(offsets))
    assert [a for a in answers] == [(206, DATA[k : k + 1]) for k in offsets]


def exchange(port: int, raw: bytes, count: int) -> list[tuple[int, bytes]]:
    """Send ``raw`` on one connection and read ``count`` responses (status, body)."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(raw)
        data, answers = b"", list[tuple[int, bytes]]()
        while len(answers) < count:
            end = data.find(b"\r\n\r\n")
            if end >= 0:
                head = data[:end].decode("latin-1").split("\r\n")
                fields = dict(line.split(": ", 1) for line in head[1:])
                length = int(fields.get("Content-Length", "0"))
                if len(data) >= end + 4 + length:
                    answers.append((int(head[0].split()[1]), data[end + 4 : end + 4 + length]))
                    data = data[end + 4 + length :]
                    continue
            block = sock.recv(1 << 20)
            assert block, f"closed after {len(answers)} answers"
            data += block
    return answers


def test_what_the_socket_does_not_take_at_once_goes_out_by_the_loop(
    tree: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = respond.sendfile_now
    direct: list[int] = []

    def limited(transport: Any, fd: int, span: ByteRange) -> int:
        sent = real(transport, fd, ByteRange.sized(span.start, min(span.length, 1000)))
        direct.append(sent)
        return sent

    monkeypatch.setattr(lean, "sendfile_now", limited)
    server = _server(tree, True)
    try:
        for _ in range(2):
            r = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=50-"})
            assert r.status == 206 and r.body == DATA[50:]
        wait_until(lambda: lean_of(server).answered == 2, 5, "both lean answers to be counted")
        assert direct == [1000, 1000]
    finally:
        server.stop()


def test_the_access_log_line_is_the_full_handlers(
    both: tuple[ThreadedServer, ThreadedServer], caplog: pytest.LogCaptureFixture
) -> None:
    on, off = both
    headers = {"Range": "bytes=10-19", "User-Agent": "probe"}
    fetch(on.port, "/files/data.bin", headers=headers)
    with caplog.at_level(logging.INFO, logger="aiohttp.access"):
        for server in (on, off):
            fetch(server.port, "/files/data.bin", headers=headers)
        wait_until(lambda: len(caplog.records) >= 2, 5, "two access-log lines")
    lines = [r.getMessage().split(" bytes ")[0] for r in caplog.records[:2]]
    assert lines[0] == lines[1]  # bytes counted alike (head and body)
    assert lines[0].startswith('127.0.0.1 "GET /files/data.bin HTTP/1.1" 206 ')


def test_an_idle_connection_closes_after_the_keepalive_time(tree: Path) -> None:
    server = ThreadedServer(make_app(tree, limits=Limits(keepalive_s=0.3)))
    try:
        fetch(server.port, "/files/data.bin", headers={"Range": "bytes=0-0"})
        with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
            sock.sendall(b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=0-0\r\n\r\n")
            start = time.monotonic()
            data = b""
            while block := sock.recv(65536):
                data += block
            assert data.startswith(b"HTTP/1.1 206 ") and data.endswith(b"\r\n\r\n\x00")
            assert 0.2 < time.monotonic() - start < 3
    finally:
        server.stop()


def test_shutdown_closes_idle_lean_connections(tree: Path) -> None:
    server = ThreadedServer(make_app(tree))
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        sock.sendall(b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=0-0\r\n\r\n")
        data = b""
        while b"\r\n\r\n\x00" not in data:
            data += sock.recv(65536)
        assert data.startswith(b"HTTP/1.1 206 ")
        server.stop()
        sock.settimeout(5)
        assert sock.recv(65536) == b""


@pytest.mark.parametrize(
    ("raw", "lean_head"),
    [
        (b"GET /files/a HTTP/1.1\r\nHost: h", True),
        (b"GET /files/a HTTP/1.1\r\nhost: h\r\nrange: bytes=0-1", True),
        (b"GET /files/a HTTP/1.0\r\nHost: h", False),
        (b"HEAD /files/a HTTP/1.1\r\nHost: h", False),
        (b"GET /files/a HTTP/1.1", False),  # no Host
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\nHost: h", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\nContent-Length: 0", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\nTransfer-Encoding: chunked", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\nConnection: close", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\n folded", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\x00", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\nRange: bytes=0-1", False),
        (b"GET /files/\xc3\xa9 HTTP/1.1\r\nHost: h", False),
        (b"GET  /files/a HTTP/1.1\r\nHost: h", False),
    ],
)
def test_only_plain_heads_are_lean(raw: bytes, lean_head: bool) -> None:
    assert (parse_head(raw) is not None) is lean_head


@pytest.mark.parametrize(
    ("start", "maybe"),
    [
        (b"G", True),
        (b"GET /files/a", True),
        (b"GET /files/a HTTP/1.1\r\nHo", True),
        (b"POST /files/a", False),
        (b"\x16\x03\x01\x00", False),
        (b"GET /files/a HTTP/1.0\r\n", False),
        (b"GET /" + b"a" * 9000, False),
        (b"GET /files/a HTTP/1.1\r", True),  # its LF may come in the next packet
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\nRange: bytes=0-1\r\nIf-", True),
        (b"GET /files/a HTTP/1.1\nHo", False),  # a bare LF
        (b"GET /files/a HTTP/1.1\r\nHost: h\n", False),
        (b"GET /files/a HTTP/1.1\rHo", False),  # a bare CR
        (b"GET /files/a\x00", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\x7f", False),
        (b"GET /files/a HTTP/1.1\r\nHost: \xc3\xa9", False),
        (b"GET /files/a HTTP/1.1\r\nHost: h\r\n\tfolded", False),  # obs-fold
        (b"GET /files/a HTTP/1.1\r\nX-Other: 1\r\n", False),  # a field it never takes
        (b"GET /files/a HTTP/1.1\r\nHost h\r\n", False),  # no colon
        (b"GET /files/a HTTP/1.1\r\n" + b"Accept: a\r\n" * 25, False),  # more than a head
    ],
)
def test_other_requests_go_to_the_full_handler_at_once(start: bytes, maybe: bool) -> None:
    assert may_be_lean(start) is maybe


HOSTILE_HEADS = {
    "bare LF": b"GET /files/data.bin HTTP/1.1\nHost: h\n\n",
    "bare LF, lean fields": b"GET /files/data.bin HTTP/1.1\nHost: h\nRange: bytes=0-1\n\n",
    "bare CR": b"GET /files/data.bin HTTP/1.1\rHost: h\r\r",
    "bare CR, cut short": b"GET /files/data.bin HTTP/1.1\rHost: h",
    "CRLF and LF mixed": b"GET /files/data.bin HTTP/1.1\r\nHost: h\nRange: bytes=0-1\r\n\r\n",
    "CRLF and LF mixed, LF CRLF end": b"GET /files/data.bin HTTP/1.1\r\nHost: h\n\r\n",
    "NUL in a field": b"GET /files/data.bin HTTP/1.1\r\nHost: h\x00x\r\n\r\n",
    "NUL in the target, cut short": b"GET /files/da\x00ta.bin HTTP/1.1\r\nHost: h\r\n",
    "control byte, cut short": b"GET /files/data.bin HTTP/1.1\r\nHost: h\x01",
    "obs-fold": b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\n folded\r\n\r\n",
    "obs-fold, cut short": b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\n\tfolded",
    "a field over the limit, never ending": (
        b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=0-" + b"0" * 9000
    ),
    "too many fields, never ending": (
        b"GET /files/data.bin HTTP/1.1\r\nHost: h\r\n" + b"X-n: y\r\n" * 200
    ),
}
"""Heads no server may take as they are, whole or cut short (the client then waits): RFC
9112 §2.2 allows reading a bare LF as a line end, but both paths refuse it, as every other
shape here, with 400 (server/lean.py, ``_NEVER_LEAN``)."""
ANSWER_BOUND_S = 3.0
"""A hostile head is answered and its connection closed within this (the keep-alive time the
servers under test would otherwise wait is 15 s)."""


@pytest.mark.parametrize("path", ["lean", "full"])
@pytest.mark.parametrize("shape", sorted(HOSTILE_HEADS))
def test_a_malformed_head_gets_400_at_once_and_a_closed_connection(
    both: tuple[ThreadedServer, ThreadedServer], shape: str, path: str
) -> None:
    server = both[0] if path == "lean" else both[1]
    status, seconds = answer_then_close(server.port, HOSTILE_HEADS[shape])
    assert status == 400 and seconds < ANSWER_BOUND_S, (shape, path, status, seconds)


def answer_then_close(port: int, raw: bytes) -> tuple[int, float]:
    """Send ``raw`` on a new connection; the status answered and the seconds until the server
    closed the connection (a socket timeout past ANSWER_BOUND_S fails the test)."""
    with socket.create_connection(("127.0.0.1", port), timeout=ANSWER_BOUND_S * 2) as sock:
        start = time.monotonic()
        with contextlib.suppress(OSError):  # refused before all was sent: still answered
            sock.sendall(raw)
        data = b""
        try:
            while block := sock.recv(65536):
                data += block
        except ConnectionResetError:
            pass  # closed with unread bytes of ours in its buffer: still closed
        except TimeoutError:
            pass  # never closed: the bound below fails
        seconds = time.monotonic() - start
    status_line = data.split(b"\r\n", 1)[0].split()
    assert len(status_line) >= 2, f"no answer, closed after {seconds:.2f} s"
    return int(status_line[1]), seconds
