"""The HTTP origin: raw files with RFC 9110 byte ranges and a small streaming API (docs/http.md).

Its rooms and what each owns: docs/design/server.md. The exports load their module (and
aiohttp.web) when first asked for, so a command that only needs a light module of the package
(``server.link``'s parsers) does not pay for it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .app import Limits, make_app, run_server, start_server
    from .private import Privacy
    from .workers import Site, default_workers, run_workers

__all__ = ["Limits", "Privacy", "Site", "default_workers", "make_app", "run_server"]
__all__ += ["run_workers", "start_server"]
_HOME = dict.fromkeys(("Limits", "make_app", "run_server", "start_server"), "app")
_HOME |= dict.fromkeys(("Site", "default_workers", "run_workers"), "workers")
_HOME["Privacy"] = "private"


def __getattr__(name: str) -> Any:
    """An export of the package, its module imported on first use."""
    if name in _HOME:
        return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
