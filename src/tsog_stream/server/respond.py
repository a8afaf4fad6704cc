"""Sending one representation (a file, or a span of one): preconditions, byte ranges,
multipart, 416, and the body under a send deadline (RFC 9110 §13-14).

A single span of at least SENDFILE_MIN bytes (whole file or one range) goes out with zero-copy
``loop.sendfile`` on the connection's transport; multipart bodies, small spans, TLS and
transports without sendfile are read with ``pread`` in a worker thread, 256 KiB at a time, and
written with ``StreamResponse.write`` (see docs/http.md). Used by the API and the player pages.
"""

from __future__ import annotations

import asyncio
import os
import secrets
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, BinaryIO, TypeVar

from aiohttp import web
from aiohttp.abc import AbstractStreamWriter

from ..container.ranges import ByteRange
from .catalog import Representation, unreadable
from .conditional import Outcome, evaluate, http_date, if_range_allows
from .ranges import Ignore, Serve, Unsatisfiable, content_range, parse_range, unsatisfied_range

READ_BLOCK = 256 * 1024
"""Bytes read and written at a time when a body is copied (not sent with sendfile)."""
SENDFILE_MIN = 16 * 1024
"""A single span at least this long goes out with sendfile (tried at once, see
sendfile_now); shorter ones are read and written in the event loop. Measured with wrk on
loopback, one process: 16 KiB ranges 4790 requests/s with sendfile against 4290 copied, 64 KiB
4480-4920 against 3900-3990."""
SENDFILE_SLICE = 4 << 20
"""Bytes handed to one ``loop.sendfile`` call: each slice must go out within the stall timeout."""
SOURCE_BLOCK = 4 << 20
"""Bytes asked of a store in one ranged GET when a body comes from one (object storage)."""
REVALIDATE = "public, max-age=0, must-revalidate"
IMMUTABLE = "public, max-age=31536000, immutable"


@dataclass(frozen=True, slots=True)
class Limits:
    """Hardening limits of one server."""

    max_concurrent: int = 256
    """Requests handled at once; more get 503 with Retry-After: 1 (``/healthz`` is exempt)."""
    max_per_client: int = 32
    """Requests handled at once for one client address once the server is half busy; more
    get 503, so one client cannot take every slot of ``max_concurrent`` from the others."""
    send_timeout_s: float = 60.0
    """Deadline for sending one response body; the connection is dropped when it passes."""
    stall_timeout_s: float = 10.0
    """Longest a body may make no progress (a client that stopped reading); the connection is
    dropped then, long before ``send_timeout_s``."""
    keepalive_s: float = 15.0
    """Idle keep-alive connections are closed after this."""
    shutdown_timeout_s: float = 10.0
    """Grace period for in-flight requests on shutdown."""
    sendfile: bool = True
    """Send large single-span bodies with zero-copy ``loop.sendfile`` when the transport can."""


LIMITS = web.AppKey("limits", Limits)
CORS = {
    "Access-Control-Allow-Origin": "*",
    "Access-Control-Expose-Headers": "Content-Range, ETag, Accept-Ranges, Content-Length",
}
"""Headers on every response (added by the app's ``on_response_prepare``)."""


@dataclass
class Load:
    """Requests being handled by one worker process: in all and by client address."""

    total: int = 0
    by_client: dict[str, int] = field(default_factory=dict)

    def refuses(self, client: str, limits: Limits) -> str | None:
        """Why one more request of ``client`` must wait (503), or None: the server is full, or
        the client holds its share while the server is at least half busy (alone it may use
        every slot: a proxy in front, a load test)."""
        if self.total >= limits.max_concurrent:
            return "too many concurrent requests"
        mine = self.by_client.get(client, 0)
        if mine >= limits.max_per_client and 2 * self.total >= limits.max_concurrent:
            return "too many concurrent requests from this client"
        return None

    def enter(self, client: str) -> None:
        """Count one more request of ``client``."""
        self.total += 1
        self.by_client[client] = self.by_client.get(client, 0) + 1

    def leave(self, client: str) -> None:
        """Count one request of ``client`` done."""
        self.total -= 1
        self.by_client[client] -= 1
        if not self.by_client[client]:
            del self.by_client[client]


