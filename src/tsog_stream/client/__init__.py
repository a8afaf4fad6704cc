"""The streaming client: show a ``.tsogs`` container served over HTTP (or on disk) at any time.

``StreamClient`` is the async core; ``SyncClient`` (``open_url``) a thin synchronous facade;
``HttpSource`` the byte source over single-range HTTP requests. See docs/client.md.
"""

from __future__ import annotations

from .http_source import HttpOptions, HttpSource
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
    "HttpOptions",
    "HttpSource",
    "PlayStats",
    "Playback",
    "PlayedFrame",
    "SceneCache",
    "StreamClient",
    "SyncClient",
    "open_source",
    "open_url",
]
