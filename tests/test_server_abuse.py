"""Abusive clients against a real server on 127.0.0.1: every loop bounded in count and time."""

from __future__ import annotations

import contextlib
import http.client
import logging
import select
import socket
import struct
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from helpers import ThreadedServer, fetch
from serve_process import Served, tsog_serve
from tsog_stream.container.stream_index import StreamIndex
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import Limits, make_app
from tsog_stream.server import catalog as catalog_module
from tsog_stream.synthetic import small_scene

DATA = bytes(range(256)) * 1024  # 256 KiB
BIG = 64 * 1024 * 1024  # larger than any loopback socket buffers


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with a small and a big file."""
    base = tmp_path_factory.mktemp("abuse")
    (base / "data.bin").write_bytes(DATA)
    with open(base / "big.bin", "wb") as f:
        f.truncate(BIG)
    return base


@pytest.fixture
def server(root: Path) -> Iterator[ThreadedServer]:
    """A server with small limits."""
    srv = ThreadedServer(make_app(root, limits=Limits(keepalive_s=0.6, send_timeout_s=0.5)))
    try:
        yield srv
    finally:
        srv.stop()


def get(port: int, path: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    """Status and body of one request over a fresh connection."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path, headers=headers or {})
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


def closed_by_peer(sock: socket.socket, wait: float) -> bool:
    """True if the peer closed ``sock`` (EOF or reset) within ``wait`` s (reads drained)."""
    deadline = time.monotonic() + wait
    for _ in range(100_000):
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        if not select.select([sock], [], [], left)[0]:
            return False
        try:
            if not sock.recv(1 << 20):
                return True
        except (ConnectionResetError, BrokenPipeError):
            return True
    return False


def connect(port: int, rcvbuf: int | None = None) -> socket.socket:
    """A raw TCP connection to the server."""
    sock = socket.socket()
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.settimeout(5)
    sock.connect(("127.0.0.1", port))
    return sock


def test_slow_loris_is_disconnected(server: ThreadedServer) -> None:
    request = b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 40 + b"\r\n\r\n"
    sock = connect(server.port)
    start, closed = time.monotonic(), False
    try:
        for i, byte in enumerate(request[:30]):  # 30 bytes x 0.2 s = 6 s at most
            try:
                sock.sendall(bytes([byte]))
            except (BrokenPipeError, ConnectionResetError):
                closed = True
                break
            if i == 2:
                assert get(server.port, "/healthz")[0] == 200  # others are served meanwhile
            if closed_by_peer(sock, 0.2):
                closed = True
                break
    finally:
        sock.close()
    assert closed and time.monotonic() - start < 3.0
    assert get(server.port, "/healthz")[0] == 200


def test_idle_keepalive_is_closed(server: ThreadedServer) -> None:
    sock = connect(server.port)
    try:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        start = time.monotonic()
        reply = b""
        for _ in range(100):
            if b'"ok"' in reply:
                break
            reply += sock.recv(65536)
        assert reply.startswith(b"HTTP/1.1 200") and b"keep-alive" not in reply.lower()
        assert closed_by_peer(sock, 5.0)
        assert 0.4 < time.monotonic() - start < 3.0
    finally:
        sock.close()


@pytest.mark.parametrize("sendfile", [True, False])
def test_stalled_reader_is_cut_off(root: Path, sendfile: bool) -> None:
    limits = Limits(keepalive_s=5, send_timeout_s=0.5, sendfile=sendfile)
    srv = ThreadedServer(make_app(root, limits=limits))
    sock = connect(srv.port, rcvbuf=4096)
    try:
        sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        time.sleep(1.5)  # never read while the deadline passes
        assert get(srv.port, "/files/data.bin") == (200, DATA)  # the server stays responsive
        received = 0
        deadline = time.monotonic() + 10
        for _ in range(100_000):
            assert time.monotonic() < deadline
            try:
                block = sock.recv(1 << 20)
            except ConnectionResetError:
                break
            if not block:
                break
            received += len(block)
        assert received < BIG  # cut off, not the whole body
    finally:
        sock.close()
        srv.stop()


