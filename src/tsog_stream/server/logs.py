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


def _quiet_bad_requests(record: logging.LogRecord) -> bool:
    """Malformed requests (answered 400 by aiohttp) and clients that went away or stalled log
    one INFO line, not an ERROR traceback, so hostile clients cannot flood the log; real
    server errors keep their traceback."""
    exc = record.exc_info[1] if record.exc_info else None
    if isinstance(exc, HttpProcessingError | ConnectionError):
        text = exc.message if isinstance(exc, HttpProcessingError) else f"{exc!r}"
        first = (str(text).splitlines() or [type(exc).__name__])[0]
        record.msg, record.args = "client error: %s", (first[:200],)
        record.exc_info, record.exc_text = None, None
        record.levelno, record.levelname = logging.INFO, "INFO"
    return True


class _AcceptFlood(logging.Filter):
    """Out of file descriptors, asyncio logs every failed ``accept`` with a traceback (thousands
    of lines a second under a connection flood): keep one line a second."""

    def __init__(self) -> None:
        super().__init__()
        self.last = -math.inf

    def filter(self, record: logging.LogRecord) -> bool:
        if not str(record.msg).startswith("socket.accept() out of system resource"):
            return True
        now = time.monotonic()
        if now - self.last < 1.0:
            return False
        self.last = now
        record.msg, record.args = (
            "out of file descriptors: new connections wait (%s)",
            (record.exc_info[1] if record.exc_info else "",),
        )
        record.exc_info, record.exc_text = None, None
        return True


_ACCEPT_FLOOD = _AcceptFlood()
_BUSY = {"last": -math.inf}


def log_out_of_fds(message: str) -> None:
    """A request answered 503 for want of file descriptors: one WARNING line a second at most."""
    now = time.monotonic()
    if now - _BUSY["last"] >= 1.0:
        _BUSY["last"] = now
        logging.getLogger("tsog_stream.server").warning("answering 503: %s", message)


def quiet_client_errors() -> None:
    """Install both filters (once per process)."""
    server_log, asyncio_log = logging.getLogger("aiohttp.server"), logging.getLogger("asyncio")
    if _quiet_bad_requests not in server_log.filters:
        server_log.addFilter(_quiet_bad_requests)
    if _ACCEPT_FLOOD not in asyncio_log.filters:
        asyncio_log.addFilter(_ACCEPT_FLOOD)