LOAD = web.AppKey("load", Load)
_T = TypeVar("_T")


def validators(rep: Representation, cache_control: str) -> dict[str, str]:
    """ETag, Last-Modified, Accept-Ranges and Cache-Control of a representation."""
    return {
        "ETag": rep.etag,
        "Last-Modified": http_date(rep.mtime),
        "Accept-Ranges": "bytes",
        "Cache-Control": cache_control,
    }


class StallError(TimeoutError):
    """The client took no bytes for the stall timeout."""


async def within_stall(step: Awaitable[_T], stall_s: float) -> _T:
    """``step`` (one write or sendfile slice), which must finish within ``stall_s``."""
    try:
        async with asyncio.timeout(stall_s):
            return await step
    except TimeoutError as exc:
        raise StallError from exc


async def _copy(resp: web.StreamResponse, fd: int, span: ByteRange, stall_s: float) -> None:
    """Write ``span`` of the open file ``fd`` in READ_BLOCK pieces, each within ``stall_s``.
    A span under SENDFILE_MIN is read in the event loop (a thread hop cost more than the
    read); longer ones (multipart, TLS) in a worker thread, so a cold disk never stalls the
    loop for long."""
    pos = span.start
    small = span.length < SENDFILE_MIN
    while pos < span.end:
        count = min(READ_BLOCK, span.end - pos)
        data = (
            os.pread(fd, count, pos) if small else await asyncio.to_thread(os.pread, fd, count, pos)
        )
        if not data:
            raise ConnectionAbortedError("file shrank while being sent")
        await within_stall(resp.write(data), stall_s)
        pos += len(data)


async def _sendfile(
    request: web.Request,
    writer: AbstractStreamWriter,
    file: BinaryIO,
    span: ByteRange,
    stall_s: float,
) -> bool:
    """Send ``span`` of ``file`` with ``loop.sendfile`` in SENDFILE_SLICE slices, each within
    ``stall_s``; False (nothing sent) if sendfile is unavailable.

    The headers were already handed to the transport by ``prepare``; sendfile waits for them
    to be flushed. The bytes sent are added to the writer's ``output_size`` (the access log's
    ``%b``) and taken off its remaining ``length``, as ``write`` would.
    """
    transport = request.transport
    if transport is None:
        raise ConnectionResetError("connection lost")
    if transport.get_extra_info("sslcontext") is not None:
        return False
    now = sendfile_now(transport, file.fileno(), span)
    _count_sent(writer, now)
    rest = ByteRange(span.start + now, span.end)
    return await sendfile_slices(
        transport, file, rest, stall_s, counted=lambda n: _count_sent(writer, n), first=now == 0
    )


async def sendfile_slices(
    transport: asyncio.WriteTransport,
    file: BinaryIO,
    span: ByteRange,
    stall_s: float,
    *,
    counted: Callable[[int], None] = lambda _n: None,
    first: bool = False,
) -> bool:
    """Send ``span`` of ``file`` with ``loop.sendfile`` in SENDFILE_SLICE slices, each within
    ``stall_s``, passing each slice's byte count to ``counted``. False when sendfile is
    unavailable and ``first`` (no byte of the body sent yet: the caller copies instead);
    unavailable later, or the transport closing, is the client gone (ConnectionResetError),
    a short slice a file that shrank (ConnectionAbortedError)."""
    loop = asyncio.get_running_loop()
    for start in range(span.start, span.end, SENDFILE_SLICE):
        count = min(SENDFILE_SLICE, span.end - start)
        try:
            sent = await within_stall(
                loop.sendfile(transport, file, start, count, fallback=False), stall_s
            )
        except (NotImplementedError, asyncio.SendfileNotAvailableError) as exc:
            if first and start == span.start:
                return False
            # part of the body went out already: sendfile failing now means the socket did
            # (the client left), which asyncio reports as "not available" on its first call
            raise ConnectionResetError("connection lost") from exc
        except RuntimeError as exc:  # "Transport is closing": the client went away
            raise ConnectionResetError("connection lost") from exc
        counted(sent)
        if sent < count:
            raise ConnectionAbortedError("file shrank while being sent")
    return True