@pytest.mark.parametrize(
    "value",
    [
        "bytes=" + ",".join(f"{i}-{i}" for i in range(0, 4000, 2)),  # thousands of ranges
        "bytes=" + ",".join(["0-"] * 1000),
        "bytes=" + "9" * 4000 + "-",  # a huge number
        "bytes=0-" + "9" * 4000,
        "bytes=-" + "9" * 4000,
        "bytes=" + "1" * 8000,  # near the field limit
        "bytes=" + "0-1," * 4000,  # over the 8190-byte field limit
        "bytes=" + " " * 5000 + "0-1",
    ],
)
def test_hostile_ranges_are_bounded(server: ThreadedServer, value: str) -> None:
    start = time.monotonic()
    status, body = get(server.port, "/files/data.bin", {"Range": value})
    assert status in (200, 206, 400, 416)
    if status == 200:
        assert body == DATA
    assert time.monotonic() - start < 2.0
    assert get(server.port, "/healthz")[0] == 200


def test_access_log_counts_bytes(server: ThreadedServer, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="aiohttp.access"):
        assert get(server.port, "/files/data.bin", {"Range": "bytes=0-99999"})[0] == 206
        assert get(server.port, "/files/data.bin", {"Range": "bytes=0-9"})[0] == 206
        for _ in range(50):  # the line is written just after the body
            if len([r for r in caplog.records if r.name == "aiohttp.access"]) >= 2:
                break
            time.sleep(0.05)
    lines = [r.getMessage() for r in caplog.records if r.name == "aiohttp.access"]
    assert len(lines) >= 2
    sizes = [int(line.split('" ')[1].split()[1]) for line in lines[:2]]
    assert 100_000 <= sizes[0] < 100_000 + 1024  # body plus the header block
    assert 10 <= sizes[1] < 10 + 1024
    assert '"bytes=0-99999"' in lines[0] and " bytes " in lines[0]


# --- The abuse table of docs/http.md, against `tsog serve` as a real process --------------
#
# Each case is sent many times on raw sockets while a bystander keeps fetching a range and
# checking its bytes; afterwards the server's RSS growth, CPU time and open fds are checked
# from /proc and its stderr must hold no traceback (a 500 or an unhandled error would).

SLICE = (1000, 2000)
CVE_2011_3192 = "bytes=0-," + ",".join(f"5-{k}" for k in range(1300))


@pytest.fixture(scope="module")
def served(root: Path) -> Iterator[Served]:
    """`tsog serve` with 1 s keep-alive and send deadline, so stalled clients go quickly."""
    with tsog_serve(root, "--keepalive", "1", "--send-timeout", "1") as srv:
        yield srv
        assert "Traceback" not in srv.stderr() and "Error handling" not in srv.stderr()


class Bystander:
    """A well-behaved client in a thread: keep-alive range GETs, every body checked."""

    def __init__(self, port: int) -> None:
        self.port, self.ok = port, 0
        self.bad: list[object] = []  # (status, length) of a wrong answer, or an exception
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        a, b = SLICE
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=10)
        deadline = time.monotonic() + 60
        for _ in range(100_000):
            if self.stop.is_set() or time.monotonic() > deadline:
                break
            try:
                conn.request("GET", "/files/data.bin", headers={"Range": f"bytes={a}-{b - 1}"})
                r = conn.getresponse()
                body = r.read()
                if (r.status, body) == (206, DATA[a:b]):
                    self.ok += 1
                else:
                    self.bad.append((r.status, len(body)))
                time.sleep(0.01)  # a player's pace, so the abuse dominates the server's CPU
            except (OSError, http.client.HTTPException) as exc:
                self.bad.append(repr(exc))
                conn.close()  # a keep-alive connection closed by the 1 s idle timeout
                conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=10)
        conn.close()

    def __enter__(self) -> Bystander:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(15)
        assert not self.thread.is_alive()


