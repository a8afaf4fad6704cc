"""The streaming client: show a ``.tsogs`` container served over HTTP (or on disk) at any time.

``StreamClient`` is the async core; ``SyncClient`` (``open_url``) a thin synchronous facade;
``HttpSource`` the byte source over single-range HTTP requests; a ``ChunkFetcher`` reads chunks
by ranges of one file (``RangeFetcher``) or as the unpacked layout's files (``FolderFetcher``).
See docs/client.md.
"""

from __future__ import annotations

from .fetchers import ChunkFetcher, FolderFetcher, RangeFetcher, make_fetcher
from .http_source import HttpFiles, HttpOptions, HttpSource
from .stream import (
    CacheStats,
    Playback,
    PlayedFrame,
    PlayStats,
    SceneCache,
    StreamClient,
    open_source,
)
from .sync import SyncClient, open_url

__all__ = [
    "CacheStats",
    "ChunkFetcher",
    "FolderFetcher",
    "HttpFiles",
    "HttpOptions",
    "HttpSource",
    "PlayStats",
    "Playback",
    "PlayedFrame",
    "RangeFetcher",
    "SceneCache",
    "StreamClient",
    "SyncClient",
    "make_fetcher",
    "open_source",
    "open_url",
]
