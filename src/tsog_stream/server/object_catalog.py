"""Serving from object storage: the catalog of a bucket prefix (``tsog serve s3://bucket/media/``).

The same routes, answers and checks as for a folder, with bodies read by ranged GETs from the
store (:class:`~tsog_stream.container.objects.ObjectSource`) instead of ``sendfile``. An
object's version is its store ETag and size, asked again at most every :data:`REVALIDATE_S`
seconds, so a replaced container is picked up without one HEAD per request.
"""

from __future__ import annotations

import asyncio
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from cachetools import TTLCache

from ..container.header import HEADER_SIZE
from ..container.objects import ObjectSource
from ..container.ranges import ByteRange
from ..container.stream_index import MANIFEST
from ..io.objects import ObjectPath, store_errors
from ..schemas.manifest import ChunkEntry
from .catalog import (
    CONTAINER_SUFFIX,
    MAX_CACHED,
    SOG_TYPE,
    Catalog,
    FileVersion,
    NotFoundError,
    Representation,
    SceneEntry,
    check_relative,
    container_etag,
    media_type,
    servable,
)

REVALIDATE_S = 2.0
"""Seconds an object's version is trusted before the store is asked again."""
Info = dict[str, Any] | None


def _version(info: dict[str, Any]) -> FileVersion:
    """A FileVersion from a store's info (ETag stands for the inode: it changes on replace)."""
    modified = info.get("LastModified")
    mtime_ns = int(modified.timestamp() * 1e9) if isinstance(modified, datetime) else 0
    tag = str(info.get("ETag") or info.get("etag") or "")
    return FileVersion(int(info.get("size") or 0), mtime_ns, hash(tag) & (2**62 - 1), 0)


class ObjectCatalog(Catalog):
    """Files and scenes under one store prefix (or one stored container)."""

    def __init__(self, root: ObjectPath) -> None:
        self.store = root
        only = root.name if root.is_file() else None
        self.base = root.parent if only is not None else root
        self._setup(Path("."), only)  # names are relative: a scene's path is its key
        self._seen: TTLCache[str, tuple[Info]] = TTLCache(MAX_CACHED, REVALIDATE_S, time.monotonic)
        self._seen_lock = threading.Lock()  # asked from worker threads

    def _info(self, rel: str) -> Info:
        """The store's info on the object ``rel`` (None when absent), cached for REVALIDATE_S."""
        with self._seen_lock:
            hit = self._seen.get(rel)
        if hit is not None:
            return hit[0]
        target = self.base / rel
        with store_errors(str(target)):
            try:
                info: Info = target.fs.info(target.path)
            except FileNotFoundError:
                info = None
        if info is not None and info.get("type") != "file":
            info = None
        with self._seen_lock:
            self._seen[rel] = (info,)
        return info

    async def find(self, rel: str) -> tuple[Path, FileVersion]:
        """The object ``rel`` (its name relative to the base) and its version, NotFoundError
        when there is none."""
        check_relative(rel)
        self.check_only(rel)
        info = await asyncio.to_thread(self._info, rel)
        if info is None:
            raise NotFoundError("no such file", where=rel[:80])
        return Path(rel), _version(info)

    def source_of(self, path: Path) -> ObjectSource:
        """Ranged reads of the object named ``path`` (relative to the base)."""
        return ObjectSource(self.base / path.as_posix())

    async def _tag(self, path: Path) -> str:
        """:func:`~.catalog.container_etag`, else the store's ETag of the object."""
        source = self.source_of(path)
        size = await source.size()
        head = await source.read(ByteRange(0, min(size, HEADER_SIZE)))
        identity = container_etag(head, path.as_posix())
        if identity is not None:
            return identity
        info = await asyncio.to_thread(self._info, path.as_posix())
        tag = str((info or {}).get("ETag") or "").strip('"')
        return f'"{tag}"' if tag else f'"{size}-{int(time.time())}"'

    def _whole(self, path: Path, version: FileVersion, etag: str) -> Representation:
        """The representation of a whole object, read from the store."""
        mtime, source = version.mtime_ns / 1e9, self.source_of(path)
        return Representation(path, 0, version.size, etag, mtime, media_type(path), source=source)

    def relative(self, path: Path) -> str:
        """Names are already relative to the base."""
        return path.as_posix()

    def has_file(self, rel: str) -> bool:
        """Whether the object ``rel`` exists (blocking: one HEAD, cached)."""
        return self._info(rel) is not None

    def _all_ids(self) -> set[str]:
        """Scene ids under the prefix (one listing)."""
        with store_errors(str(self.base), "list"):
            keys: list[str] = self.base.fs.find(self.base.path)
        prefix = self.base.path.strip("/") + "/"
        ids: set[str] = set()
        for key in keys:
            rel = key.strip("/").removeprefix(prefix)
            parts = rel.split("/")
            if any(p.startswith(".") or not servable(p) for p in parts):
                continue
            if parts[-1] == MANIFEST and len(parts) > 1:
                ids.add("/".join(parts[:-1]))
            elif rel.endswith(CONTAINER_SUFFIX):
                ids.add(rel.removesuffix(CONTAINER_SUFFIX))
        return ids

    def _chunk(self, scene: SceneEntry, entry: ChunkEntry, etag: str) -> Representation:
        """One chunk: a range of the container object, or an object of the unpacked layout."""
        if scene.packed:
            path, offset = scene.path, entry.offset
        else:
            rel = f"{scene.path.parent.as_posix()}/{entry.file}"
            check_relative(rel)
            path, offset = Path(rel), 0
        source = self.source_of(path)
        return Representation(
            path, offset, entry.length, etag, scene.mtime, SOG_TYPE, source=source
        )


__all__ = ["REVALIDATE_S", "ObjectCatalog"]