@contextlib.contextmanager
def under_abuse(srv: Served, max_rss_mib: float = 50.0) -> Iterator[Bystander]:
    """Run the body beside a bystander; then check the bystander, RSS and open fds."""
    rss0, fds0 = srv.rss_mib(), srv.open_fds()
    with Bystander(srv.port) as bystander:
        yield bystander
        for _ in range(200):  # at least a few bystander rounds during the abuse
            if bystander.ok >= 3:
                break
            time.sleep(0.05)
    # the idle timeout (1 s) may close the bystander's connection once: one reconnect allowed
    assert bystander.ok >= 3 and len([b for b in bystander.bad if isinstance(b, tuple)]) == 0
    assert len(bystander.bad) <= 2, bystander.bad[:5]
    assert srv.rss_mib() - rss0 < max_rss_mib
    for _ in range(100):  # connections of the abuse are closed within a few seconds
        if srv.open_fds() <= fds0 + 2:
            break
        time.sleep(0.05)
    assert srv.open_fds() <= fds0 + 2


def exchange(port: int, raw: bytes, watch_close: bool) -> tuple[int, bytes, bool]:
    """Send raw bytes; the first response's status and body, and whether the server closed
    the connection right after it (watched 0.8 s if asked, under the 1 s idle timeout)."""
    sock = connect(port)
    try:
        sock.sendall(raw)
        data, closed = b"", False
        deadline = time.monotonic() + 10
        while b"\r\n\r\n" not in data and not closed and time.monotonic() < deadline:
            block = sock.recv(1 << 16)
            closed, data = not block, data + block
        head, _, body = data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        fields = {k.lower(): v.strip() for k, _, v in (x.partition(":") for x in lines[1:])}
        length = int(fields.get("content-length", "0"))
        while len(body) < length and not closed and time.monotonic() < deadline:
            block = sock.recv(1 << 20)
            closed, body = not block, body + block
        closed = closed or (watch_close and closed_by_peer(sock, 0.8))
        return int(lines[0].split()[1]), body[:length], closed
    finally:
        sock.close()


def req(range_value: str | bytes | None = None, extra: bytes = b"", line: bytes = b"") -> bytes:
    """A raw GET of data.bin with an optional Range value (sent as given) and header lines."""
    head = line or b"GET /files/data.bin HTTP/1.1"
    value = range_value.encode() if isinstance(range_value, str) else range_value
    rng = b"Range: " + value + b"\r\n" if value is not None else b""
    return head + b"\r\nHost: 127.0.0.1\r\n" + rng + extra + b"\r\n"


