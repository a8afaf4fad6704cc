"""``HttpSource``: the :class:`ByteSource` protocol over HTTP single-range GET requests.

Every read is one ``GET`` with ``Range: bytes=a-b`` (RFC 9110 §14.2) and
``Accept-Encoding: identity``; a response is used only when its status is 206, its
``Content-Range`` (RFC 9110 §14.4) is exactly the range asked for and names the file's length,
and its body has that many bytes. The first response teaches the file's length and its strong
ETag; later requests carry ``If-Match: <etag>`` so a file replaced on the server fails with a
412 (a SourceError), never a silent mix of two versions. Transient failures are retried by
one policy (:func:`with_retries`), a truncated body resuming from the last byte received. An
origin that ignores ``Range`` (200 with the whole file) is tolerated for small files (kept in
memory) and refused for large ones. ``HttpFiles`` does whole-file GETs the same way. See
docs/client.md.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Awaitable, Callable
from typing import TypeVar

import aiohttp
from tenacity import (
    AsyncRetrying,
    retry_if_exception_type,
    stop_after_attempt,
    stop_before_delay,
    wait_exponential,
)

from ..container.header import PREFIX_SIZE
from ..container.ranges import ByteRange
from ..container.sources import ReadStats
from ..errors import AccessError, SourceError
from ..signing import redact_url
from .http_options import HttpOptions

_CONTENT_RANGE = re.compile(r"^bytes (\d+)-(\d+)/(\d+)$")
_UNSATISFIED = re.compile(r"^bytes \*/(\d+)$")
_MAX_ERROR_BODY = 4096
_PIECE = 64 * 1024
T = TypeVar("T")


class _RetryableError(Exception):
    """A transient failure (5xx) worth another attempt."""


RETRYABLE = (aiohttp.ClientError, TimeoutError, ConnectionError, _RetryableError)
"""Failures worth another attempt: refused or reset connections (a server restarting),
bodies cut short, timeouts and 5xx answers."""


def retry_policy(options: HttpOptions) -> AsyncRetrying:
    """The client's one retry policy: RETRYABLE failures only, waits doubling from
    ``backoff_s`` up to ``max_backoff_s``, at most ``retries`` more attempts, and no wait that
    would end past ``deadline_s`` from the first attempt (better to fail now than at it)."""
    return AsyncRetrying(
        retry=retry_if_exception_type(RETRYABLE),
        wait=wait_exponential(multiplier=options.backoff_s, max=options.max_backoff_s),
        stop=stop_after_attempt(options.retries + 1) | stop_before_delay(options.deadline_s),
        reraise=True,
    )


async def with_retries(
    options: HttpOptions, attempt: Callable[[], Awaitable[T]], what: Callable[[], str], where: str
) -> T:
    """``attempt()`` under :func:`retry_policy`, all within ``options.deadline_s``: an attempt
    still running then is cancelled. Giving up is one SourceError line; ``what()`` names what
    is being read (it may change as a body resumes)."""
    policy = retry_policy(options)
    try:
        async with asyncio.timeout(options.deadline_s) as limit:
            return await policy(attempt)
    except RETRYABLE as exc:
        tries = int(policy.statistics.get("attempt_number", 1))
        cut = limit.expired()
        attempts = f"{tries} attempt{'s' if tries > 1 else ''}"
        reason = "still unfinished at the deadline" if cut else str(exc) or type(exc).__name__
        if tries > options.retries and not cut:
            raise SourceError(f"{what()} failed after {attempts}: {reason}", where=where) from exc
        raise SourceError(
            f"{what()} not received within {options.deadline_s:g} s ({attempts}, the last "
            f"{reason}; see --timeout)",
            where=where,
        ) from exc


def new_session(options: HttpOptions) -> aiohttp.ClientSession:
    """A client session with the options' per-attempt timeouts (the deadline of a whole read
    is :func:`with_retries`'s) and no transparent decompression."""
    timeout = aiohttp.ClientTimeout(
        total=None, sock_connect=options.connect_timeout_s, sock_read=options.read_timeout_s
    )
    return aiohttp.ClientSession(timeout=timeout, auto_decompress=False)


