"""The server on the wire: a table of requests for files and chunks with the exact answer of
each (status, headers, body), pipelined requests answered in order on one connection,
shutdown closing idle connections, and malformed request heads refused with 400 at once."""

from __future__ import annotations

import contextlib
import hashlib
import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import ThreadedServer, fetch
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.server.private import Privacy
from tsog_stream.synthetic import small_scene

DATA = bytes(range(256)) * 800  # 204 800 bytes
SECRET = b"0123456789abcdef0123456789abcdef"
ETAG = f'"{hashlib.sha256(DATA).hexdigest()}"'
SIZE = len(DATA)


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with a data file, an empty file, a private folder, a symlink and a container."""
    root = tmp_path_factory.mktemp("wire")
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


@pytest.fixture(scope="module")
def server(tree: Path) -> Iterator[ThreadedServer]:
    """The root served with ``paid/`` private."""
    srv = ThreadedServer(make_app(tree, privacy=Privacy(("paid",), SECRET)))
    try:
        yield srv
    finally:
        srv.stop()


WHOLE = slice(0, SIZE)
ANSWERS: list[tuple[str, dict[str, str], int, slice | None]] = [
    # path, request headers, status, the slice of DATA answered (None: no body)
    ("/files/data.bin", {}, 200, WHOLE),
    ("/files/data.bin", {"Range": "bytes=100-65635"}, 206, slice(100, 65636)),
    ("/files/data.bin", {"Range": "bytes=-4"}, 206, slice(SIZE - 4, SIZE)),
    ("/files/data.bin", {"Range": "bytes=200000-"}, 206, slice(200000, SIZE)),
    ("/files/data.bin", {"Range": "bytes=0-9999999"}, 206, WHOLE),
    ("/files/data.bin", {"Range": "bytes=999999-"}, 416, None),
    ("/files/data.bin", {"Range": "lines=1-2"}, 200, WHOLE),
    ("/files/data.bin", {"Range": "bytes=1-2", "If-Range": ETAG}, 206, slice(1, 3)),
    ("/files/data.bin", {"Range": "bytes=1-2", "If-Range": '"other"'}, 200, WHOLE),
    ("/files/data.bin", {"If-None-Match": ETAG}, 304, None),
    ("/files/data.bin", {"If-Match": '"other"'}, 412, None),
    ("/files/data.bin", {"If-Modified-Since": "Tue, 01 Jan 2999 00:00:00 GMT"}, 304, None),
    ("/files/data.bin", {"Accept-Encoding": "gzip", "User-Agent": "test"}, 200, WHOLE),
    ("/files/data.bin", {"X-Other": "1"}, 200, WHOLE),
    ("/files/data.bin?x=1", {"Range": "bytes=0-9"}, 206, slice(0, 10)),
    ("/files/link.bin", {"Range": "bytes=0-9"}, 206, slice(0, 10)),
]
"""Requests a player or a cache sends for a public file, and the exact answer to each."""


@pytest.mark.parametrize(("path", "headers", "status", "part"), ANSWERS)
def test_each_request_for_a_file_gets_its_exact_answer(
    server: ThreadedServer, path: str, headers: dict[str, str], status: int, part: slice | None
) -> None:
    r = fetch(server.port, path, headers=headers)
    body = b"" if part is None else DATA[part]
    assert (r.status, r.body) == (status, body)
    content_range = {416: f"bytes */{SIZE}"}.get(status)
    if status == 206 and part is not None:
        content_range = f"bytes {part.start}-{part.stop - 1}/{SIZE}"
    assert r.headers.get("Content-Range") == content_range
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    if status in (200, 206, 304):
        assert r.headers["ETag"] == ETAG and r.headers["Accept-Ranges"] == "bytes"
        assert r.headers["Cache-Control"] == "public, max-age=0, must-revalidate"
    if status in (200, 206):
        assert r.headers["Content-Type"] == "application/octet-stream"
        assert r.headers["Content-Length"] == str(len(body))


def test_an_empty_file_is_an_empty_200(server: ThreadedServer) -> None:
    r = fetch(server.port, "/files/empty.bin")
    assert (r.status, r.body, r.headers["Content-Length"]) == (200, b"", "0")
    assert r.headers["ETag"] == f'"{hashlib.sha256(b"").hexdigest()}"'


def test_several_ranges_come_as_multipart_byteranges(server: ThreadedServer) -> None:
    r = fetch(server.port, "/files/data.bin", headers={"Range": "bytes=0-0,5-9"})
    kind = r.headers["Content-Type"]
    assert r.status == 206 and kind.startswith("multipart/byteranges; boundary=")
    boundary = kind.split("boundary=")[1].encode()
    parts = r.body.split(b"--" + boundary)
    assert parts[-1] == b"--\r\n" and len(parts) == 4
    heads_bodies = [p.strip(b"\r\n").split(b"\r\n\r\n", 1) for p in parts[1:3]]
    assert [b for _, b in heads_bodies] == [DATA[0:1], DATA[5:10]]
    assert [f"bytes 0-0/{SIZE}", f"bytes 5-9/{SIZE}"] == [
        h.decode().split("Content-Range: ")[1] for h, _ in heads_bodies
    ]


@pytest.mark.parametrize(
    ("path", "status"),
    [
        ("/files/paid/show.bin", 403),
        ("/files/nothing.bin", 404),
        ("/files/../data.bin", 400),
        ("/files/%2e%2e/data.bin", 400),
        ("/v1/scenes/clip/chunks/999.sog", 404),
        ("/v1/scenes/nope/chunks/0.sog", 404),
        ("/v1/scenes/clip/chunks/0.sog?v=" + "0" * 64, 404),
    ],
)
def test_what_is_not_served_gets_a_json_error(
    server: ThreadedServer, path: str, status: int
) -> None:
    r = fetch(server.port, path)
    assert r.status == status
    assert json.loads(r.body)["error"]["status"] == status
    assert "ETag" not in r.headers


def test_chunks_are_slices_of_the_container(server: ThreadedServer, tree: Path) -> None:
    container = (tree / "clip.tsogs").read_bytes()
    listed = fetch(server.port, "/v1/scenes/clip/chunks?t=0&horizon=100")
    chunks = json.loads(listed.body)["chunks"]
    assert listed.status == 200 and len(chunks) >= 2
    for c in chunks:
        piece = container[c["offset"] : c["offset"] + c["length"]]
        versioned = fetch(server.port, c["url"])
        plain = fetch(server.port, f"/v1/scenes/clip/chunks/{c['id']}.sog")
        assert (versioned.status, versioned.body) == (200, piece)
        assert (plain.status, plain.body) == (200, piece)
        assert versioned.headers["ETag"] == plain.headers["ETag"] == f'"{c["sha256"]}"'
        assert versioned.headers["Cache-Control"] == "public, max-age=31536000, immutable"
        assert plain.headers["Cache-Control"] == "public, max-age=0, must-revalidate"
        assert plain.headers["Content-Type"] == "application/x-sog"
    ranged = fetch(server.port, "/v1/scenes/clip/chunks/1.sog", headers={"Range": "bytes=10-20"})
    start = chunks[1]["offset"]
    assert (ranged.status, ranged.body) == (206, container[start + 10 : start + 21])
    assert ranged.headers["Content-Range"] == f"bytes 10-20/{chunks[1]['length']}"


def test_a_connection_answers_pipelined_requests_in_order(server: ThreadedServer) -> None:
    """Four requests in one write, a 304 among them: four answers, in order, exact."""
    reqs = [
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=0-99\r\n\r\n",
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=100000-170000\r\n\r\n",
        f"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nIf-None-Match: {ETAG}\r\n\r\n",
        "GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes=5-9\r\n\r\n",
    ]
    answers = exchange(server.port, "".join(reqs).encode(), 4)
    assert answers == [(206, DATA[:100]), (206, DATA[100000:170001]), (304, b""), (206, DATA[5:10])]


def test_many_pipelined_requests_are_answered_in_order(server: ThreadedServer) -> None:
    """A burst of 1000 one-byte ranges in one write: each answer exact and in order."""
    offsets = [(k * 7919) % len(DATA) for k in range(1000)]
    raw = "".join(
        f"GET /files/data.bin HTTP/1.1\r\nHost: h\r\nRange: bytes={k}-{k}\r\n\r\n" for k in offsets
    )
    answers = exchange(server.port, raw.encode(), len(offsets))
    assert answers == [(206, DATA[k : k + 1]) for k in offsets]


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


def test_shutdown_closes_idle_connections(tree: Path) -> None:
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


HOSTILE_HEADS = {
    "bare LF": b"GET /files/data.bin HTTP/1.1\nHost: h\n\n",
    "bare LF, range": b"GET /files/data.bin HTTP/1.1\nHost: h\nRange: bytes=0-1\n\n",
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
9112 §2.2 allows reading a bare LF as a line end, but this server refuses it, as every other
shape here, with 400: a proxy in front must never read one message where we read another
(request smuggling, RFC 9112 §11.2)."""
ANSWER_BOUND_S = 3.0
"""A hostile head is answered and its connection closed within this (the keep-alive time the
server under test would otherwise wait is 15 s)."""


@pytest.mark.parametrize("shape", sorted(HOSTILE_HEADS))
def test_a_malformed_head_gets_400_at_once_and_a_closed_connection(
    server: ThreadedServer, shape: str
) -> None:
    status, seconds = answer_then_close(server.port, HOSTILE_HEADS[shape])
    assert status == 400 and seconds < ANSWER_BOUND_S, (shape, status, seconds)


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