N = len(DATA)
HUGE = "9" * 4000
# raw request, expected status, expected body (None: any), closed after the answer
ABUSE = [
    pytest.param(
        req("bytes=" + ",".join(f"{i}-{i}" for i in range(0, 1800, 2))),
        200,
        DATA,
        False,
        id="900 disjoint ranges",
    ),
    pytest.param(req("bytes=" + ",".join(["0-0"] * 2000)), 200, DATA, False, id="2000 ranges"),
    pytest.param(
        req(CVE_2011_3192, b"Accept-Encoding: gzip\r\n"), 200, DATA, False, id="CVE-2011-3192"
    ),
    pytest.param(req("bytes=" + ",".join(["0-"] * 32)), 206, DATA, False, id="32 x whole"),
    pytest.param(
        req("bytes=" + ",".join(f"{i}-{i + 9999}" for i in range(32))),
        206,
        DATA[:10031],
        False,
        id="32 overlapping",
    ),
    pytest.param(
        req("bytes=" + ",".join(f"{i}-{i + 9999}" for i in range(33))),
        200,
        DATA,
        False,
        id="33 overlapping",
    ),
    pytest.param(req("bytes=18446744073709551616-"), 416, b"", False, id="start 2^64"),
    pytest.param(req("bytes=0-18446744073709551616"), 206, DATA, False, id="end 2^64"),
    pytest.param(req("bytes=-18446744073709551617"), 206, DATA, False, id="suffix 2^64+1"),
    pytest.param(req(f"bytes={HUGE}-"), 416, b"", False, id="start 4000 digits"),
    pytest.param(req(f"bytes=0-{HUGE}"), 206, DATA, False, id="end 4000 digits"),
    pytest.param(req(f"bytes=-{HUGE}"), 206, DATA, False, id="suffix 4000 digits"),
    pytest.param(req(f"bytes={N}-{N + 10**6}"), 416, b"", False, id="past the end"),
    pytest.param(
        req(f"bytes={N - 2}-{10**12},{10**9}-"), 206, DATA[-2:], False, id="past the end, clipped"
    ),
    pytest.param(req("bytes=5-2"), 200, DATA, False, id="last < first"),
    pytest.param(req("bytes=abc"), 200, DATA, False, id="not numbers"),
    pytest.param(req("bytes==0-1"), 200, DATA, False, id="double ="),
    pytest.param(req("bytes=0-1-2"), 200, DATA, False, id="two dashes"),
    pytest.param(req("bytes=0x10-0x20"), 200, DATA, False, id="hex"),
    pytest.param(req("bytes=--1"), 200, DATA, False, id="negative"),
    pytest.param(req("bits=0-1"), 200, DATA, False, id="other unit"),
    pytest.param(req("bytes= , ,"), 200, DATA, False, id="empty list"),
    pytest.param(req(b"bytes=\xd9\xa1-\xd9\xa3"), 200, DATA, False, id="arabic digits"),
    pytest.param(req(b"bytes=\xef\xbc\x90-\xef\xbc\x91"), 200, DATA, False, id="fullwidth digits"),
    pytest.param(req(b"bytes=0-1\xff"), 200, DATA, False, id="latin-1 byte"),
    pytest.param(req(b"bytes=0-1\x01"), 400, None, True, id="control byte"),
    pytest.param(req(b"bytes=0\x00-1"), 400, None, True, id="NUL byte"),
    pytest.param(
        req("bytes=0-1", b"Range: bytes=5-6\r\n"), 200, DATA, False, id="two Range fields"
    ),
    pytest.param(req("bytes=" + "0-1," * 2100), 400, None, True, id="Range over 8190 bytes"),
    pytest.param(
        req(None, b"X-Big: " + b"a" * 9000 + b"\r\n"), 400, None, True, id="field over 8190 bytes"
    ),
    pytest.param(
        req(None, b"".join(b"X-%d: y\r\n" % i for i in range(200))),
        400,
        None,
        True,
        id="200 fields",
    ),
    pytest.param(
        req(None, line=b"GET /files/data.bin?" + b"a" * 9000 + b" HTTP/1.1"),
        400,
        None,
        True,
        id="request line over 8190 bytes",
    ),
    pytest.param(
        req(None, line=b"GET /files/" + b"a" * 9000 + b" HTTP/1.1"),
        400,
        None,
        True,
        id="path over 8190 bytes",
    ),
    pytest.param(
        b"GET /files/data.bin HTTP/1.0\r\nRange: bytes=0-9\r\n\r\n",
        206,
        DATA[:10],
        True,
        id="HTTP/1.0",
    ),
    pytest.param(b"GET /files/data.bin\r\n\r\n", 505, None, True, id="HTTP/0.9"),
    pytest.param(
        req(None, line=b"GET /files/data.bin HTTP/2.0"), 505, None, True, id="HTTP/2.0 line"
    ),
    pytest.param(req(None, line=b"G@T /files/data.bin HTTP/1.1"), 400, None, True, id="bad method"),
    pytest.param(
        b"\x16\x03\x01\x00\xa5\x01\x00\x00\xa1\x03\x03" + bytes(64), 400, None, True, id="TLS hello"
    ),
    pytest.param(
        req(None, b"Content-Length: 99999999999999999999999\r\n"),
        400,
        None,
        True,
        id="huge Content-Length",
    ),
    pytest.param(
        req(None, b"Content-Length: 3\r\nTransfer-Encoding: chunked\r\n"),
        400,
        None,
        True,
        id="CL and TE",
    ),
    pytest.param(b"GET /files/data.bin HTTP/1.1\r\n\r\n", 400, None, True, id="no Host"),
    pytest.param(req("bytes=0-1,", b" 3-4\r\n"), 400, None, True, id="obsolete line folding"),
]
REPEAT = 20


