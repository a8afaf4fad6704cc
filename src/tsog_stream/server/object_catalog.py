"""Serving from object storage: the catalog of a bucket prefix (``tsog serve s3://bucket/media/``).

The same routes, answers and checks as for a folder (relative paths checked by
:func:`~.catalog.check_relative`), with bodies read by ranged GETs from the store
(:class:`~tsog_stream.container.objects.ObjectSource`) instead of ``sendfile``. An object's
version is its store ETag and size, asked again at most every :data:`REVALIDATE_S` seconds, so
a replaced container is picked up without one HEAD per request; a scene's index is read once
per version. ETags sent to clients are a container's identity (as for files) or the store's.
"""

from __future__ import annotations

import asyncio
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from ..container.header import HEADER_SIZE
from ..container.objects import ObjectSource
from ..container.ranges import ByteRange
from ..container.stream_index import MANIFEST
from ..io.objects import ObjectPath, store_errors
from ..schemas.manifest import ChunkEntry
from .catalog import (
    CONTAINER_SUFFIX,
    CONTAINER_TYPE,
    SOG_TYPE,
    Catalog,
    FileVersion,
    NotFoundError,
    Representation,
    SceneEntry,
    check_relative,
    container_etag,
    guess_type,
    remember,
    servable,
)

REVALIDATE_S = 2.0
"""Seconds an object's version is trusted before the store is asked again."""


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
        self.only = root.name if root.is_file() else None
        self.base = root.parent if self.only is not None else root
        self.root = Path(".")  # names are relative: a scene's path is its key under the base
        self._etags: dict[Path, tuple[FileVersion, str]] = {}
        self._scenes: dict[Path, tuple[FileVersion, SceneEntry]] = {}
        self._pending = {}
        self._seen: dict[str, tuple[float, dict[str, Any] | None]] = {}

    def _info(self, rel: str) -> dict[str, Any] | None:
        """The store's info on ``rel`` (None when absent), cached for REVALIDATE_S."""
        now = time.monotonic()
        cached = self._seen.get(rel)
        if cached is not None and now - cached[0] < REVALIDATE_S:
            return cached[1]
        target = self.base / rel
        with store_errors(str(target)):
            try:
                info: dict[str, Any] | None = target.fs.info(target.path)
            except FileNotFoundError:
                info = None
        if info is not None and info.get("type") != "file":
            info = None
        remember(self._seen, rel, (now, info))
        return info

    async def _find(self, rel: str) -> tuple[Path, FileVersion]:
        """The object ``rel`` (its name relative to the base) and its version, NotFoundError
        when there is none."""
        check_relative(rel)
        self.check_only(rel)
        info = await asyncio.to_thread(self._info, rel)
        if info is None:
            raise NotFoundError("no such file", where=rel[:80])
        return Path(rel), _version(info)

    def source(self, rel: str) -> ObjectSource:
        """Ranged reads of the object ``rel``."""
        return ObjectSource(self.base / rel)

    def source_of(self, path: Path) -> ObjectSource:
        """Ranged reads of the object named ``path`` (relative to the base)."""
        return self.source(path.as_posix())

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
        kind = CONTAINER_TYPE if path.suffix == CONTAINER_SUFFIX else guess_type(path)
        mtime = version.mtime_ns / 1e9
        source = self.source_of(path)
        return Representation(path, 0, version.size, etag, mtime, kind, source=source)

    def relative(self, path: Path) -> str:
        """Names are already relative to the base."""
        return path.as_posix()

    def has_file(self, rel: str) -> bool:
        """Whether the object ``rel`` exists (blocking: one HEAD, cached)."""
        return self._info(rel) is not None

    def scene_ids(self) -> list[str]:
        """Ids of every container and unpacked layout under the prefix (one listing)."""
        if self.only is not None:
            suffixed = self.only.endswith(CONTAINER_SUFFIX)
            return [self.only.removesuffix(CONTAINER_SUFFIX)] if suffixed else []
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
        return sorted(ids)

    def _chunk(self, scene: SceneEntry, entry: ChunkEntry, etag: str) -> Representation:
        """One chunk: a range of the container object, or an object of the unpacked layout."""
        if scene.packed:
            rel = scene.path.as_posix()
            offset, length = entry.offset, entry.length
        else:
            rel = f"{scene.path.parent.as_posix()}/{entry.file}"
            check_relative(rel)
            offset, length = 0, entry.length
        source = self.source(rel)
        return Representation(Path(rel), offset, length, etag, scene.mtime, SOG_TYPE, source=source)


__all__ = ["REVALIDATE_S", "ObjectCatalog"]
