"""The lean path: plain byte-range GETs of public files and chunks, answered below aiohttp.

Every connection starts on :class:`LeanProtocol`. A request it fully understands (see
:func:`parse_head`: ``GET /files/<path>`` or ``GET /v1/scenes/<id>/chunks/<n>.sog[?v=<sha256>]``
over HTTP/1.1, known headers only, a public file or scene already known to the catalog,
preconditions that let it through, at most one satisfiable range) is answered here: the same
status, headers and body as the full handler, the body with one non-blocking ``os.sendfile``
(``loop.sendfile`` for what the socket does not take at once, under the same deadlines). The
first request it does not take hands the connection, with every byte buffered, to aiohttp's
handler for the rest of its life, so behaviour never depends on which path answers
(docs/http.md, "The per-request path").
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import socket
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from typing import Any, BinaryIO, Final

from aiohttp import web
from aiohttp.http import SERVER_SOFTWARE
from aiohttp.log import access_logger

from ..container.ranges import ByteRange
from ..errors import TsogError
from .catalog import (
    CONTAINER_SUFFIX,
    Catalog,
    FileVersion,
    Representation,
    SceneEntry,
    check_relative,
    open_fd_beneath,
    remember,
    version_of,
)
from .conditional import Outcome, evaluate, http_date, if_range_allows
from .private import PRIVACY, Privacy, Served, log_served
from .ranges import Ignore, Serve, content_range, parse_range
from .respond import (
    CORS,
    IMMUTABLE,
    LIMITS,
    LOAD,
    REVALIDATE,
    Limits,
    Load,
    sendfile_now,
    sendfile_slices,
    validators,
)
from .scenes import CATALOG

MAX_HEAD: Final = 8190
"""A request head longer than this goes to the full handler, which applies its own limits
(8190 bytes a line)."""
LEAN_FIELDS: Final = frozenset(
    {
        "host",
        "range",
        "if-range",
        "if-match",
        "if-none-match",
        "if-modified-since",
        "if-unmodified-since",
        "user-agent",
        "accept",
        "accept-encoding",
        "accept-language",
        "connection",
        "origin",
        "referer",
        "cache-control",
        "pragma",
        "dnt",
        "priority",
        "sec-fetch-site",
        "sec-fetch-mode",
        "sec-fetch-dest",
        "sec-ch-ua",
        "sec-ch-ua-mobile",
        "sec-ch-ua-platform",
    }
)
"""Header fields the lean path understands; any other (a body, an upgrade, a proxy header)
sends the request to the full handler."""
_SEGMENT = r"[A-Za-z0-9._~!$&'()*+,;=:@-]+"
_FILE = re.compile(rf"/files/((?:{_SEGMENT}/)*{_SEGMENT})")
_CHUNK = re.compile(rf"/v1/scenes/((?:{_SEGMENT}/)*{_SEGMENT})/chunks/([0-9]{{1,9}})\.sog")
_VERSION = re.compile(r"v=([0-9a-f]{64})")
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")
_NEVER_LEAN = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\xff]|\r[^\n]|(?<!\r)\n|\n[ \t]")
"""Bytes no lean head holds, seen before the head ends: a control byte or non-ASCII, a bare
CR, a bare LF, an obs-fold continuation line. RFC 9112 §2.2 lets a recipient take a bare LF
as a line end (MAY) and makes a bare CR invalid or a space; we take neither leniency: the head
goes at once to aiohttp's parser, which refuses both (400, connection closed), so the lean and
full paths agree and no proxy in front can read one message where we read another (request
smuggling, RFC 9112 §11.2)."""


@dataclass(frozen=True, slots=True)
class Head:
    """A parsed request head the lean path may answer; ``fields`` keyed ``Title-Case``."""

    path: str
    query: str
    target: str
    fields: dict[str, str]


def parse_head(raw: bytes) -> Head | None:
    """The head of ``GET <target> HTTP/1.1`` with only :data:`LEAN_FIELDS`, each once, in
    printable ASCII, a Host, and a keep-alive connection; None for anything else."""
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        return None
    if _CONTROL.search(text.replace("\r\n", "")):
        return None
    lines = text.split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or parts[0] != "GET" or parts[2] != "HTTP/1.1":
        return None
    fields: dict[str, str] = {}
    for line in lines[1:]:
        name, colon, value = line.partition(":")
        name = name.lower()
        if not colon or name not in LEAN_FIELDS or name.title() in fields:
            return None
        fields[name.title()] = value.strip(" \t")
    if "Host" not in fields or fields.get("Connection", "keep-alive").lower() != "keep-alive":
        return None
    path, _, query = parts[1].partition("?")
    return Head(path, query, parts[1], fields)


def may_be_lean(start: bytes) -> bool:
    """Whether a request whose first bytes are ``start`` may still be one for the lean path
    (so the full handler answers garbage, TLS, other methods and malformed heads at once, as
    it would, instead of the lean path waiting for a ``CRLF CRLF`` that may never come)."""
    if len(start) > MAX_HEAD or not (start.startswith(b"GET ") or b"GET ".startswith(start)):
        return False
    if _NEVER_LEAN.search(start):
        return False
    line, *fields = start.split(b"\r\n")
    if fields and not line.endswith(b" HTTP/1.1"):
        return False
    ended = fields[:-1]  # the field lines already ended (the last may still be coming)
    return len(ended) <= len(LEAN_FIELDS) and all(_lean_name(f) for f in ended)


def _lean_name(line: bytes) -> bool:
    """Whether a field line names one of :data:`LEAN_FIELDS`."""
    name, colon, _ = line.partition(b":")
    return bool(colon) and name.decode("ascii").lower() in LEAN_FIELDS


@dataclass(frozen=True, slots=True)
class Found:
    """What a lean request asks for: the representation, its Cache-Control, and its file,
    open (the caller closes ``fd``)."""

    rep: Representation
    cache_control: str
    fd: int


class Lean:
    """The lean path of one application: its catalog, privacy, limits and load, the full
    handler's protocol factory to hand connections to, and what it learnt of files and scenes
    (each entry checked against the ``fstat`` of the file it opens, every request)."""

    def __init__(self, app: web.Application, full: Callable[[], asyncio.Protocol]) -> None:
        self.catalog: Catalog = app[CATALOG]
        self.privacy: Privacy = app[PRIVACY]
        self.limits: Limits = app[LIMITS]
        self.load: Load = app[LOAD]
        self.full = full
        self.root = str(self.catalog.root)
        self.files: dict[str, tuple[FileVersion, Representation]] = {}
        self.scenes: dict[str, tuple[FileVersion, SceneEntry]] = {}
        self.heads: dict[tuple[str, float, str, str], str] = {}
        self.answered = 0
        """Requests answered on the lean path (in this process)."""
        self.handed_over = 0
        """Connections handed to the full handler."""

    def find(self, head: Head) -> Found | None:
        """The open file and representation ``head`` asks for, when the lean path may send
        it: public, already known to the catalog, named plainly, no symlink below the root;
        None otherwise (the full handler answers)."""
        try:
            if match := _FILE.fullmatch(head.path):
                return None if head.query else self._file(match[1])
            if match := _CHUNK.fullmatch(head.path):
                return self._chunk(match[1], int(match[2]), head.query)
        except (TsogError, OSError):
            return None  # missing, malformed, not found: the full handler says which
        return None

    def _file(self, rel: str) -> Found | None:
        """A public file whose ETag the catalog knows."""
        if self.privacy.is_private(rel):
            return None
        fd, version = self._open(rel)
        known = self.files.get(rel)
        if known is None or known[0] != version:
            rep = self.catalog.file_if_known(rel)
            if rep is None or (rep.length, rep.mtime) != (version.size, version.mtime_ns / 1e9):
                return _closed(fd)
            remember(self.files, rel, known := (version, rep))
        return Found(known[1], REVALIDATE, fd)

    def _chunk(self, scene_id: str, n: int, query: str) -> Found | None:
        """A chunk of a public container the catalog has open, at the version the query names
        (if it names one). Chunks of unpacked scenes take the full handler."""
        sha = _VERSION.fullmatch(query) if query else None
        if (query and sha is None) or self.private_scene(scene_id):
            return None
        fd, version = self._open(scene_id + CONTAINER_SUFFIX)
        known = self.scenes.get(scene_id)
        if known is None or known[0] != version:
            scene = self.catalog.scene_if_known(scene_id)
            if scene is None or not scene.packed or scene.size != version.size:
                return _closed(fd)
            remember(self.scenes, scene_id, known := (version, scene))
        try:
            rep = self.catalog.chunk(known[1], n)
        except TsogError:
            return _closed(fd)
        if sha is not None and f'"{sha[1]}"' != rep.etag:
            return _closed(fd)
        return Found(rep, IMMUTABLE if sha else REVALIDATE, fd)

    def _open(self, rel: str) -> tuple[int, FileVersion]:
        """Open the regular file ``rel`` beneath the root (no symlink on the way) and read its
        version from the open descriptor; TsogError or OSError when it cannot be."""
        self.catalog.check_only(rel)
        check_relative(rel)
        fd = open_fd_beneath(self.root, rel)
        try:
            return fd, version_of(os.fstat(fd), rel)
        except BaseException:
            os.close(fd)
            raise

    def private_scene(self, scene_id: str) -> bool:
        """Whether the id (as asked) names a private scene."""
        return any(self.privacy.is_private(r) for r in (scene_id + CONTAINER_SUFFIX, scene_id))

    def static_headers(self, rep: Representation, cache_control: str) -> str:
        """The header lines every answer for ``rep`` carries (validators, type, server, CORS),
        formatted once per representation."""
        key = (rep.etag, rep.mtime, rep.content_type, cache_control)
        lines = self.heads.get(key)
        if lines is None:
            headers = validators(rep, cache_control)
            headers |= {"Content-Type": rep.content_type, "Server": SERVER_SOFTWARE, **CORS}
            lines = "".join(f"{k}: {v}\r\n" for k, v in headers.items())
            remember(self.heads, key, lines)
        return lines


def _closed(fd: int) -> Found | None:
    """Close ``fd``: nothing found after all."""
    os.close(fd)
    return None


@dataclass(frozen=True, slots=True)
class Answer:
    """A response the lean path sends: the head's bytes, then ``span`` of the file."""

    head: bytes
    span: ByteRange
    status: int