@pytest.mark.parametrize(("raw", "status", "body", "closes"), ABUSE)
def test_abuse_table(
    served: Served, raw: bytes, status: int, body: bytes | None, closes: bool
) -> None:
    cpu0 = served.cpu_s()
    with under_abuse(served):
        for _ in range(REPEAT):
            got_status, got_body, closed = exchange(served.port, raw, closes)
            assert got_status == status
            if body is not None:
                assert got_body == body
            if closes:
                assert closed
    assert served.cpu_s() - cpu0 < REPEAT * 0.25  # generous: a few ms each in fact


def test_pipelined_requests(served: Served) -> None:
    a, b = SLICE
    one = req(f"bytes={a}-{b - 1}")
    raw = one * 3 + req(None, line=b"GET /healthz HTTP/1.1")[:-2] + b"Connection: close\r\n\r\n"
    with under_abuse(served):
        sock = connect(served.port)
        try:
            sock.sendall(raw)
            data = b""
            for _ in range(1000):
                block = sock.recv(1 << 16)
                if not block:
                    break
                data += block
        finally:
            sock.close()
    parts = data.split(b"HTTP/1.1 ")[1:]
    assert [p[:3] for p in parts] == [b"206", b"206", b"206", b"200"]
    assert all(p.split(b"\r\n\r\n", 1)[1] == DATA[a:b] for p in parts[:3])
    assert parts[3].endswith(b'{"status": "ok"}')


@pytest.mark.slow
def test_many_slow_loris_connections(served: Served) -> None:
    """100 clients trickle a request head byte by byte: all cut at the 1 s head timeout."""
    head = b"GET /files/data.bin HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 100
    socks = [connect(served.port) for _ in range(100)]
    cut = set()
    try:
        with under_abuse(served):
            for k in range(30):  # 30 rounds x 0.1 s: well past the timeout
                for i, sock in enumerate(socks):
                    if i in cut:
                        continue
                    try:
                        sock.sendall(head[k : k + 1])
                    except OSError:
                        cut.add(i)
                time.sleep(0.1)
            for i, sock in enumerate(socks):
                if i not in cut and closed_by_peer(sock, 2.0):
                    cut.add(i)
    finally:
        for sock in socks:
            sock.close()
    assert len(cut) == len(socks)


@pytest.mark.slow
def test_many_clients_that_never_read(served: Served) -> None:
    """20 clients ask for 64 MiB and never read: the server buffers little and drops them."""
    socks = [connect(served.port, rcvbuf=4096) for _ in range(20)]
    try:
        with under_abuse(served, max_rss_mib=50.0):
            for sock in socks:
                sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            time.sleep(2.5)  # past the 1 s send deadline
            received = []
            for sock in socks:
                total = 0
                for _ in range(10_000):
                    try:
                        block = sock.recv(1 << 20)
                    except (ConnectionResetError, TimeoutError):
                        break
                    if not block:
                        break
                    total += len(block)
                received.append(total)
    finally:
        for sock in socks:
            sock.close()
    assert max(received) < BIG


