"""The HTTP origin: raw files with RFC 9110 byte ranges and a small streaming API (docs/http.md).

``ranges`` and ``conditional`` are sans-I/O; ``catalog`` maps URLs to files safely; ``app``
holds the aiohttp application; ``private`` guards private scenes with signed URLs; ``workers``
runs it in several processes sharing one port.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .app import Limits, make_app, run_server, start_server
    from .private import Privacy
    from .workers import Site, default_workers, run_workers

_HOME = {
    "Limits": "app",
    "make_app": "app",
    "run_server": "app",
    "start_server": "app",
    "Privacy": "private",
    "Site": "workers",
    "default_workers": "workers",
    "run_workers": "workers",
}
"""Where each export lives: loaded (with aiohttp.web) when first asked for, so a command that
only needs a light module of the package (``server.link``'s parsers) does not pay for it."""

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


def __getattr__(name: str) -> Any:
    """An export of the package, its module imported on first use."""
    if name in _HOME:
        return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