STATUS_LINES: Final = {200: "HTTP/1.1 200 OK\r\n", 206: "HTTP/1.1 206 Partial Content\r\n"}


def plan_answer(head: Head, rep: Representation, static: str) -> Answer | None:
    """The 200 or single-range 206 the full handler would send (sans-I/O), ``static`` being
    :meth:`Lean.static_headers`; None when it would answer otherwise (304, 412, 416,
    multipart)."""
    if evaluate("GET", head.fields, rep.etag, rep.mtime) is not Outcome.PROCEED:
        return None
    verdict = parse_range(head.fields.get("Range"), rep.length)
    if not if_range_allows(head.fields.get("If-Range"), rep.etag, rep.mtime):
        verdict = Ignore("If-Range does not match")
    if isinstance(verdict, Serve) and len(verdict.ranges) == 1:
        span, status = verdict.ranges[0], 206
        extra = f"Content-Range: {content_range(span, rep.length)}\r\n"
    elif isinstance(verdict, Ignore):
        span, status, extra = ByteRange(0, rep.length), 200, ""
    else:
        return None
    text = (
        f"{STATUS_LINES[status]}{static}{extra}Content-Length: {span.length}\r\n"
        f"Date: {_now()}\r\n\r\n"
    )
    return Answer(text.encode("latin-1"), span, status)


