"""Chunk fetchers: how :class:`StreamClient` gets the raw bytes of chunks, by source kind.

Two kinds share the whole client (cache, prefetch, playback, verification): a
:class:`RangeFetcher` reads byte ranges of one ``.tsogs`` file (runs of neighbouring chunks
merged into one read), a :class:`FolderFetcher` reads each chunk's own file of the unpacked
layout (``manifest.json`` + ``chunks/NNNNNN.sog``), over HTTP or from a local folder.
"""

from __future__ import annotations

import asyncio
import os
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import unquote, urljoin, urlparse, urlsplit, urlunsplit

from ..container.index import MAX_INDEX_BYTES
from ..container.objects import ObjectSource
from ..container.ranges import ByteRange
from ..container.sources import ByteSource, FileSource, ReadStats, read_index
from ..container.stream_index import MANIFEST, StreamIndex, unpacked_index
from ..errors import SourceError
from ..io.files import read_head
from ..io.objects import is_object_url, object_at
from ..schemas.manifest import ChunkEntry
from ..signing import redact_url
from .http_options import HttpOptions

if TYPE_CHECKING:
    from .http_source import HttpFiles


class ChunkFetcher(ABC):
    """Raw (unverified) bytes of chunks; ``coalesces`` when a run of chunks costs one read."""

    name: str
    stats: ReadStats
    coalesces: bool = False

    @abstractmethod
    async def open(self, after: int | None = None) -> StreamIndex:
        """Read the index (one request in the usual case); ``after``: see
        :meth:`FolderFetcher.open`."""

    @abstractmethod
    async def fetch(self, group: Sequence[ChunkEntry]) -> list[bytes]:
        """The bytes of each chunk of ``group``, in the same order."""

    @abstractmethod
    async def aclose(self) -> None:
        """Release connections."""


class RangeFetcher(ChunkFetcher):
    """Chunks as byte ranges of one container file; a run is read with one request."""

    coalesces = True

    def __init__(self, source: ByteSource) -> None:
        self.source = source
        self.name = source.name
        self.stats = source.stats

    async def open(self, after: int | None = None) -> StreamIndex:
        """Read the header and index (one request when the index fits the prefix); a
        container file is never live, so ``after`` is not used."""
        return await read_index(self.source)

    async def fetch(self, group: Sequence[ChunkEntry]) -> list[bytes]:
        """One read spanning the group, split back into chunks."""
        start = min(c.offset for c in group)
        body = await self.source.read(ByteRange(start, max(c.offset + c.length for c in group)))
        return [body[c.offset - start : c.offset + c.length - start] for c in group]

    async def aclose(self) -> None:
        """Close the source's HTTP session, if it has one (an ``HttpSource``)."""
        aclose = getattr(self.source, "aclose", None)
        if aclose is not None:
            await aclose()


class FolderFetcher(ChunkFetcher):
    """Chunks as whole files of the unpacked layout, by URL (``base/chunks/NNNNNN.sog``) or path.

    ``base`` is the folder: an http(s) URL ending with ``/`` (uses :class:`HttpFiles`; its
    query, such as a signed URL's, is carried to every file's URL) or a local folder path.
    """

    def __init__(self, base: str, options: HttpOptions | None = None) -> None:
        parts = urlsplit(base)
        self._query = parts.query if _is_http(base) else ""
        self.base = urlunsplit(parts._replace(query="", fragment="")) if self._query else base
        self.name = redact_url(base)
        self._http: HttpFiles | None = None
        if _is_http(base):
            from .http_source import HttpFiles  # noqa: PLC0415 - aiohttp only for HTTP

            self._http = HttpFiles(options)
        self.stats = self._http.stats if self._http is not None else ReadStats()

    async def _get(self, name: str, limit: int, query: str | None = None) -> bytes:
        """The file ``name`` of the folder, at most ``limit`` bytes (a longer one is refused
        after ``limit`` + 1 bytes, never read whole); ``query`` added to its URL."""
        if self._http is not None:
            return await self._http.get(self._url(name, query), limit)
        where = self._where(name)
        data = await asyncio.to_thread(read_head, where, limit + 1)
        if len(data) > limit:
            raise SourceError(f"more than {limit} bytes, expected at most {limit}", where=where)
        self.stats.add(len(data))
        return data

    async def open(self, after: int | None = None) -> StreamIndex:
        """Read ``manifest.json`` (one request) and present it as an opened container;
        ``after``: a live stream's last publication seen, which an origin with the blocking
        reload (``tsog serve``) waits to pass before it answers (others ignore it)."""
        query = None if after is None or self._http is None else f"after={after}"
        raw = await self._get(MANIFEST, MAX_INDEX_BYTES, query)
        index = unpacked_index(raw, where=self._where(MANIFEST))
        return StreamIndex(index.header, index.manifest, self.name, packed=False)

    async def fetch(self, group: Sequence[ChunkEntry]) -> list[bytes]:
        """Each chunk's file, one request each (a longer file is refused, never read whole)."""
        return list(await asyncio.gather(*(self._get(c.file, c.length) for c in group)))

    def _url(self, name: str, query: str | None = None) -> str:
        """The URL of the folder's file ``name``, with the folder URL's query (and ``query``)."""
        url = urljoin(self.base, name)
        joined = "&".join(q for q in (self._query, query) if q)
        return f"{url}?{joined}" if joined else url

    def _where(self, name: str) -> str:
        if self._http is not None:
            return redact_url(self._url(name))
        if is_object_url(self.base):
            return f"{self.base.rstrip('/')}/{name}"
        return str(Path(self.base) / name)

    async def aclose(self) -> None:
        """Close the HTTP session."""
        if self._http is not None:
            await self._http.aclose()


def _is_http(text: str) -> bool:
    return urlparse(text).scheme.lower() in ("http", "https")


def make_fetcher(
    target: str | os.PathLike[str], options: HttpOptions | None = None
) -> RangeFetcher | FolderFetcher:
    """The fetcher for a target, by its form.

    An http(s) URL ending with ``/`` or ``/manifest.json``, a local folder or store prefix
    (``s3://bucket/scene/``), or a ``manifest.json`` in either, is the unpacked layout;
    anything else is one ``.tsogs`` file (a storage URL is read with ranged GETs).
    """
    text = os.fspath(target)
    if _is_http(text):
        parts = urlsplit(text)
        if parts.path.endswith("/"):
            return FolderFetcher(text, options)
        if parts.path.endswith("/" + MANIFEST):
            folder = parts._replace(path=parts.path[: -len(MANIFEST)])
            return FolderFetcher(urlunsplit(folder), options)
        from .http_source import HttpSource  # noqa: PLC0415 - aiohttp only for HTTP

        return RangeFetcher(HttpSource(text, options))
    if is_object_url(text):
        if text.endswith("/" + MANIFEST):
            return FolderFetcher(text[: -len(MANIFEST)])
        if text.endswith("/") or object_at(text).is_dir():
            return FolderFetcher(text)
        return RangeFetcher(ObjectSource(text))
    if urlparse(text).scheme.lower() == "file":
        text = unquote(urlparse(text).path)
    path = Path(text)
    if path.is_dir():
        return FolderFetcher(str(path))
    if path.name == MANIFEST:
        return FolderFetcher(str(path.parent))
    return RangeFetcher(FileSource(text))