def sendfile_now(transport: asyncio.BaseTransport, fd: int, span: ByteRange) -> int:
    """Bytes of ``span`` sent at once by one non-blocking ``os.sendfile`` when the headers
    already left the transport (0 when the socket is full or the transport holds bytes):
    most bodies fit the socket buffer, and this skips the futures and the writability wait
    of ``loop.sendfile`` (1 MiB ranges: 0.75 ms a request, of which about 0.3 above nginx)."""
    sock = transport.get_extra_info("socket")
    if sock is None or not isinstance(transport, asyncio.WriteTransport):
        return 0
    if transport.get_write_buffer_size() or transport.is_closing():
        return 0
    try:
        return os.sendfile(sock.fileno(), fd, span.start, span.length)
    except (BlockingIOError, InterruptedError):
        return 0
    except OSError as exc:  # EPIPE, ECONNRESET: the client went away
        raise ConnectionResetError("connection lost") from exc


def _count_sent(writer: AbstractStreamWriter, sent: int) -> None:
    """Add ``sent`` body bytes to the writer's ``output_size`` and take them off ``length``,
    as its own ``write`` would (the access log's ``%b``)."""
    writer.output_size += sent
    if writer.length is not None:
        writer.length = max(0, writer.length - sent)


def _parts(
    rep: Representation, spans: tuple[ByteRange, ...], boundary: str
) -> tuple[list[tuple[bytes, ByteRange]], bytes]:
    """Multipart/byteranges framing: (part header, span) pairs and the closing delimiter."""
    parts = [
        (
            f"\r\n--{boundary}\r\nContent-Type: {rep.content_type}\r\n"
            f"Content-Range: {content_range(s, rep.length)}\r\n\r\n".encode(),
            s,
        )
        for s in spans
    ]
    return parts, f"\r\n--{boundary}--\r\n".encode()


async def _send_body(
    request: web.Request, resp: web.StreamResponse, rep: Representation, plan: list[Any]
) -> web.StreamResponse:
    """Open the file, prepare ``resp`` and write ``plan`` (bytes and spans) unless HEAD, under
    the deadline and the stall timeout.

    The file is opened (in the event loop: a few ``openat`` calls on cached directories cost
    less than a thread hop) before any byte goes out, so a failure is still a whole answer (503
    when out of file descriptors, 404 when gone), never a 200 without a body. A plan of one span
    of at least SENDFILE_MIN bytes is sent with sendfile when possible. When the deadline
    passes, or the client takes nothing for the stall timeout, the transport is aborted
    (buffered bytes discarded).
    """
    if request.method == "HEAD":
        await resp.prepare(request)
        return resp
    if rep.source is not None:
        return await _write_from_source(request, resp, rep, plan)
    try:
        file = rep.open()
    except OSError as exc:
        raise unreadable(exc, "no such file", rep.path.name) from exc
    try:
        return await _write_body(request, resp, file, rep, plan)
    finally:
        file.close()


async def _write_body(
    request: web.Request,
    resp: web.StreamResponse,
    file: BinaryIO,
    rep: Representation,
    plan: list[Any],
) -> web.StreamResponse:
    """The sending part of :func:`_send_body`, on an open file."""
    writer = await resp.prepare(request)
    if writer is None:
        return resp
    limits = request.app[LIMITS]
    stall = limits.stall_timeout_s
    try:
        async with asyncio.timeout(limits.send_timeout_s):
            spans = [
                ByteRange.sized(rep.offset + x.start, x.length) if isinstance(x, ByteRange) else x
                for x in plan
            ]
            first = spans[0]
            zero_copy = (
                limits.sendfile
                and len(spans) == 1
                and isinstance(first, ByteRange)
                and first.length >= SENDFILE_MIN
                and await _sendfile(request, writer, file, first, stall)
            )
            for item in [] if zero_copy else spans:
                if isinstance(item, ByteRange):
                    await _copy(resp, file.fileno(), item, stall)
                else:
                    await within_stall(resp.write(item), stall)
            await within_stall(resp.write_eof(), stall)
    except TimeoutError as exc:
        if request.transport is not None:
            request.transport.abort()  # close() would keep waiting to flush to a stalled reader
        why = (
            "the client stopped reading" if isinstance(exc, StallError) else "send deadline passed"
        )
        raise ConnectionAbortedError(f"{why}; connection dropped") from exc
    return resp


