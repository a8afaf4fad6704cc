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
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import Any

from ..constants import is_container
from ..container.header import HEADER_SIZE, Header
from ..container.index import MAX_INDEX_BYTES
from ..container.objects import ObjectSource
from ..container.ranges import ByteRange
from ..container.sources import read_index
from ..container.stream_index import MANIFEST, unpacked_index
from ..errors import SourceError, TsogError
from ..io.objects import ObjectPath, store_errors
from ..schemas.manifest import dump_manifest
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
    guess_type,
    remember,
    servable,
)
from .shown import gaussians_per_frame

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

    async def _locate(self, rel: str) -> FileVersion:
        """The version of the object ``rel``, NotFoundError when there is none."""
        check_relative(rel)
        self.check_only(rel)
        info = await asyncio.to_thread(self._info, rel)
        if info is None:
            raise NotFoundError("no such file", where=rel[:80])
        return _version(info)

    def source(self, rel: str) -> ObjectSource:
        """Ranged reads of the object ``rel``."""
        return ObjectSource(self.base / rel)

    async def file(self, rel: str) -> Representation:
        """The whole object at ``rel``, its ETag the container identity or the store's."""
        version = await self._locate(rel)
        path = Path(rel)
        cached = self._etags.get(path)
        if cached is None or cached[0] != version:
            cached = (version, await self._etag(rel))
            remember(self._etags, path, cached)
        kind = CONTAINER_TYPE if path.suffix == CONTAINER_SUFFIX else guess_type(path)
        mtime = version.mtime_ns / 1e9
        return Representation(
            path, 0, version.size, cached[1], mtime, kind, source=self.source(rel)
        )

    async def _etag(self, rel: str) -> str:
        source = self.source(rel)
        size = await source.size()
        head = await source.read(ByteRange(0, min(size, HEADER_SIZE)))
        if is_container(head):
            try:
                return f'"{Header.unpack(head, where=rel).index_sha256.hex()}"'
            except TsogError:
                pass
        info = await asyncio.to_thread(self._info, rel)
        tag = str((info or {}).get("ETag") or "").strip('"')
        return f'"{tag}"' if tag else f'"{size}-{int(time.time())}"'

    def file_if_known(self, rel: str) -> Representation | None:
        """Never known without asking the store: the full handler answers."""
        return None

    def scene_if_known(self, scene_id: str) -> SceneEntry | None:
        """Never known without asking the store: the full handler answers."""
        return None

    async def scene(self, scene_id: str) -> SceneEntry:
        """The scene ``scene_id``: ``<id>.tsogs`` if it exists, else ``<id>/manifest.json``."""
        packed = True
        rel = scene_id + CONTAINER_SUFFIX
        try:
            version = await self._locate(rel)
        except NotFoundError:
            packed, rel = False, f"{scene_id}/{MANIFEST}"
            version = await self._locate(rel)
        path = Path(rel)
        cached = self._scenes.get(path)
        if cached is None or cached[0] != version:
            scene = await self._open_scene(scene_id, rel, packed, version)
            cached = (version, scene)
            remember(self._scenes, path, cached)
        entry = cached[1]
        return entry if entry.id == scene_id else replace(entry, id=scene_id)

    async def _open_scene(
        self, scene_id: str, rel: str, packed: bool, version: FileVersion
    ) -> SceneEntry:
        source = self.source(rel)
        try:
            if packed:
                index = await read_index(source)
                manifest_json = dump_manifest(index.manifest)
                size = version.size
            else:
                if version.size > MAX_INDEX_BYTES:
                    raise SourceError(f"manifest over {MAX_INDEX_BYTES} bytes", where=rel)
                manifest_json = await source.read(ByteRange(0, version.size))
                index = unpacked_index(manifest_json, where=rel)
                size = len(manifest_json) + index.manifest.payload_bytes
        except TsogError as exc:
            raise NotFoundError(f"not a readable scene: {exc.message}", where=scene_id) from exc
        per_frame = await asyncio.to_thread(gaussians_per_frame, index.manifest)
        mtime = version.mtime_ns / 1e9
        return SceneEntry(scene_id, Path(rel), packed, index, manifest_json, mtime, size, per_frame)

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

    def chunk(self, scene: SceneEntry, chunk_id: int) -> Representation:
        """One chunk: a range of the container object, or an object of the unpacked layout."""
        chunks = scene.index.manifest.chunks
        if not 0 <= chunk_id < len(chunks):
            raise NotFoundError(f"no chunk {chunk_id} (it has {len(chunks)})", where=scene.id)
        entry = chunks[chunk_id]
        etag = f'"{entry.sha256}"'
        if scene.packed:
            rel = scene.path.as_posix()
            return Representation(
                scene.path,
                entry.offset,
                entry.length,
                etag,
                scene.mtime,
                SOG_TYPE,
                source=self.source(rel),
            )
        rel = f"{scene.path.parent.as_posix()}/{entry.file}"
        check_relative(rel)
        return Representation(
            Path(rel), 0, entry.length, etag, scene.mtime, SOG_TYPE, source=self.source(rel)
        )


__all__ = ["REVALIDATE_S", "ObjectCatalog"]
