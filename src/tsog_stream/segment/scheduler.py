"""Reaching a Dask scheduler: its address parsed, then a short probe of its handshake before
Dask's own client connects.

Dask's client trusts its peer: it waits for a handshake without a deadline and allocates
whatever length the peer's first eight bytes claim (``HTTP/1.1`` reads as 3.5 EiB). So the
probe first exchanges handshakes on its own socket within one deadline, the peer's length
bounded before anything is allocated, and checks it is the msgpack map Dask sends. Every
failure is one :class:`InputError` line naming the address.
"""

from __future__ import annotations

import importlib.util
import ipaddress
import pickle
import re
import socket
import ssl
import struct
import sys
import time
from dataclasses import dataclass
from typing import Any

from ..errors import InputError

SCHEMES = ("tcp", "tls", "ucx")
"""The transports of a Dask scheduler address."""
_ADDRESS = re.compile(
    r"(?P<scheme>[a-z]+)://(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.\-]+):(?P<port>[0-9]{1,5})"
)
_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9\-]{0,61}[A-Za-z0-9])?")
MAX_HANDSHAKE_BYTES = 4096
"""Largest handshake accepted from a scheduler (theirs is 58 bytes: a map of three keys)."""
HANDSHAKE_KEY = "pickle-protocol"
"""A key every Dask handshake holds (with ``compression`` and ``python``)."""
_FRAME_LENGTH = struct.Struct("<Q")
"""Dask's TCP framing: a message's length, its frame count and each frame's length, each an
unsigned 64-bit integer (little-endian on every platform Dask runs on)."""


@dataclass(frozen=True)
class SchedulerAddress:
    """A scheduler's ``scheme://host:port``, checked (no name is looked up here)."""

    scheme: str
    host: str
    """A name or an IP address; an IPv6 address without its brackets."""
    port: int

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"


def parse_address(text: str) -> SchedulerAddress:
    """``text`` as a scheduler address (tcp://, tls:// or ucx://; a host name, an IPv4 or a
    bracketed IPv6 address; a port from 1 to 65535), else an InputError."""
    m = _ADDRESS.fullmatch(text)
    host = m.group("host").strip("[]") if m else ""
    if m is None or m.group("scheme") not in SCHEMES or not _valid_host(host, m.group("host")):
        raise _bad_address(text)
    port = int(m.group("port"))
    if not 1 <= port <= 65535:
        raise _bad_address(text)
    return SchedulerAddress(m.group("scheme"), host, port)


def _valid_host(host: str, written: str) -> bool:
    """An IPv6 address in brackets, an IPv4 address, or a host name of valid labels."""
    if written.startswith("["):
        return _is_ip(host, ipaddress.IPv6Address)
    if re.fullmatch(r"[0-9.]+", host):
        return _is_ip(host, ipaddress.IPv4Address)
    return len(host) <= 253 and all(_LABEL.fullmatch(label) for label in host.split("."))


def _is_ip(text: str, kind: type[ipaddress.IPv4Address | ipaddress.IPv6Address]) -> bool:
    try:
        kind(text)
    except ValueError:
        return False
    return True


_HUNG_UP = "not a scheduler: it closed the connection without a handshake"


class _NotASchedulerError(Exception):
    """What answered at the address is not a Dask scheduler (the message says what it was)."""


def _bad_address(text: str) -> InputError:
    return InputError(
        f"expected 'local' or a scheduler address such as tcp://127.0.0.1:8786, got {text!r}",
        where="--cluster",
    )


def probe_scheduler(address: SchedulerAddress, timeout_s: float) -> None:
    """Return when a Dask scheduler answers at ``address`` within ``timeout_s`` seconds with a
    well-formed handshake; else an InputError saying what answered. ucx:// is checked for
    its support only (no raw socket can speak it)."""
    if address.scheme == "ucx":
        _check_ucx(address)
        return
    context = _tls_context(address) if address.scheme == "tls" else None
    deadline = time.monotonic() + timeout_s
    try:
        with _connect(address, context, timeout_s) as sock:
            sock.sendall(client_handshake())
            _check_handshake(_read_handshake(sock, deadline))
    except _NotASchedulerError as exc:
        raise _unreachable(address, str(exc)) from None
    except TimeoutError:
        raise _unreachable(address, f"no Dask handshake within {timeout_s:g} s") from None
    except ssl.SSLError as exc:
        raise _unreachable(address, f"TLS failed: {exc.reason or exc}") from None
    except (ConnectionResetError, BrokenPipeError):
        raise _unreachable(address, _HUNG_UP) from None
    except ConnectionRefusedError:
        raise _unreachable(address, "connection refused (nothing listens there)") from None
    except OSError as exc:
        raise _unreachable(address, exc.strerror or str(exc)) from None


