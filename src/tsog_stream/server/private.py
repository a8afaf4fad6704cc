"""Private scenes: which paths need a signed URL, the check itself, and a redacting access log.

A path (relative to the served root) is private when a ``--private`` glob matches it or one of
its parent folders (``*`` also crosses ``/``). Requests for it need a valid signed URL
(:mod:`tsog_stream.signing`); both the path as asked and the path it resolves to (after
symlinks) are checked, the former before the file system is touched so that a missing private
file and an existing one answer alike (403). ``GET /v1/authorize`` lets a proxy in front
(nginx ``auth_request``) apply the same check to its own URLs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import PurePosixPath
from urllib.parse import parse_qsl, urlencode, urlsplit

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger

from ..constants import THUMBNAIL_SUFFIX
from ..errors import InputError
from ..signing import MIN_SECRET_BYTES, check_signed, decoded_path, redact_url, signed_params

ORIGINAL_URI = "X-Original-URI"
MAX_LOGGED_HEADER = 200
SIGNED = web.RequestKey("signed", bool)


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
        """Let the request through, or raise AccessError when a path is private and unsigned.

        The signature is verified once per request: it covers the request's own URL, so a
        request already admitted by it (the path as asked) is admitted for the path it resolves
        to without verifying again."""
        if is_signed(request) or not any(self.is_private(r) for r in rels):
            return
        secret = self.secret or b""  # never empty here: __post_init__ demands one with patterns
        check_signed(decoded_path(request.raw_path), request.query, secret, self.clock())
        request[SIGNED] = True


PRIVACY = web.AppKey("privacy", Privacy)


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


@dataclass(frozen=True, slots=True)
class Served:
    """What the access log says of one finished request."""

    remote: str | None
    method: str
    target: str
    version: tuple[int, int]
    status: int
    body_bytes: int
    seconds: float
    range: str | None
    user_agent: str | None


def log_served(logger: logging.Logger, served: Served) -> None:
    """Write one access-log line (signatures in the target redacted):
    ``addr "METHOD target HTTP/x.y" status bytes bytes seconds s "Range" "User-Agent"``."""
    logger.info(
        '%s "%s %s HTTP/%d.%d" %d %d bytes %.6f s "%s" "%s"',
        served.remote,
        served.method,
        _clip(redact_url(served.target)),
        *served.version,
        served.status,
        served.body_bytes,
        served.seconds,
        _clip(served.range),
        _clip(served.user_agent),
    )


class AccessLog(AbstractAccessLogger):
    """aiohttp's access logger, writing :func:`log_served` lines."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        """Write the line for one finished request."""
        v = request.version
        served = Served(
            request.remote,
            request.method,
            request.path_qs,
            (v.major, v.minor),
            response.status,
            response.body_length,
            time,
            request.headers.get("Range"),
            request.headers.get("User-Agent"),
        )
        log_served(self.logger, served)

    @property
    def enabled(self) -> bool:
        """Skip formatting when INFO is off."""
        return self.logger.isEnabledFor(logging.INFO)


__all__ = [
    "PRIVACY",
    "AccessLog",
    "Privacy",
    "Served",
    "authorize",
    "is_signed",
    "log_served",
    "signed_suffix",
]