_DATE: list[tuple[int, str]] = [(0, "")]


def _now() -> str:
    """The Date header value, formatted once a second."""
    second = int(time.time())
    if _DATE[0][0] != second:
        _DATE[0] = (second, http_date(second))
    return _DATE[0][1]


class LeanProtocol(asyncio.Protocol):
    """One connection on the lean path until a request needs the full handler."""

    def __init__(self, lean: Lean, connections: set[LeanProtocol]) -> None:
        self.lean = lean
        self.connections = connections
        self.transport: asyncio.Transport | None = None
        self.buffer = bytearray()  # dropping answered heads from its front costs no copy
        self.client = ""
        self.busy: asyncio.Future[None] | None = None
        self.idle: asyncio.TimerHandle | None = None
        self.eof = False
        self.closing = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.connections.add(self)
        peer = transport.get_extra_info("peername")
        self.client = str(peer[0]) if isinstance(peer, tuple) else ""
        sock = transport.get_extra_info("socket")
        if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._wait_idle()

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        if self.busy is None:
            self._answer_buffered()

    def eof_received(self) -> bool:
        self.eof = True
        if self.busy is None:
            self._answer_buffered()
        return True  # closed by us once every buffered request is answered

    def connection_lost(self, exc: Exception | None) -> None:
        self.connections.discard(self)
        self._stop_idle()
        if self.busy is not None:
            self.busy.cancel()

    def close_when_idle(self) -> None:
        """Shutting down: close now if no response is being sent, else after it."""
        self.closing = True
        if self.busy is None and self.transport is not None:
            self.transport.close()

    def _answer_buffered(self) -> None:
        """Answer complete requests in the buffer, in order, until one must wait (a body the
        socket does not take at once, an ETag or scene not known yet) or goes elsewhere."""
        while self.transport is not None and not self.transport.is_closing():
            end = self.buffer.find(b"\r\n\r\n")
            if end < 0:
                if not may_be_lean(bytes(self.buffer[: MAX_HEAD + 1])) or (
                    self.eof and self.buffer
                ):
                    self._hand_over()
                elif self.eof or self.closing:
                    self.transport.close()
                return
            head = parse_head(bytes(self.buffer[:end])) if end <= MAX_HEAD else None
            found = self.lean.find(head) if head is not None else None
            if head is None or found is None:
                if head is not None and self._may_learn(head):
                    self._start(self._learn(head))
                else:
                    self._hand_over()
                return
            static = self.lean.static_headers(found.rep, found.cache_control)
            answer = plan_answer(head, found.rep, static)
            if answer is None or self._refused():
                os.close(found.fd)
                self._hand_over()  # the full handler answers (304, 412, 416, 503)
                return
            del self.buffer[: end + 4]
            if not self._send(head, answer, found):
                return

    def _refused(self) -> bool:
        """Whether the load caps refuse this client now (the full handler answers 503)."""
        return self.lean.load.refuses(self.client, self.lean.limits) is not None

    def _may_learn(self, head: Head) -> bool:
        """Whether a public file or scene may only be unknown yet (worth one lookup, then
        lean); private and signed requests never make the catalog read anything here."""
        if match := _FILE.fullmatch(head.path):
            return not head.query and not self.lean.privacy.is_private(match[1])
        if match := _CHUNK.fullmatch(head.path):
            return not self.lean.private_scene(match[1])
        return False

    async def _learn(self, head: Head) -> None:
        """Have the catalog hash the file or open the scene (once, shared with the full
        handler), so this and later requests stay lean; errors go to the full handler."""
        catalog = self.lean.catalog
        try:
            if match := _FILE.fullmatch(head.path):
                await catalog.file(match[1])
            elif match := _CHUNK.fullmatch(head.path):
                await catalog.scene(match[1])
        except (TsogError, OSError):
            pass
        found = self.lean.find(head)
        if found is None:
            self._hand_over()
        else:
            os.close(found.fd)  # opened again when the request is answered

    def _send(self, head: Head, answer: Answer, found: Found) -> bool:
        """Send one answer from the open file; True when it went out whole at once."""
        assert self.transport is not None
        self._stop_idle()
        load, started = self.lean.load, time.monotonic()
        load.enter(self.client)
        self.transport.write(answer.head)
        span = ByteRange.sized(found.rep.offset + answer.span.start, answer.span.length)
        try:
            sent = sendfile_now(self.transport, found.fd, span) if span.length else 0
        except ConnectionError:
            sent = -1
        if 0 <= sent < span.length:
            rest = ByteRange(span.start + sent, span.end)
            file = os.fdopen(found.fd, "rb")
            self._start(self._send_rest(file, rest, head, answer, started))
            return False
        os.close(found.fd)
        load.leave(self.client)
        if sent < 0:
            self.transport.abort()
            return False
        self._served(head, answer, started)
        return True

    async def _send_rest(
        self, file: BinaryIO, rest: ByteRange, head: Head, answer: Answer, started: float
    ) -> None:
        """What the socket did not take at once, under the send deadline and stall timeout
        (the connection is dropped when either passes, as on the full path)."""
        assert self.transport is not None
        limits = self.lean.limits
        try:
            async with asyncio.timeout(limits.send_timeout_s):
                stall = limits.stall_timeout_s
                await sendfile_slices(self.transport, file, rest, stall, fallback=True)
        except (TimeoutError, OSError):  # stalled, gone, or the file shrank
            self.transport.abort()
            return
        finally:
            file.close()
            self.lean.load.leave(self.client)
        self._served(head, answer, started)

    def _start(self, work: Coroutine[Any, Any, None]) -> None:
        """Run ``work`` with reading paused; then answer what is buffered."""
        assert self.transport is not None
        self.transport.pause_reading()
        self.busy = asyncio.ensure_future(work)
        self.busy.add_done_callback(self._resume)

    def _resume(self, done: asyncio.Future[None]) -> None:
        """After waiting work: read again and go on answering (unless handed over or gone)."""
        self.busy = None
        if done.cancelled() or self.transport is None or self.transport.is_closing():
            return
        if self.transport.get_protocol() is not self:
            return
        self.transport.resume_reading()
        self._wait_idle()
        self._answer_buffered()

    def _served(self, head: Head, answer: Answer, started: float) -> None:
        """Count and log the request (when the access log is on); wait for the next one."""
        self.lean.answered += 1
        if access_logger.isEnabledFor(logging.INFO):
            served = Served(
                self.client,
                "GET",
                head.target,
                (1, 1),
                answer.status,
                len(answer.head) + answer.span.length,  # as aiohttp counts: head and body
                time.monotonic() - started,
                head.fields.get("Range"),
                head.fields.get("User-Agent"),
            )
            log_served(access_logger, served)
        self._wait_idle()

    def _hand_over(self) -> None:
        """Give the connection and every buffered byte to the full handler for good."""
        assert self.transport is not None
        self._stop_idle()
        self.connections.discard(self)
        self.lean.handed_over += 1
        full = self.lean.full()
        self.transport.set_protocol(full)
        full.connection_made(self.transport)
        if self.buffer:
            full.data_received(bytes(self.buffer))
        self.buffer.clear()
        if self.eof:
            full.eof_received()
        self.transport.resume_reading()
        self.transport = None

    def _wait_idle(self) -> None:
        """Close the connection if no request comes within the keep-alive time."""
        self._stop_idle()
        if self.transport is not None:
            loop = asyncio.get_running_loop()
            self.idle = loop.call_later(self.lean.limits.keepalive_s, self._idle_close)

    def _stop_idle(self) -> None:
        if self.idle is not None:
            self.idle.cancel()
            self.idle = None

    def _idle_close(self) -> None:
        if self.busy is None and self.transport is not None:
            self.transport.close()


class LeanSite(web.TCPSite):
    """A TCP site whose connections start on the lean path (see the module docstring)."""

    def __init__(self, runner: web.AppRunner, host: str, port: int, *, reuse_port: bool) -> None:
        super().__init__(runner, host, port, reuse_port=reuse_port or None)
        self.lean_connections: set[LeanProtocol] = set()
        self.lean: Lean | None = None

    async def start(self) -> None:
        await web.BaseSite.start(self)
        runner = self._runner
        assert isinstance(runner, web.AppRunner) and runner.server is not None
        self.lean = lean = Lean(runner.app, runner.server)
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: LeanProtocol(lean, self.lean_connections),
            self._host,
            self._port,
            backlog=self._backlog,
            reuse_address=self._reuse_address,
            reuse_port=self._reuse_port,
        )
        self._bound_port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        await super().stop()
        for protocol in list(self.lean_connections):
            protocol.close_when_idle()


__all__ = ["LEAN_FIELDS", "Head", "LeanSite", "parse_head", "plan_answer"]
