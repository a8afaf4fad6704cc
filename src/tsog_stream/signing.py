"""Signed, expiring URLs for private scenes (docs/http.md, "Private scenes").

A signed URL carries three query parameters: ``expires`` (Unix seconds), ``scope`` (a URL path:
the exact path, or a prefix ending with ``/`` that covers everything below it) and
``signature``, the unpadded base64url HMAC-SHA256 under the server secret of
``"tsog-url-v1\\n{expires}\\n{scope}"``. Paths are compared percent-decoded, and a path with
``.`` or ``..`` segments, empty segments or a backslash is never covered (so a prefix cannot be
climbed out of, whoever normalises the URL). Sans-I/O: strings in, verdicts out.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import re
from collections.abc import Mapping
from urllib.parse import parse_qsl, unquote, urlencode, urlsplit, urlunsplit

from .errors import AccessError, InputError

SCHEME = "tsog-url-v1"
EXPIRES, SCOPE, SIGNATURE = "expires", "scope", "signature"
SIGNED_PARAMS = (EXPIRES, SCOPE, SIGNATURE)
SECRET_ENV = "TSOG_URL_SECRET"
SECRET_FILE_ENV = "TSOG_URL_SECRET_FILE"
MIN_SECRET_BYTES = 16
MAX_SECRET_BYTES = 4096
REDACTED = "REDACTED"
_EXPIRES = re.compile(r"[0-9]{1,12}")
_SIGNATURE = re.compile(r"[A-Za-z0-9_-]{43}")
_TTL = re.compile(r"([0-9]+)([smhd]?)")
_TTL_UNITS = {"": 1, "s": 1, "m": 60, "h": 3600, "d": 86400}


def load_secret(
    secret_file: str | os.PathLike[str] | None = None, environ: Mapping[str, str] = os.environ
) -> bytes | None:
    """The server secret: ``secret_file``, else ``$TSOG_URL_SECRET_FILE``, else
    ``$TSOG_URL_SECRET``; None when none is set. Trailing newlines of a file are dropped."""
    path = secret_file or environ.get(SECRET_FILE_ENV)
    if path:
        where = str(path)
        try:
            with open(path, "rb") as f:
                raw = f.read(MAX_SECRET_BYTES + 1).rstrip(b"\r\n")
        except OSError as exc:
            raise InputError(f"cannot read the URL secret: {exc.strerror}", where=where) from exc
    elif SECRET_ENV in environ:
        raw, where = environ[SECRET_ENV].encode(), f"${SECRET_ENV}"
    else:
        return None
    if not MIN_SECRET_BYTES <= len(raw) <= MAX_SECRET_BYTES:
        raise InputError(
            f"the URL secret must be {MIN_SECRET_BYTES}-{MAX_SECRET_BYTES} bytes, got {len(raw)}"
            " (make one with: head -c 32 /dev/urandom | base64)",
            where=where,
        )
    return raw


def signature(secret: bytes, scope: str, expires: int) -> str:
    """The signature of (scope, expires) under ``secret``."""
    message = f"{SCHEME}\n{expires}\n{scope}".encode()
    digest = hmac.new(secret, message, hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def decoded_path(raw_path: str) -> str:
    """The percent-decoded path of a URL or request target (query dropped)."""
    return unquote(raw_path.partition("?")[0].partition("#")[0])


def _plain(path: str) -> bool:
    """True for an absolute path without dot, empty or backslash segments."""
    parts = path.split("/")[1:]
    return (
        path.startswith("/")
        and "\\" not in path
        and "\x00" not in path
        and all(p not in (".", "..") for p in parts)
        and "" not in parts[:-1]
    )


def covers(scope: str, path: str) -> bool:
    """Whether a signed ``scope`` covers the decoded request ``path``."""
    if not (_plain(scope) and _plain(path)):
        return False
    return path == scope or (scope.endswith("/") and path.startswith(scope))


def sign_url(url: str, secret: bytes, expires: int, scope: str | None = None) -> str:
    """``url`` with the signed parameters added (replacing any it had).

    ``scope`` defaults to the URL's own path; a prefix ending with ``/`` signs a whole folder
    or scene (a player fetching many chunk URLs needs that).
    """
    parts = urlsplit(url)
    path = decoded_path(parts.path)
    scope = path if scope is None else scope
    if not covers(scope, path):
        raise InputError(
            "the scope must be the URL's path or a prefix of it ending with '/'", where=scope
        )
    kept = [q for q in parse_qsl(parts.query, keep_blank_values=True) if q[0] not in SIGNED_PARAMS]
    query = urlencode(kept + signing_params(secret, scope, expires), safe="/")
    return urlunsplit(parts._replace(query=query))


def signing_params(secret: bytes, scope: str, expires: int) -> list[tuple[str, str]]:
    """The query parameters that sign ``scope`` (a path, or a prefix ending with '/') until
    ``expires`` (Unix seconds)."""
    return [(EXPIRES, str(expires)), (SCOPE, scope), (SIGNATURE, signature(secret, scope, expires))]


def check_signed(path: str, query: Mapping[str, str], secret: bytes, now: float) -> None:
    """Accept a request for decoded ``path`` with these query parameters, or raise AccessError.

    The signature is compared in constant time; the message says which check failed but
    never echoes the signature.
    """
    expires, scope, sig = (query.get(k) for k in SIGNED_PARAMS)
    if expires is None or sig is None:
        raise AccessError("this scene is private: a signed URL is required", where=path[:80])
    scope = path if scope is None else scope
    if not _EXPIRES.fullmatch(expires) or not _SIGNATURE.fullmatch(sig):
        raise AccessError("malformed signed URL parameters", where=path[:80])
    if not covers(scope, path):
        raise AccessError("the signed URL does not cover this path", where=path[:80])
    if not hmac.compare_digest(sig.encode(), signature(secret, scope, int(expires)).encode()):
        raise AccessError("bad signature", where=path[:80])
    if now >= int(expires):
        raise AccessError("the signed URL has expired; ask for a new one", where=path[:80])


def signed_params(query: Mapping[str, str]) -> dict[str, str]:
    """The signed-URL parameters present in ``query`` (to carry them to derived URLs)."""
    return {k: query[k] for k in SIGNED_PARAMS if k in query}


def redact_url(url: str) -> str:
    """``url`` (or a request target) with any ``signature`` value replaced by REDACTED."""
    if SIGNATURE not in url:
        return url
    return re.sub(rf"([?&;]{SIGNATURE}=)[^&;#\s]*", rf"\g<1>{REDACTED}", url)


def parse_ttl(text: str) -> int:
    """Seconds from ``3600``, ``90s``, ``15m``, ``12h`` or ``7d`` (InputError otherwise)."""
    match = _TTL.fullmatch(text.strip())
    if match is None or int(match.group(1)) == 0:
        raise InputError(f"expected a duration like 3600, 90s, 15m, 12h or 7d, got {text!r}")
    return int(match.group(1)) * _TTL_UNITS[match.group(2)]
