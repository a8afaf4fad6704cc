"""Private scenes: which paths need a signed URL, the one decision per request, a redacting log.

A path (relative to the served root) is private when a ``--private`` glob matches it or one of
its parent folders (``*`` also crosses ``/``). :func:`admitted` decides each request once, on
the paths as asked and the one they resolve to (after symlinks); a lookup that fails answers
only after the paths as asked were admitted, so a missing private file and an existing one
answer alike (403). ``GET /v1/authorize`` lets a proxy in front (nginx ``auth_request``) apply
the same check to its own URLs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import PurePosixPath
from typing import TypeVar
from urllib.parse import parse_qsl, urlencode, urlsplit

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger

from ..constants import THUMBNAIL_SUFFIX
from ..errors import InputError, TsogError
from ..signing import MIN_SECRET_BYTES, check_signed, decoded_path, redact_url, signed_params

ORIGINAL_URI = "X-Original-URI"
MAX_LOGGED_HEADER = 200
SIGNED = web.RequestKey("signed", bool)
"""Set on a request that its signature admitted to a private path (the one decision's outcome)."""
_T = TypeVar("_T")


@dataclass(frozen=True, slots=True)
class Privacy:
    """The private-path globs of a server and the secret that signs their URLs."""

    patterns: tuple[str, ...] = ()
    secret: bytes | None = None
    clock: Callable[[], float] = field(default=time.time, compare=False)

    def __post_init__(self) -> None:
        if self.patterns and self.secret is None:
            raise InputError(
                "private scenes need a URL secret: set $TSOG_URL_SECRET_FILE or "
                "$TSOG_URL_SECRET, or pass --secret-file",
                where="--private",
            )
        if self.secret is not None and len(self.secret) < MIN_SECRET_BYTES:
            raise InputError(f"the URL secret must be at least {MIN_SECRET_BYTES} bytes")

    def is_private(self, rel: str) -> bool:
        """Whether the root-relative path ``rel`` (or a folder above it) is private; a
        thumbnail is private when the container or manifest it shows is."""
        if not self.patterns:
            return False
        path = PurePosixPath(rel)
        candidates = [path.as_posix()] + [p.as_posix() for p in path.parents if p.name]
        if rel.endswith(THUMBNAIL_SUFFIX):
            candidates.append(rel.removesuffix(THUMBNAIL_SUFFIX))
        return any(fnmatchcase(c, p) for c in candidates for p in self.patterns)

    def admit(self, request: web.Request, rels: Iterable[str]) -> None:
        """Let the request through, or raise AccessError when one of ``rels`` is private and
        the request's signed URL does not hold; marks a request its signature admitted."""
        if any(self.is_private(r) for r in rels):
            secret = self.secret or b""  # never empty here: __post_init__ demands one
            check_signed(decoded_path(request.raw_path), request.query, secret, self.clock())
            request[SIGNED] = True


PRIVACY = web.AppKey("privacy", Privacy)


async def admitted(
    request: web.Request, asked: list[str], find: Awaitable[_T], rel_of: Callable[[_T], str]
) -> _T:
    """What ``find`` looks up, once the request is admitted (one :meth:`Privacy.admit` per
    request) for the paths ``asked`` and the one ``rel_of`` says the lookup found; a failed
    lookup is raised only after ``asked`` was admitted."""
    privacy = request.app[PRIVACY]
    try:
        found = await find
    except TsogError:
        privacy.admit(request, asked)
        raise
    privacy.admit(request, [*asked, rel_of(found)])
    return found


def is_signed(request: web.Request) -> bool:
    """Whether this request was admitted to a private path by its signature."""
    return request.get(SIGNED) is True


def signed_suffix(request: web.Request) -> str:
    """``&expires=..&scope=..&signature=..`` for URLs handed out to a signed request, else ''."""
    if not is_signed(request):
        return ""
    return "&" + urlencode(signed_params(request.query), safe="/")


async def mark_private_responses(request: web.Request, response: web.StreamResponse) -> None:
    """Responses to signed requests must not be stored by shared caches."""
    cache = response.headers.get("Cache-Control")
    if is_signed(request) and cache is not None:
        response.headers["Cache-Control"] = cache.replace("public", "private")


async def authorize(request: web.Request) -> web.StreamResponse:
    """GET /v1/authorize: 204 when ``X-Original-URI`` carries a valid signature, else 403."""
    secret = request.app[PRIVACY].secret
    if secret is None:
        raise web.HTTPNotFound(reason="no URL secret configured on this server")
    target = request.headers.get(ORIGINAL_URI)
    if target is None:
        raise InputError(f"the {ORIGINAL_URI} header is required (nginx auth_request)")
    parts = urlsplit(target)
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    check_signed(decoded_path(parts.path), query, secret, request.app[PRIVACY].clock())
    return web.Response(status=204, headers={"Cache-Control": "no-store"})


def _clip(value: str | None) -> str:
    """A header value for the log: '-' when absent, cut to MAX_LOGGED_HEADER characters."""
    if value is None:
        return "-"
    return value[:MAX_LOGGED_HEADER].replace('"', "'")


class AccessLog(AbstractAccessLogger):
    """aiohttp's access logger: one line a request, signatures in the target redacted:
    ``addr "METHOD target HTTP/x.y" status bytes bytes seconds s "Range" "User-Agent"``."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        """Write the line for one finished request."""
        self.logger.info(
            '%s "%s %s HTTP/%d.%d" %d %d bytes %.6f s "%s" "%s"',
            request.remote,
            request.method,
            _clip(redact_url(request.path_qs)),
            *request.version,
            response.status,
            response.body_length,
            time,
            _clip(request.headers.get("Range")),
            _clip(request.headers.get("User-Agent")),
        )

    @property
    def enabled(self) -> bool:
        """Skip formatting when INFO is off."""
        return self.logger.isEnabledFor(logging.INFO)
