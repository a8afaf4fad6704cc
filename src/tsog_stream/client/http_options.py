"""How the client talks HTTP (:class:`HttpOptions`), apart from the HTTP code itself: the
reader of local files and storage takes options without loading aiohttp."""

from __future__ import annotations

from dataclasses import dataclass


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
    request_timeout_s: float = 120.0
    """Deadline of one request, body included: a server that trickles a byte now and then
    (never silent for ``read_timeout_s``) is cut off here, and the request retried."""
    max_unranged_bytes: int = 1 << 20
    """Largest whole-file (200) answer kept in memory when the origin ignores ``Range``."""