class _Http:
    """A session made on first use (inside the running event loop), with its read counters."""

    def __init__(self, options: HttpOptions | None, session: aiohttp.ClientSession | None) -> None:
        self.options = options or HttpOptions()
        self.stats = ReadStats()
        self._session = session
        self._owns_session = session is None

    def _client(self) -> aiohttp.ClientSession:
        if self._session is None:
            self._session = new_session(self.options)
        return self._session

    async def aclose(self) -> None:
        """Close the HTTP session if this object created it."""
        if self._session is not None and self._owns_session:
            await self._session.close()
        self._session = None

    async def _body(
        self, resp: aiohttp.ClientResponse, got: bytearray, length: int, where: str, *, exact: bool
    ) -> None:
        """Append the body to ``got``, counting bytes on the wire: more than ``length`` bytes
        is a SourceError, fewer (when ``exact``) a cut-off body to retry."""
        received = 0
        async for piece in resp.content.iter_chunked(_PIECE):
            received += len(piece)
            self.stats.bytes += len(piece)
            if received > length:
                raise SourceError(f"expected at most {length} bytes, got more", where=where)
            got += piece
        if exact and received < length:
            raise aiohttp.ClientPayloadError(f"body ended after {received} of {length} bytes")


class HttpSource(_Http):
    """Random access to one file on an HTTP server, pinned to the version first seen."""

    def __init__(
        self,
        url: str,
        options: HttpOptions | None = None,
        *,
        session: aiohttp.ClientSession | None = None,
    ) -> None:
        super().__init__(options, session)
        self.url = url
        self.name = redact_url(url)  # for messages: a signature is never shown
        self.etag: str | None = None
        self._size: int | None = None
        self._head = b""  # bytes from the first request, served again without a request
        self._copy: bytes | None = None  # the whole file, when the origin ignores ranges
        self._lock = asyncio.Lock()

    async def size(self) -> int:
        """Length of the file, learnt from the first request (which also fetches its prefix)."""
        async with self._lock:
            if self._size is None:
                self._head = await self._fetch(ByteRange(0, PREFIX_SIZE), probe=True)
                if self._size is None:  # the first answer always sets it; keeps mypy honest
                    raise SourceError("the server sent no file length", where=self.name)
            return self._size

    async def read(self, span: ByteRange) -> bytes:
        """Exactly the bytes of ``span``: from memory as far as already received, the rest with
        one GET."""
        size = await self.size()
        if not span.within(size):
            raise SourceError(
                f"asked for bytes [{span.start}, {span.end}) of a {size}-byte file", where=self.name
            )
        if span.length == 0:
            return b""
        if self._copy is not None:
            return self._copy[span.start : span.end]
        held = len(self._head)
        if span.end <= held:
            return self._head[span.start : span.end]
        if span.start < held:  # a compact container's first chunk begins in the first request
            rest = await self._fetch(ByteRange(held, span.end), probe=False)
            return self._head[span.start :] + rest
        return await self._fetch(span, probe=False)

    async def _fetch(self, span: ByteRange, *, probe: bool) -> bytes:
        """GET ``span`` with retries, each attempt resuming after the bytes already received."""
        got = bytearray()

        async def attempt() -> bytes:
            rest = ByteRange(span.start + len(got), span.end)
            self.stats.requests += 1
            async with self._client().get(self.url, headers=self._headers(rest)) as resp:
                await self._receive(resp, rest, got, probe=probe)
            return bytes(got)

        def what() -> str:
            return f"bytes [{span.start}, {span.end})" + (f" ({len(got)} came)" if got else "")

        return await with_retries(self.options, attempt, what, self.name)

    def _headers(self, span: ByteRange) -> dict[str, str]:
        """Request headers: one range, no compression, pinned to the known version."""
        headers = {"Range": span.http_header(), "Accept-Encoding": "identity"}
        if self.etag is not None:
            headers["If-Match"] = self.etag
        return headers

    async def _receive(
        self, resp: aiohttp.ClientResponse, span: ByteRange, got: bytearray, *, probe: bool
    ) -> None:
        """Check one response and read its body into ``got``."""
        if resp.status == 412:
            raise SourceError(
                f"the file changed on the server (ETag {self.etag} no longer matches); "
                "reopen it to read the new version",
                where=self.name,
            )
        await _refuse_failures(resp, self.name)
        if resp.status == 200:
            await self._take_whole_file(resp, got, span)
        elif resp.status == 416 and probe:
            self._learn(_parse(_UNSATISFIED, resp, self.name)[0], resp)
        elif resp.status == 206:
            expected = self._check_range(resp, span, probe=probe)
            await self._body(resp, got, expected, self.name, exact=True)
        else:
            raise SourceError(
                f"expected HTTP 206 for Range {span.http_header()}, got {resp.status}",
                where=self.name,
            )

    def _check_range(self, resp: aiohttp.ClientResponse, span: ByteRange, *, probe: bool) -> int:
        """Validate ``Content-Range`` against the request and the file; returns the body length."""
        first, last, total = _parse(_CONTENT_RANGE, resp, self.name)
        if probe:
            self._learn(total, resp)
        want_last = min(span.end, self._size or 0) - 1
        if (first, last, total) != (span.start, want_last, self._size):
            raise SourceError(
                f"asked for bytes {span.start}-{want_last}/{self._size}, the server sent "
                f"Content-Range: {resp.headers.get('Content-Range')}",
                where=self.name,
            )
        self._check_etag(resp)
        length = last - first + 1
        declared = resp.headers.get("Content-Length")
        if declared is not None and declared != str(length):
            raise SourceError(
                f"Content-Range has {length} bytes but Content-Length says {declared}",
                where=self.name,
            )
        return length

    def _learn(self, total: int, resp: aiohttp.ClientResponse) -> None:
        """Remember the file's length and strong ETag from the first answer."""
        self._size = total
        etag = resp.headers.get("ETag")
        self.etag = etag if etag and not etag.startswith("W/") else None

    def _check_etag(self, resp: aiohttp.ClientResponse) -> None:
        """A SourceError when a pinned file answers with another ETag."""
        etag = resp.headers.get("ETag")
        if self.etag is not None and etag is not None and etag != self.etag:
            raise SourceError(
                f"the file changed on the server (ETag {self.etag}, now {etag})", where=self.name
            )

    async def _take_whole_file(
        self, resp: aiohttp.ClientResponse, got: bytearray, span: ByteRange
    ) -> None:
        """A 200 answer: keep a small file in memory, refuse a large one (never stream it)."""
        length = resp.content_length
        limit = self.options.max_unranged_bytes
        if length is None or length > limit or (self._size is not None and length != self._size):
            resp.close()
            raise SourceError(
                f"origin ignores Range requests (HTTP 200 with {length} bytes; only files up to "
                f"{limit} bytes are read whole)",
                where=self.name,
            )
        if self._size is None:
            self._learn(length, resp)
        self._check_etag(resp)
        whole = bytearray()
        await self._body(resp, whole, length, self.name, exact=True)
        self._copy = bytes(whole)
        got += self._copy[span.start : span.end]


