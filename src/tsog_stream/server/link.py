"""A slow link on loopback: a TCP relay with a bandwidth (token bucket) and an added latency.

In front of any origin (``tsog serve``, nginx) it makes the link a viewer would have: every byte
the origin sends goes through one shared bucket at ``bandwidth`` bits per second (one link,
however many connections), every byte the viewer sends reaches the origin ``latency`` seconds
late. ``tsog play --bandwidth``, the tests and the benchmarks measure through it.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
from dataclasses import dataclass
from types import TracebackType

from ..errors import InputError

PIECE = 16 * 1024
"""Bytes relayed at a time: the bucket's grain (a piece leaves once the link has carried it)."""
BURST = 16 * 1024
"""Bytes an idle link may send at once (the bucket's depth)."""
DELAYED_PIECES = 64
"""Pieces of one connection held back for the latency at most (1 MiB): a viewer sending
faster than the origin reads waits, it does not fill memory."""
CLOSE_S = 1.0
"""Seconds a closing connection may take to hand over what it was given."""
MAX_CONNECTIONS = 256
"""Connections relayed at once; more are closed on arrival (a bound, not a tuning)."""
LOOPBACK = "127.0.0.1"
_RATE = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*([kmg]?)(bit|bps|b/s|b)(?:/s)?\s*$", re.IGNORECASE)
_DELAY = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*(ms|s)\s*$", re.IGNORECASE)
_PREFIX = {"": 1.0, "k": 1e3, "m": 1e6, "g": 1e9}


def parse_bandwidth(text: str) -> float:
    """'20Mbit', '500kbit', '1.5 Mbps', '2MB/s' (bytes) -> bits per second."""
    m = _RATE.match(text)
    if not m:
        raise InputError(
            f"expected a rate like 20Mbit, 500kbit or 2MB/s, got {text!r}", where="--bandwidth"
        )
    number, prefix, unit = m.groups()
    bits = float(number) * _PREFIX[prefix.lower()] * (8.0 if unit in ("B", "B/s") else 1.0)
    if not (math.isfinite(bits) and bits > 0):
        raise InputError(f"must be a positive rate, got {text!r}", where="--bandwidth")
    return bits


def parse_latency(text: str) -> float:
    """'50ms', '0.2s' -> seconds."""
    m = _DELAY.match(text)
    if not m:
        raise InputError(f"expected a delay like 50ms or 0.2s, got {text!r}", where="--latency")
    seconds = float(m.group(1)) / (1000.0 if m.group(2).lower() == "ms" else 1.0)
    if not math.isfinite(seconds) or seconds > 60:
        raise InputError(f"must be at most 60 s, got {text!r}", where="--latency")
    return seconds


@dataclass(frozen=True)
class LinkShape:
    """A link: ``bandwidth_bps`` bits per second from the origin, ``latency_s`` added to every
    request's way there."""

    bandwidth_bps: float
    latency_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.bandwidth_bps) and self.bandwidth_bps > 0):
            raise InputError(f"bandwidth must be positive, got {self.bandwidth_bps}")
        if not (math.isfinite(self.latency_s) and 0 <= self.latency_s <= 60):
            raise InputError(f"latency must be 0-60 s, got {self.latency_s}")

    def describe(self) -> str:
        """'1 Mbit/s, 50 ms' style."""
        return f"{self.bandwidth_bps / 1e6:g} Mbit/s, {self.latency_s * 1000:g} ms"


async def _close(writer: asyncio.StreamWriter, cut: bool) -> None:
    """Close one side: cut at once, or flush what is written for at most CLOSE_S (a peer
    that stopped reading does not hold the connection open)."""
    if not cut:
        writer.close()
        with contextlib.suppress(OSError, TimeoutError, asyncio.CancelledError):
            await asyncio.wait_for(writer.wait_closed(), CLOSE_S)
    writer.transport.abort()


class ThrottledRelay:
    """Relays 127.0.0.1:``port`` to ``upstream`` through a :class:`LinkShape`."""

    def __init__(self, upstream_port: int, shape: LinkShape, upstream_host: str = LOOPBACK):
        self.upstream = (upstream_host, upstream_port)
        self.shape = shape
        self.port = 0
        self.bytes_down = 0
        self.connections = 0
        self._free_at = 0.0  # the shared link: when it is next free (a bucket of depth BURST)
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    async def start(self) -> ThrottledRelay:
        """Listen on a free loopback port."""
        self._server = await asyncio.start_server(self._relay, LOOPBACK, 0)
        self.port = int(self._server.sockets[0].getsockname()[1])
        return self

    def url(self, path: str = "/") -> str:
        """The relay's URL for ``path`` on the origin."""
        return f"http://{LOOPBACK}:{self.port}{path}"

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One viewer connection: requests delayed to the origin, answers through the bucket,
        until either side ends; then both are closed (cut at once when the relay closes)."""
        task = asyncio.current_task()
        if len(self._tasks) >= MAX_CONNECTIONS or task is None:
            writer.close()
            return
        self._tasks.add(task)
        self.connections += 1
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except (OSError, asyncio.CancelledError):
            self._tasks.discard(task)
            writer.close()
            return
        pumps = [
            asyncio.ensure_future(self._delayed(reader, up_writer)),
            asyncio.ensure_future(self._throttled(up_reader, writer)),
        ]
        closing = False
        try:
            await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:
            closing = True  # the relay is closing: it ends quietly, without waiting for peers
        finally:  # the pumps end (and are reaped) with the connection
            self._tasks.discard(task)
            for pump in pumps:
                pump.cancel()
            await asyncio.gather(*pumps, return_exceptions=True)
            await asyncio.gather(*(_close(w, closing) for w in (writer, up_writer)))

    async def _delayed(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Viewer -> origin, each piece ``latency_s`` after it arrived, in order; at most
        DELAYED_PIECES wait at once (reading stops until the origin side catches up)."""
        loop = asyncio.get_running_loop()
        due: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue(DELAYED_PIECES)

        async def forward() -> None:
            while True:
                when, piece = await due.get()
                await asyncio.sleep(max(0.0, when - loop.time()))
                if not piece:
                    writer.write_eof()
                    return
                writer.write(piece)
                await writer.drain()

        sender = asyncio.ensure_future(forward())
        try:
            while True:
                piece = await reader.read(PIECE)
                await due.put((loop.time() + self.shape.latency_s, piece))
                if not piece:
                    break
            await sender
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)

    async def _throttled(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Origin -> viewer, each piece once the shared link has carried it."""
        while piece := await reader.read(PIECE):
            await self._carry(len(piece))
            writer.write(piece)
            self.bytes_down += len(piece)
            await writer.drain()

    async def _carry(self, size: int) -> None:
        """Return once ``size`` more bytes have crossed the link (pieces cross in call order)."""
        now, rate = asyncio.get_running_loop().time(), self.shape.bandwidth_bps / 8.0
        self._free_at = max(self._free_at, now - BURST / rate) + size / rate
        await asyncio.sleep(max(0.0, self._free_at - now))

    async def aclose(self) -> None:
        """Stop listening and cut every relayed connection."""
        if self._server is not None:
            self._server.close()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self._server is not None:
            await self._server.wait_closed()

    async def __aenter__(self) -> ThrottledRelay:
        return await self.start()

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()
