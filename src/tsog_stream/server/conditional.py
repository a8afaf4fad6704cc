"""Conditional requests (RFC 9110 §13), sans-I/O.

:func:`evaluate` applies the preconditions in the order of RFC 9110 §13.2.2 and says whether
to proceed, answer 304 Not Modified or 412 Precondition Failed; :func:`if_range_allows` says
whether a ``Range`` header may be honoured (§13.1.5). Our ETags are always strong.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from datetime import UTC, datetime
from email.utils import format_datetime, parsedate_to_datetime


class Outcome(enum.Enum):
    """What the preconditions decide (the value is the status to answer)."""

    PROCEED = 200
    NOT_MODIFIED = 304
    FAILED = 412


def http_date(seconds: float) -> str:
    """An IMF-fixdate (RFC 9110 §5.6.7) for a POSIX time, truncated to whole seconds."""
    return format_datetime(datetime.fromtimestamp(int(seconds), UTC), usegmt=True)


def parse_http_date(value: str) -> datetime | None:
    """A parsed HTTP date (any of the three RFC 9110 forms), or None when invalid."""
    try:
        parsed = parsedate_to_datetime(value)
    except (TypeError, ValueError, IndexError, OverflowError):  # OverflowError: a huge year
        return None
    return parsed if parsed.tzinfo is not None else parsed.replace(tzinfo=UTC)


def parse_etags(value: str) -> list[str] | None:
    """The entity-tags of an If-Match / If-None-Match list; None means ``*``. Weak tags keep
    their ``W/`` prefix; unquoted junk is dropped (it can never match)."""
    if value.strip() == "*":
        return None
    tags = [item.strip(" \t") for item in value.split(",")]
    return [t for t in tags if _quoted(t.removeprefix("W/"))]


def _quoted(opaque: str) -> bool:
    """Whether ``opaque`` is one quoted string (an entity-tag without its ``W/``)."""
    return len(opaque) >= 2 and opaque[0] == opaque[-1] == '"' and '"' not in opaque[1:-1]


def _not_after(value: str, mtime: float) -> bool | None:
    """True when the resource was not modified after the date; None for an invalid date."""
    date = parse_http_date(value)
    return None if date is None else int(mtime) <= date.timestamp()


def evaluate(method: str, headers: Mapping[str, str], etag: str, mtime: float) -> Outcome:
    """Apply If-Match, If-Unmodified-Since, If-None-Match, If-Modified-Since in §13.2.2 order:
    If-Match compares strongly (§8.8.3.2), If-None-Match weakly, ``*`` matches anything."""
    safe = method in ("GET", "HEAD")
    if "If-Match" in headers:
        tags = parse_etags(headers["If-Match"])
        if tags is not None and etag not in tags:
            return Outcome.FAILED
    elif "If-Unmodified-Since" in headers and (
        _not_after(headers["If-Unmodified-Since"], mtime) is False
    ):
        return Outcome.FAILED
    if "If-None-Match" in headers:
        tags = parse_etags(headers["If-None-Match"])
        if tags is None or etag.removeprefix("W/") in {t.removeprefix("W/") for t in tags}:
            return Outcome.NOT_MODIFIED if safe else Outcome.FAILED
    elif (
        safe and "If-Modified-Since" in headers and _not_after(headers["If-Modified-Since"], mtime)
    ):
        return Outcome.NOT_MODIFIED
    return Outcome.PROCEED


def if_range_allows(value: str | None, etag: str, mtime: float) -> bool:
    """True when the Range header may be honoured (§13.1.5): an entity-tag must match strongly,
    a date must equal Last-Modified exactly; anything else (a weak tag, an unparsable value,
    another date) means: send the whole representation."""
    if value is None:
        return True
    value = value.strip(" \t")
    if value.startswith('"'):
        return value == etag
    if value.startswith("W/"):
        return False
    date = parse_http_date(value)
    return date is not None and date.timestamp() == int(mtime)