def _unreachable(address: SchedulerAddress, why: str) -> InputError:
    return InputError(f"cannot reach the Dask scheduler: {why}", where=str(address))


def _connect(
    address: SchedulerAddress, context: ssl.SSLContext | None, timeout_s: float
) -> socket.socket:
    """A connected socket (TLS wrapped with ``context``), every operation under the timeout."""
    raw = socket.create_connection((address.host, address.port), timeout=timeout_s)
    if context is None:
        return raw
    try:
        return context.wrap_socket(raw, server_hostname=address.host)
    except BaseException:
        raw.close()
        raise


def _tls_context(address: SchedulerAddress) -> ssl.SSLContext:
    """The client TLS context of the Dask configuration, which Dask's client uses too."""
    from distributed.security import Security  # noqa: PLC0415 - an optional extra

    context = Security().get_connection_args("client").get("ssl_context")  # type: ignore[no-untyped-call]
    if not isinstance(context, ssl.SSLContext):
        raise InputError(
            "tls:// needs Dask's TLS settings (distributed.comm.tls.ca-file and "
            "distributed.comm.tls.client.cert/key in the Dask configuration); none are set",
            where=str(address),
        )
    return context


def _check_ucx(address: SchedulerAddress) -> None:
    """UCX needs its own package beside Dask; say so rather than fail inside Dask."""
    if not any(importlib.util.find_spec(name) for name in ("ucp", "ucxx", "distributed_ucxx")):
        raise InputError(
            "ucx:// needs UCX support for Dask (ucx-py or distributed-ucxx), not installed here",
            where=str(address),
        )


def _msgpack() -> Any:
    """Dask's own message codec (it comes with the optional extra)."""
    import msgpack  # type: ignore[import-untyped]  # noqa: PLC0415 - an optional extra

    return msgpack


def client_handshake() -> bytes:
    """The handshake a Dask client sends first: one msgpack frame, Dask's TCP framing."""
    payload: bytes = _msgpack().packb(
        {
            "compression": None,
            "python": list(sys.version_info[:3]),
            HANDSHAKE_KEY: pickle.HIGHEST_PROTOCOL,
        }
    )
    frames = _FRAME_LENGTH.pack(1) + _FRAME_LENGTH.pack(len(payload)) + payload
    return _FRAME_LENGTH.pack(len(frames)) + frames


def _read_handshake(sock: socket.socket, deadline: float) -> bytes:
    """The peer's first message, its claimed length checked before it is read."""
    head = _read_exactly(sock, _FRAME_LENGTH.size, deadline)
    if head.startswith(b"HTTP"):
        raise _NotASchedulerError(
            "an HTTP server answered, not a scheduler (the dashboard's port? a scheduler "
            "listens on 8786 by default)"
        )
    (length,) = _FRAME_LENGTH.unpack(head)
    if not 2 * _FRAME_LENGTH.size <= length <= MAX_HANDSHAKE_BYTES:
        raise _NotASchedulerError(
            f"not a scheduler: its first message claims {length} bytes, a handshake has "
            f"16 to {MAX_HANDSHAKE_BYTES}"
        )
    return _read_exactly(sock, length, deadline)


def _read_exactly(sock: socket.socket, size: int, deadline: float) -> bytes:
    """``size`` bytes (at most MAX_HANDSHAKE_BYTES), all by ``deadline``."""
    data = bytearray()
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        sock.settimeout(left)
        piece = sock.recv(size - len(data))
        if not piece:
            raise _NotASchedulerError(
                f"not a scheduler: the connection closed after {len(data)} of {size} bytes"
                if data
                else _HUNG_UP
            )
        data += piece
    return bytes(data)


def _check_handshake(message: bytes) -> None:
    """``message`` is Dask's framing of frames whose first is a msgpack map holding
    HANDSHAKE_KEY."""
    count = _FRAME_LENGTH.unpack_from(message)[0]
    start = _FRAME_LENGTH.size * (1 + count)
    if not 1 <= count <= 16 or start > len(message):
        raise _NotASchedulerError(
            f"not a scheduler: a handshake of {count} frames in {len(message)} bytes"
        )
    lengths = struct.unpack_from(f"<{count}Q", message, _FRAME_LENGTH.size)
    if start + sum(lengths) != len(message):
        raise _NotASchedulerError("not a scheduler: handshake frame lengths that do not add up")
    if not _is_handshake(message[start : start + lengths[0]]):
        raise _NotASchedulerError("not a scheduler: a handshake that is not Dask's")


def _is_handshake(frame: bytes) -> bool:
    """Whether ``frame`` is a msgpack map holding HANDSHAKE_KEY."""
    msgpack = _msgpack()
    try:
        value: Any = msgpack.unpackb(frame, raw=False)
    except (ValueError, TypeError, msgpack.UnpackException):
        return False
    return isinstance(value, dict) and HANDSHAKE_KEY in value
