"""How the client talks HTTP (:class:`HttpOptions`), apart from the HTTP code itself: the
reader of local files and storage takes options without loading aiohttp."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from ..errors import InputError

DEFAULT_DEADLINE_S = 60.0
"""Seconds one read may take, every attempt and wait included: the server's own deadline for
sending one body (docs/http.md), so the client never gives up on an answer our server would
still finish, and a player that has waited a minute for one chunk has long stalled anyway."""


@dataclass(frozen=True)
class HttpOptions:
    """Tuning of an :class:`HttpSource`: retries, timeouts and the unranged-origin limit."""

    retries: int = 4
    backoff_s: float = 0.1
    max_backoff_s: float = 2.0
    """Cap of one wait between attempts (the waits double from ``backoff_s``)."""
    connect_timeout_s: float = 10.0
    read_timeout_s: float = 30.0
    """Longest wait for any bytes of a response."""
    deadline_s: float = DEFAULT_DEADLINE_S
    """Deadline of one read (the opening request, a chunk or a run of chunks), every attempt
    and every wait between them included: a server that drips a byte now and then (never
    silent for ``read_timeout_s``) is given up on here, not after retries x a request timeout."""
    max_unranged_bytes: int = 1 << 20
    """Largest whole-file (200) answer kept in memory when the origin ignores ``Range``."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.deadline_s) and self.deadline_s > 0):
            raise InputError(
                f"expected a finite number of seconds > 0, got {self.deadline_s}", where="timeout"
            )


def with_deadline(options: HttpOptions | None, timeout: float | None) -> HttpOptions | None:
    """``options`` (the defaults if None) with the deadline of one read set to ``timeout``
    seconds; unchanged when ``timeout`` is None."""
    if timeout is None:
        return options
    return replace(options or HttpOptions(), deadline_s=timeout)
