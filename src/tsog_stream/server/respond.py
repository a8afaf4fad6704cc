"""Sending one representation (a file, a span of one, or a stored object): preconditions, byte
ranges, multipart, 416, and the body under a send deadline and a stall timeout (RFC 9110 §13-14):
zero-copy sendfile for one long span of a local file, else read in blocks and written
(docs/http.md, "Body transfer").
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import secrets
from collections.abc import AsyncGenerator, Awaitable
from dataclasses import dataclass, field
from typing import BinaryIO, TypeVar

from aiohttp import web
from aiohttp.abc import AbstractStreamWriter

from ..container.ranges import ByteRange
from ..container.sources import ByteSource
from .catalog import Representation, unreadable
from .conditional import Outcome, evaluate, http_date, if_range_allows
from .ranges import Ignore, Serve, Unsatisfiable, content_range, parse_range, unsatisfied_range

READ_BLOCK = 256 * 1024
"""Bytes read and written at a time when a local body is copied."""
SENDFILE_MIN = 16 * 1024
"""A single span at least this long goes out with sendfile; shorter ones are copied, read in
the event loop (both faster for their sizes: docs/design/server.md)."""
SENDFILE_SLICE = 4 << 20
"""Bytes handed to one ``loop.sendfile`` call: each slice must go out within the stall timeout."""
SOURCE_BLOCK = 4 << 20
"""Bytes asked of a store in one ranged GET."""
REVALIDATE = "public, max-age=0, must-revalidate"
IMMUTABLE = "public, max-age=31536000, immutable"
CORS = {
    "Access-Control-Allow-Origin": "*",
    "Access-Control-Expose-Headers": "Content-Range, ETag, Accept-Ranges, Content-Length",
}
"""Headers on every response (added by the app's ``on_response_prepare``)."""
Plan = list[bytes | ByteRange]
"""A body: bytes as they are, and spans of the representation."""
_T = TypeVar("_T")


@dataclass(frozen=True, slots=True)
class Limits:
    """Hardening limits of one server (docs/http.md, "Hardening")."""

    max_concurrent: int = 256
    """Requests handled at once; more get 503 with Retry-After: 1 (``/healthz`` is exempt)."""
    max_per_client: int = 32
    """Requests at once of one client address while the server is half busy (more get 503)."""
    send_timeout_s: float = 60.0
    """Deadline for sending one response body; the connection is dropped when it passes."""
    stall_timeout_s: float = 10.0
    """Longest a body may make no progress (a client that stopped reading) before the drop."""
    keepalive_s: float = 15.0
    """Idle keep-alive connections are closed after this."""
    shutdown_timeout_s: float = 10.0
    """Grace period for in-flight requests on shutdown."""
    sendfile: bool = True
    """Send large single-span bodies of local files with zero-copy sendfile."""


LIMITS = web.AppKey("limits", Limits)


@dataclass
class Load:
    """Requests being handled by one worker process: in all and by client address."""

    total: int = 0
    by_client: dict[str, int] = field(default_factory=dict)

    def refuses(self, client: str, limits: Limits) -> str | None:
        """Why one more request of ``client`` must wait (503), or None: the server is full, or
        the client holds its share while the server is half busy (alone it may use all)."""
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


class StallError(TimeoutError):
    """The client took no bytes for the stall timeout."""


async def within_stall(step: Awaitable[_T], stall_s: float) -> _T:
    """``step`` (one write or sendfile slice), which must finish within ``stall_s``."""
    try:
        async with asyncio.timeout(stall_s):
            return await step
    except TimeoutError as exc:
        raise StallError from exc


def sendfile_now(transport: asyncio.BaseTransport, fd: int, span: ByteRange) -> int:
    """Bytes of ``span`` sent at once by one non-blocking ``os.sendfile`` when the headers
    already left the transport (0 when the socket is full or the transport holds bytes):
    most bodies fit the socket buffer, and this skips ``loop.sendfile``'s futures."""
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
    """Count ``sent`` body bytes on the writer as its own ``write`` would (access log's size)."""
    writer.output_size += sent
    if writer.length is not None:
        writer.length = max(0, writer.length - sent)


async def _sendfile(
    request: web.Request, writer: AbstractStreamWriter, file: BinaryIO, span: ByteRange
) -> bool:
    """Send ``span`` of ``file``: what fits at once (:func:`sendfile_now`), the rest with
    ``loop.sendfile`` in SENDFILE_SLICE slices, each within the stall timeout. False (nothing
    sent) when the transport cannot (TLS, no sendfile); sendfile failing later is the client
    gone (ConnectionResetError), a short slice a file that shrank (ConnectionAbortedError)."""
    transport = request.transport
    if transport is None:
        raise ConnectionResetError("connection lost")
    if transport.get_extra_info("sslcontext") is not None:
        return False
    sent = sendfile_now(transport, file.fileno(), span)
    _count_sent(writer, sent)
    loop, stall = asyncio.get_running_loop(), request.app[LIMITS].stall_timeout_s
    for start in range(span.start + sent, span.end, SENDFILE_SLICE):
        count = min(SENDFILE_SLICE, span.end - start)
        step = loop.sendfile(transport, file, start, count, fallback=False)
        try:
            sent = await within_stall(step, stall)
        except (NotImplementedError, asyncio.SendfileNotAvailableError) as exc:
            if start == span.start:
                return False
            # asyncio says "not available" when the socket failed under it: the client left
            raise ConnectionResetError("connection lost") from exc
        except RuntimeError as exc:  # "Transport is closing": the client went away
            raise ConnectionResetError("connection lost") from exc
        _count_sent(writer, sent)
        if sent < count:
            raise ConnectionAbortedError("file shrank while being sent")
    return True


async def _pieces(
    plan: Plan, body: io.BufferedReader | ByteSource, ahead: bytes | None
) -> AsyncGenerator[bytes, None]:
    """The bytes of ``plan`` in order: a span of a local file in READ_BLOCK reads (in the event
    loop under SENDFILE_MIN, where a thread hop costs more than the read), a span of a stored
    object in SOURCE_BLOCK ranged GETs, the first of them ``ahead`` when given."""
    step = READ_BLOCK if isinstance(body, io.BufferedReader) else SOURCE_BLOCK
    for item in plan:
        if isinstance(item, bytes):
            yield item
            continue
        for start in range(item.start, item.end, step):
            count = min(step, item.end - start)
            if ahead is not None:
                data, ahead = ahead, None
            elif not isinstance(body, io.BufferedReader):
                data = await body.read(ByteRange.sized(start, count))
            elif item.length < SENDFILE_MIN:
                data = os.pread(body.fileno(), count, start)
            else:
                data = await asyncio.to_thread(os.pread, body.fileno(), count, start)
            if len(data) != count:
                raise ConnectionAbortedError("file shrank while being sent")
            yield data


async def _first_read(
    rep: Representation, plan: Plan
) -> tuple[io.BufferedReader | ByteSource, bytes | None]:
    """The file opened, or a store's first block read: what can fail is done before a byte
    goes out, so a failure is still a whole answer (404, 503 when out of file descriptors)."""
    if rep.source is None:
        try:
            return rep.open(), None
        except OSError as exc:
            raise unreadable(exc, "no such file", rep.path.name) from exc
    first = next((x for x in plan if isinstance(x, ByteRange) and x.length), None)
    if first is None:
        return rep.source, None
    span = ByteRange.sized(first.start, min(first.length, SOURCE_BLOCK))
    return rep.source, await rep.source.read(span)


async def _send_body(
    request: web.Request, resp: web.StreamResponse, rep: Representation, plan: Plan
) -> web.StreamResponse:
    """Prepare ``resp`` and write ``plan`` unless HEAD, within the send deadline and the
    stall timeout; when either passes, the transport is aborted (buffered bytes discarded)."""
    if request.method == "HEAD":
        await resp.prepare(request)
        return resp
    plan = [
        x if isinstance(x, bytes) else ByteRange.sized(rep.offset + x.start, x.length) for x in plan
    ]
    body, ahead = await _first_read(rep, plan)
    file = body if isinstance(body, io.BufferedReader) else None
    limits, stall = request.app[LIMITS], request.app[LIMITS].stall_timeout_s
    one = plan[0] if len(plan) == 1 else None
    whole = one if isinstance(one, ByteRange) and one.length >= SENDFILE_MIN else None
    try:
        writer = await resp.prepare(request)
        if writer is None:
            return resp
        pieces = contextlib.aclosing(_pieces(plan, body, ahead))
        async with asyncio.timeout(limits.send_timeout_s), pieces as out:
            if not (
                limits.sendfile
                and file is not None
                and whole is not None
                and await _sendfile(request, writer, file, whole)
            ):
                async for piece in out:
                    await within_stall(resp.write(piece), stall)
            await within_stall(resp.write_eof(), stall)
    except TimeoutError as exc:
        if request.transport is not None:
            request.transport.abort()  # close() would keep waiting to flush to a stalled reader
        why = (
            "the client stopped reading" if isinstance(exc, StallError) else "send deadline passed"
        )
        raise ConnectionAbortedError(f"{why}; connection dropped") from exc
    finally:
        if file is not None:
            file.close()
    return resp


async def send_representation(
    request: web.Request, rep: Representation, cache_control: str = REVALIDATE
) -> web.StreamResponse:
    """Answer GET/HEAD for ``rep`` with preconditions, ranges, multipart and 416."""
    headers = {
        "ETag": rep.etag,
        "Last-Modified": http_date(rep.mtime),
        "Accept-Ranges": "bytes",
        "Cache-Control": cache_control,
    }
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
    plan: Plan = [ByteRange(0, rep.length)]
    if isinstance(verdict, Serve) and len(verdict.ranges) == 1:
        plan = [verdict.ranges[0]]
        headers["Content-Range"] = content_range(verdict.ranges[0], rep.length)
    elif isinstance(verdict, Serve):
        boundary = secrets.token_hex(16)
        headers["Content-Type"] = f"multipart/byteranges; boundary={boundary}"
        plan = [
            x
            for s in verdict.ranges
            for x in (
                f"\r\n--{boundary}\r\nContent-Type: {rep.content_type}\r\n"
                f"Content-Range: {content_range(s, rep.length)}\r\n\r\n".encode(),
                s,
            )
        ] + [f"\r\n--{boundary}--\r\n".encode()]
    resp = web.StreamResponse(status=206 if isinstance(verdict, Serve) else 200, headers=headers)
    resp.content_length = sum(len(x) if isinstance(x, bytes) else x.length for x in plan)
    if "Content-Type" not in headers:
        resp.content_type = rep.content_type
    return await _send_body(request, resp, rep, plan)