async def _write_from_source(
    request: web.Request, resp: web.StreamResponse, rep: Representation, plan: list[Any]
) -> web.StreamResponse:
    """:func:`_write_body` for bytes in a store: each span read with ranged GETs of at most
    SOURCE_BLOCK bytes, the first one before the headers go out (a missing object is still a
    whole 404 or 503, never a 200 without a body)."""
    assert rep.source is not None
    source = rep.source
    limits = request.app[LIMITS]
    stall = limits.stall_timeout_s
    pieces = [
        ByteRange.sized(rep.offset + x.start, x.length) if isinstance(x, ByteRange) else x
        for x in plan
    ]
    first = next((x for x in pieces if isinstance(x, ByteRange) and x.length), None)
    ahead = (
        await source.read(ByteRange.sized(first.start, min(first.length, SOURCE_BLOCK)))
        if first is not None
        else b""
    )
    writer = await resp.prepare(request)
    if writer is None:
        return resp
    try:
        async with asyncio.timeout(limits.send_timeout_s):
            for item in pieces:
                if not isinstance(item, ByteRange):
                    await within_stall(resp.write(item), stall)
                    continue
                pos = item.start
                while pos < item.end:
                    count = min(SOURCE_BLOCK, item.end - pos)
                    if item is first and pos == item.start:
                        data = ahead
                    else:
                        data = await source.read(ByteRange.sized(pos, count))
                    await within_stall(resp.write(data), stall)
                    pos += len(data)
            await within_stall(resp.write_eof(), stall)
    except TimeoutError as exc:
        if request.transport is not None:
            request.transport.abort()
        raise ConnectionAbortedError("send deadline passed or the client stopped reading") from exc
    return resp


async def send_representation(
    request: web.Request, rep: Representation, cache_control: str = REVALIDATE
) -> web.StreamResponse:
    """Answer GET/HEAD for ``rep`` with preconditions, ranges, multipart and 416."""
    headers = validators(rep, cache_control)
    outcome = evaluate(request.method, request.headers, rep.etag, rep.mtime)
    if outcome is not Outcome.PROCEED:
        return web.Response(status=outcome.value, headers=headers)
    fields = request.headers.getall("Range", [])
    verdict = parse_range(fields[0], rep.length) if len(fields) == 1 else Ignore("not one Range")
    if not if_range_allows(request.headers.get("If-Range"), rep.etag, rep.mtime):
        verdict = Ignore("If-Range does not match")
    if isinstance(verdict, Unsatisfiable):
        headers["Content-Range"] = unsatisfied_range(rep.length)
        return web.Response(status=416, headers=headers)
    plan: list[Any]
    if isinstance(verdict, Serve) and len(verdict.ranges) == 1:
        span = verdict.ranges[0]
        headers["Content-Range"] = content_range(span, rep.length)
        resp, plan = web.StreamResponse(status=206, headers=headers), [span]
        resp.content_length = span.length
    elif isinstance(verdict, Serve):
        boundary = secrets.token_hex(16)
        parts, tail = _parts(rep, verdict.ranges, boundary)
        headers["Content-Type"] = f"multipart/byteranges; boundary={boundary}"
        resp = web.StreamResponse(status=206, headers=headers)
        plan = [x for head, span in parts for x in (head, span)] + [tail]
        resp.content_length = sum(len(x) if isinstance(x, bytes) else x.length for x in plan)
    else:
        resp, plan = web.StreamResponse(status=200, headers=headers), [ByteRange(0, rep.length)]
        resp.content_length = rep.length
    if "Content-Type" not in headers:
        resp.content_type = rep.content_type
    return await _send_body(request, resp, rep, plan)