@pytest.mark.slow
def test_clients_that_never_read_cannot_stall_the_server(root: Path) -> None:
    """Issue 15's attack: far more non-reading clients than request slots, all asking for a
    big file. The server keeps answering /healthz and other clients at once, and drops the
    stalled ones at the stall timeout, long before the whole-body deadline."""
    options = ("--max-concurrent", "16", "--max-per-client", "4", "--stall-timeout", "1")
    with tsog_serve(root, *options, "--send-timeout", "60", "--keepalive", "30") as srv:
        socks = [connect(srv.port, rcvbuf=4096) for _ in range(40)]
        try:
            began = time.monotonic()
            for sock in socks:
                sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            time.sleep(0.3)  # every request is in: the attacker's share taken, the rest refused
            for _ in range(5):
                assert fetch(srv.port, "/healthz").status == 200
                other = fetch(srv.port, "/files/data.bin", source="127.0.0.2")
                assert (other.status, other.body) == (200, DATA)
            assert time.monotonic() - began < 3
            statuses = [sock.recv(12)[9:12] for sock in socks]  # a few bytes: still stalled
            assert statuses.count(b"200") <= 8 and set(statuses) <= {b"200", b"503"}
            time.sleep(2.0)  # reading nothing more, past the 1 s stall timeout
            served = [
                sock for sock, status in zip(socks, statuses, strict=True) if status == b"200"
            ]
            assert served and all(closed_by_peer(sock, 2.0) for sock in served)
            assert time.monotonic() - began < 15
        finally:
            for sock in socks:
                sock.close()
        assert "Traceback" not in srv.stderr()


@pytest.mark.slow
def test_many_abandoned_connections(served: Served) -> None:
    """Connections opened and dropped in every way leave no fd and no memory behind."""
    held: list[socket.socket] = []
    try:
        with under_abuse(served):
            for _ in range(300):  # connect and close at once
                connect(served.port).close()
            for i in range(200):  # half a request, then a reset (SO_LINGER 0)
                sock = connect(served.port)
                sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHo" if i % 2 else b"GET /fi")
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                sock.close()
            for _ in range(100):  # a whole request, then a reset mid-body
                sock = connect(served.port, rcvbuf=4096)
                sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                sock.recv(100)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                sock.close()
            held = [connect(served.port) for _ in range(300)]  # open, idle, never closed
            assert get(served.port, "/files/data.bin") == (200, DATA)
            time.sleep(1.5)  # past the idle timeout: the server closed them all
            assert all(closed_by_peer(sock, 2.0) for sock in held)
    finally:
        for sock in held:
            sock.close()


@pytest.mark.slow
def test_symlink_aliases_do_not_grow_the_scene_cache(tmp_path: Path) -> None:
    """``alias -> .`` makes endless ids for one scene; they share one cache entry (this grew
    the server by ~30 kB per id, without bound, before the fix)."""
    segment_scene(
        small_scene(TimelineType.CENTER_SCALE, sh_bands=0),
        tmp_path / "clip.tsogs",
        SegmentOptions(window_s=0.5),
    )
    (tmp_path / "alias").symlink_to(".")
    with tsog_serve(tmp_path) as srv:
        conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=10)
        try:
            conn.request("GET", "/v1/scenes/clip/manifest")
            manifest = conn.getresponse().read()
            rss0 = srv.rss_mib()
            for depth in range(1, 1001):
                conn.request("GET", "/v1/scenes/" + "alias/" * depth + "clip/manifest")
                r = conn.getresponse()
                assert (r.status, r.read()) == (200, manifest)
        finally:
            conn.close()
        assert srv.rss_mib() - rss0 < 10


def test_cold_etag_is_computed_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """40 clients asking at once for a file not yet hashed cost one hash, not 40 full reads."""
    calls: list[Path] = []
    real = catalog_module._content_etag

    def slow_etag(root: Path, path: Path) -> str:
        calls.append(path)
        time.sleep(0.5)  # every request arrives while the first hash runs
        return real(root, path)

    monkeypatch.setattr(catalog_module, "_content_etag", slow_etag)
    (tmp_path / "fresh.bin").write_bytes(DATA)
    srv = ThreadedServer(make_app(tmp_path))
    try:
        with ThreadPoolExecutor(40) as pool:
            answers = list(pool.map(lambda _: get(srv.port, "/files/fresh.bin"), range(40)))
    finally:
        srv.stop()
    assert answers == [(200, DATA)] * 40
    assert len(calls) == 1