class HttpFiles(_Http):
    """Whole-file GETs (the unpacked layout's manifest and chunks) over one shared session.

    Each file is one request with ``Accept-Encoding: identity``; only a 200 whose body has at
    most ``limit`` bytes is accepted (a longer declared length is refused unread), retried
    like :class:`HttpSource`.
    """

    def __init__(self, options: HttpOptions | None = None) -> None:
        super().__init__(options, None)

    async def get(self, url: str, limit: int) -> bytes:
        """The whole body of ``url`` (at most ``limit`` bytes)."""
        where = redact_url(url)

        async def attempt() -> bytes:
            self.stats.requests += 1
            async with self._client().get(url, headers={"Accept-Encoding": "identity"}) as resp:
                await _refuse_failures(resp, where)
                if resp.status != 200:
                    raise SourceError(f"expected HTTP 200, got {resp.status}", where=where)
                length = resp.content_length
                if length is not None and length > limit:
                    resp.close()
                    raise SourceError(f"{length} bytes, expected at most {limit}", where=where)
                body = bytearray()
                exact = length is not None  # without a declared length, a short body is whole
                await self._body(
                    resp, body, limit if length is None else length, where, exact=exact
                )
                return bytes(body)

        return await with_retries(self.options, attempt, lambda: "GET", where)


async def _refuse_failures(resp: aiohttp.ClientResponse, where: str) -> None:
    """Raise for an answer with no body to use: 5xx (retried), 403, 404/410, an encoded body."""
    if resp.status >= 500:
        raise _RetryableError(f"HTTP {resp.status} {resp.reason}")
    if resp.status == 403:
        raise AccessError(await _denial(resp), where=where)
    if resp.status in (404, 410):
        raise SourceError(f"not found (HTTP {resp.status})", where=where)
    encoding = resp.headers.get("Content-Encoding", "identity")
    if encoding.lower() != "identity":
        raise SourceError(
            f"expected an unencoded body, got Content-Encoding: {encoding}", where=where
        )


async def _denial(resp: aiohttp.ClientResponse) -> str:
    """The reason of a 403: the server's JSON error message when it sent one."""
    try:
        body = await resp.content.read(_MAX_ERROR_BODY)
        message = json.loads(body)["error"]["message"]
    except (aiohttp.ClientError, TimeoutError, ValueError, TypeError, KeyError):
        message = None
    reason = message if isinstance(message, str) else "forbidden"
    return f"HTTP 403: {reason[:200]} (private scene: open it with a valid signed URL)"


def _parse(pattern: re.Pattern[str], resp: aiohttp.ClientResponse, url: str) -> tuple[int, ...]:
    """The integers of a ``Content-Range`` header matching ``pattern``, else a SourceError."""
    value = resp.headers.get("Content-Range", "")
    m = pattern.match(value)
    if m is None:
        raise SourceError(
            f"expected Content-Range like {pattern.pattern!r}, got {value!r}", where=url
        )
    return tuple(int(g) for g in m.groups())
