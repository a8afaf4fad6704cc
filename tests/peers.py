"""Loopback peers that misbehave, for hostile-input tests: each listens on 127.0.0.1 (a free
port), answers every connection on a thread of its own as its behaviour says, and stops by
itself after ``lifetime_s`` at the latest (or when its ``with`` block ends)."""

from __future__ import annotations

import contextlib
import random
import socket
import struct
import threading
from collections.abc import Callable
from types import TracebackType

Behaviour = Callable[[socket.socket, threading.Event], None]
"""What a peer does with one accepted connection until the stop event is set."""


class Peer:
    """A misbehaving TCP server on loopback (use it as a context manager)."""

    def __init__(self, behaviour: Behaviour, lifetime_s: float = 30.0) -> None:
        self.behaviour = behaviour
        self.lifetime_s = lifetime_s
        self.accepted = 0
        self._stop = threading.Event()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.port: int = self._listener.getsockname()[1]
        self._threads: list[threading.Thread] = []

    def address(self, scheme: str) -> str:
        return f"{scheme}://127.0.0.1:{self.port}"

    def __enter__(self) -> Peer:
        accept = threading.Thread(target=self._accept, daemon=True)
        accept.start()
        self._threads.append(accept)
        self._timer = threading.Timer(self.lifetime_s, self._stop.set)
        self._timer.daemon = True
        self._timer.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        self._timer.cancel()
        for thread in list(self._threads):
            thread.join(5)
        self._listener.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            self.accepted += 1
            thread = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            thread.start()
            self._threads.append(thread)

    def _serve(self, conn: socket.socket) -> None:
        with conn, contextlib.suppress(OSError):  # the client went away: expected here
            self.behaviour(conn, self._stop)


def silent(conn: socket.socket, stop: threading.Event) -> None:
    """Accept and say nothing."""
    stop.wait()


def closes(conn: socket.socket, stop: threading.Event) -> None:
    """Accept and hang up at once."""


def random_bytes(conn: socket.socket, stop: threading.Event) -> None:
    """Send 4 KiB of seeded random bytes, then nothing."""
    conn.sendall(random.Random(55).randbytes(4096))
    stop.wait()


def claims(size: int) -> Behaviour:
    """Send a little-endian 8-byte length ``size`` (a frame header), then nothing."""

    def behaviour(conn: socket.socket, stop: threading.Event) -> None:
        conn.sendall(struct.pack("<Q", size))
        stop.wait()

    return behaviour


def _read_head(conn: socket.socket, stop: threading.Event) -> None:
    """Read until the end of an HTTP request head (or 64 KiB, or a second)."""
    conn.settimeout(1.0)
    head = b""
    while b"\r\n\r\n" not in head and len(head) < 65536 and not stop.is_set():
        try:
            piece = conn.recv(4096)
        except TimeoutError:
            return
        if not piece:
            return
        head += piece


def http_error(conn: socket.socket, stop: threading.Event) -> None:
    """Answer like a web server to bytes that are no request: a 400 once some arrive."""
    conn.settimeout(5.0)
    conn.recv(4096)
    conn.sendall(
        b"HTTP/1.1 400 Bad Request\r\nContent-Length: 11\r\nConnection: close\r\n\r\nbad request"
    )


def unavailable(conn: socket.socket, stop: threading.Event) -> None:
    """Answer every request with an immediate 503 (retryable for ever)."""
    _read_head(conn, stop)
    conn.sendall(
        b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
    )


def drip(head: bytes, every_s: float, *, drip_head: bool = False) -> Behaviour:
    """Answer a request with ``head`` (an HTTP response head), then drip a body byte every
    ``every_s`` seconds (``drip_head``: the head itself too, a byte at a time)."""

    def behaviour(conn: socket.socket, stop: threading.Event) -> None:
        _read_head(conn, stop)
        if not drip_head:
            conn.sendall(head)
        for byte in (head if drip_head else b"") + b"\0" * 1_000_000:
            if stop.wait(every_s):
                return
            conn.sendall(bytes([byte]))

    return behaviour