def test_cold_scene_is_opened_once_off_the_event_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """40 first requests for a scene at once cost one opening, read through the async reader
    and described (manifest JSON, Gaussians per frame) in a worker thread: meanwhile the event
    loop answers /healthz at once."""
    calls: list[str] = []
    real = catalog_module._describe

    def slow_describe(index: StreamIndex, manifest_json: bytes | None) -> tuple[bytes, int]:
        calls.append(threading.current_thread().name)
        time.sleep(1.0)  # a big index: every request arrives while it is described
        return real(index, manifest_json)

    monkeypatch.setattr(catalog_module, "_describe", slow_describe)
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0)
    segment_scene(scene, tmp_path / "clip.tsogs", SegmentOptions(window_s=0.5))
    srv = ThreadedServer(make_app(tmp_path))
    try:
        with ThreadPoolExecutor(40) as pool:
            pending = [pool.submit(get, srv.port, "/v1/scenes/clip/manifest") for _ in range(40)]
            time.sleep(0.3)
            began = time.monotonic()
            assert get(srv.port, "/healthz")[0] == 200
            assert time.monotonic() - began < 0.5  # not behind the opening
            answers = [p.result()[0] for p in pending]
    finally:
        srv.stop()
    assert answers == [200] * 40
    assert len(calls) == 1 and calls[0] != srv.thread.name  # a worker, not the loop


@pytest.mark.slow
def test_connection_flood_past_the_file_limit(root: Path) -> None:
    """More connections than the server may open files: it keeps running, serves again once
    idle ones time out, and logs one line a second, not a traceback per failed accept."""
    with tsog_serve(root, "--keepalive", "1", nofile=64) as srv:
        socks = []
        try:
            for _ in range(150):  # the kernel queues those the server cannot accept
                socks.append(connect(srv.port))
            assert get(srv.port, "/files/data.bin") == (200, DATA)  # once idle ones are closed
        finally:
            for sock in socks:
                sock.close()
        assert get(srv.port, "/files/data.bin") == (200, DATA)
        log = srv.stderr()
        assert "Traceback" not in log and len(log.splitlines()) < 30


@pytest.mark.slow
def test_out_of_file_descriptors_is_503_never_404_or_an_empty_200(root: Path) -> None:
    """Stalled clients hold a socket and an open file each until the process has no file
    descriptor left: a request that cannot open its file is answered 503 with Retry-After
    before any header goes out (never a 200 without a body, never a 404 for a file that
    exists), and the log says so in a line a second at most."""
    slow = ("--stall-timeout", "30", "--send-timeout", "60", "--keepalive", "30")
    with tsog_serve(root, *slow, nofile=40) as srv:
        socks = [connect(srv.port, rcvbuf=4096) for _ in range(40)]
        heads = []
        try:
            for sock in socks:
                sock.sendall(b"GET /files/big.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            for sock in socks:
                sock.settimeout(1.0)
                try:
                    heads.append(sock.recv(400))
                except TimeoutError:
                    heads.append(b"")  # not accepted yet: the kernel queues it
        finally:
            for sock in socks:
                sock.close()
        statuses = [head[9:12] for head in heads]
        assert b"503" in statuses and set(statuses) <= {b"200", b"503", b""}
        assert all(b"Retry-After: 1" in h for h in heads if h[9:12] == b"503")
        assert all(b"Content-Length: 67108864" in h for h in heads if h[9:12] == b"200")
        assert get(srv.port, "/files/data.bin") == (200, DATA)  # serves again once freed
        log = srv.stderr()
        assert "Traceback" not in log and log.count("answering 503") <= 5
