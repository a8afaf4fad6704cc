"""The HTTP origin: raw files with RFC 9110 byte ranges and a small streaming API (docs/http.md).

``ranges`` and ``conditional`` are sans-I/O; ``catalog`` maps URLs to files safely; ``app``
holds the aiohttp application.
"""

from .app import Limits, make_app, run_server, start_server

__all__ = ["Limits", "make_app", "run_server", "start_server"]
