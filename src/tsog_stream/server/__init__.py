"""The HTTP origin: raw files with RFC 9110 byte ranges and a small streaming API (docs/http.md).

``ranges`` and ``conditional`` are sans-I/O; ``catalog`` maps URLs to files safely; ``app``
holds the aiohttp application; ``private`` guards private scenes with signed URLs; ``workers``
runs it in several processes sharing one port.
"""

from .app import Limits, make_app, run_server, start_server
from .private import Privacy
from .workers import Site, default_workers, run_workers

__all__ = [
    "Limits",
    "Privacy",
    "Site",
    "default_workers",
    "make_app",
    "run_server",
    "run_workers",
    "start_server",
]
