"""The one reader of a container: show a ``.tsogs`` file or an unpacked folder, on disk or
over HTTP, at any time.

``StreamClient`` is the async core; ``Stream`` (``open_stream``) its thin synchronous facade;
``HttpSource`` the byte source over single-range HTTP requests; a ``ChunkFetcher`` reads chunks
by ranges of one file (``RangeFetcher``) or as the unpacked layout's files (``FolderFetcher``).
See docs/client.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .cache import CacheStats, SceneCache
from .costs import SeekCost
from .fetchers import ChunkFetcher, FolderFetcher, RangeFetcher, make_fetcher
from .http_options import HttpOptions
from .live import LiveStats, follow_live
from .playback import Playback, PlayedFrame, PlayStats
from .stream import StreamClient
from .sync import Stream, open_stream
from .verify import Check, VerifyReport

if TYPE_CHECKING:
    from .http_source import HttpFiles, HttpSource

__all__ = [
    "CacheStats",
    "Check",
    "ChunkFetcher",
    "FolderFetcher",
    "HttpFiles",
    "HttpOptions",
    "HttpSource",
    "LiveStats",
    "PlayStats",
    "Playback",
    "PlayedFrame",
    "RangeFetcher",
    "SceneCache",
    "SeekCost",
    "Stream",
    "StreamClient",
    "VerifyReport",
    "follow_live",
    "make_fetcher",
    "open_stream",
]


def __getattr__(name: str) -> Any:
    """HttpSource and HttpFiles, loaded (with aiohttp) when first asked for: reading local
    files and storage does without them."""
    if name in ("HttpFiles", "HttpSource"):
        from . import http_source  # noqa: PLC0415 - aiohttp only for HTTP

        return getattr(http_source, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
