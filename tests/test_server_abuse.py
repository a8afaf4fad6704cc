"""Abusive clients against a real server on 127.0.0.1: every loop bounded in count and time."""

from __future__ import annotations

import http.client
import logging
import select
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import ThreadedServer
from tsog_stream.server import Limits, make_app

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
