"""Log filters: hostile or broken clients must not flood the server's log.

aiohttp logs every malformed request (answered 400) and every client that disconnects or
stalls mid-response at ERROR with a traceback; asyncio logs every failed ``accept`` when the
process is out of file descriptors, thousands of times a second under a connection flood.
These become one INFO line each, and one line a second, respectively. Real server errors keep
their traceback.
"""

from __future__ import annotations

import logging
import math
import time

from aiohttp.http_exceptions import HttpProcessingError

_LAST = {"accept": -math.inf, "busy": -math.inf}
"""When each once-a-second line was last written."""


def _due(kind: str) -> bool:
    """Whether a once-a-second line of ``kind`` may be written now (then it is counted)."""
    now = time.monotonic()
    if now - _LAST[kind] < 1.0:
        return False
    _LAST[kind] = now
    return True


def _quiet_bad_requests(record: logging.LogRecord) -> bool:
    """A malformed request, or a client that went away or stalled: one INFO line."""
    exc = record.exc_info[1] if record.exc_info else None
    if isinstance(exc, HttpProcessingError | ConnectionError):
        text = exc.message if isinstance(exc, HttpProcessingError) else f"{exc!r}"
        first = (str(text).splitlines() or [type(exc).__name__])[0]
        record.msg, record.args = "client error: %s", (first[:200],)
        record.exc_info, record.exc_text = None, None
        record.levelno, record.levelname = logging.INFO, "INFO"
    return True


def _quiet_accept_flood(record: logging.LogRecord) -> bool:
    """A failed ``accept`` for want of file descriptors: one line a second, no traceback."""
    if not str(record.msg).startswith("socket.accept() out of system resource"):
        return True
    if not _due("accept"):
        return False
    cause = record.exc_info[1] if record.exc_info else ""
    record.msg, record.args = "out of file descriptors: new connections wait (%s)", (cause,)
    record.exc_info, record.exc_text = None, None
    return True


def log_out_of_fds(message: str) -> None:
    """A request answered 503 for want of file descriptors: one WARNING line a second at most."""
    if _due("busy"):
        logging.getLogger("tsog_stream.server").warning("answering 503: %s", message)


def quiet_client_errors() -> None:
    """Install both filters (once per process)."""
    server_log, asyncio_log = logging.getLogger("aiohttp.server"), logging.getLogger("asyncio")
    if _quiet_bad_requests not in server_log.filters:
        server_log.addFilter(_quiet_bad_requests)
    if _quiet_accept_flood not in asyncio_log.filters:
        asyncio_log.addFilter(_quiet_accept_flood)
