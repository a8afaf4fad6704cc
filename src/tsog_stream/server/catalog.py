"""What the server may send: safe paths under the root, ETags, scenes and their chunks.

A path a client names is refused when it is not plainly relative (InputError, 400), and must
resolve (symlinks followed) inside the root, else :class:`NotFoundError` (404, as for a missing
file, so nothing leaks). Scenes are ``.tsogs`` containers and unpacked layouts (folders with
``manifest.json``), reopened when their file changes.
"""

from __future__ import annotations

import asyncio
import errno
import functools
import hashlib
import io
import os
import stat
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple, TypeVar, cast

from cachetools import FIFOCache

from ..constants import is_container, thumbnail_path
from ..container.header import HEADER_SIZE, Header
from ..container.index import MAX_INDEX_BYTES
from ..container.ranges import ByteRange
from ..container.sources import ByteSource, FileSource, read_index
from ..container.stream_index import MANIFEST, StreamIndex, unpacked_index
from ..errors import InputError, SourceError, TsogError
from ..schemas.manifest import ChunkEntry, dump_manifest
from .shown import gaussians_per_frame

CONTAINER_SUFFIX = ".tsogs"
CONTAINER_TYPE = "application/vnd.tsog-stream"
SOG_TYPE = "application/x-sog"
MEDIA_TYPES = {".json": "application/json", ".sog": SOG_TYPE, ".png": "image/png"}
"""Media types by lower-case extension; any other file is application/octet-stream."""
MAX_CACHED = 4096
"""Files per cache (ETags, opened scenes): the current version of each, oldest dropped first."""
OUT_OF_FDS = (errno.EMFILE, errno.ENFILE)
_T = TypeVar("_T")


class NotFoundError(SourceError):
    """Nothing servable at this path or id (missing, outside the root, not a regular file)."""


class BusyError(SourceError):
    """Out of file descriptors for a moment: 503, never a 404 (a client takes it as permanent)."""


def unreadable(exc: BaseException, message: str, where: str) -> SourceError:
    """The error to answer for a failed read: BusyError when the process is out of file
    descriptors (the OSError itself or the cause of a SourceError), else NotFoundError."""
    cause = exc if isinstance(exc, OSError) else exc.__cause__
    if isinstance(cause, OSError) and cause.errno in OUT_OF_FDS:
        return BusyError("out of file descriptors; try again", where=where)
    return NotFoundError(message, where=where)


@dataclass(frozen=True, slots=True)
class Representation:
    """Bytes ``[offset, offset + length)`` of a file, with their validators."""

    path: Path
    offset: int
    length: int
    etag: str
    mtime: float
    content_type: str
    beneath: Path | None = None
    """The root ``path`` was checked to lie under (opened with :func:`open_beneath`), if any."""
    source: ByteSource | None = None
    """Where a stored object's bytes are read (``path`` is then its name under the prefix)."""

    def open(self) -> io.BufferedReader:
        """The file, opened for reading (see :func:`open_beneath`)."""
        if self.beneath is None:
            return open(self.path, "rb")
        return open_beneath(self.beneath, self.path)


@dataclass(frozen=True, slots=True)
class SceneEntry:
    """An opened scene: packed (a container file) or unpacked (a folder)."""

    id: str
    path: Path
    packed: bool
    index: StreamIndex
    manifest_json: bytes
    mtime: float
    size: int
    gaussians_per_frame: int
    """The most Gaussians shown at one time (:func:`.shown.gaussians_per_frame`)."""


class FileVersion(NamedTuple):
    """What tells one version of a file from the next: a file replaced by rename gets a new
    inode, one rewritten in place a new ctime (which, unlike mtime, no tool can set back)."""

    size: int
    mtime_ns: int
    inode: int
    ctime_ns: int


class SceneFile(NamedTuple):
    """A scene's container (packed) or manifest file, found and not yet opened."""

    path: Path
    version: FileVersion
    packed: bool


def open_beneath(root: Path, path: Path) -> io.BufferedReader:
    """Open ``path``, a resolved path under the resolved ``root``, refusing a symlink at any
    component below the root (OSError), so a component swapped for a symlink after the check
    cannot lead out: one ``openat(O_NOFOLLOW)`` at a time, ``openat2(RESOLVE_BENEATH)`` on
    every POSIX."""
    parts = path.relative_to(root).parts
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
    try:
        for part in parts[:-1]:
            below = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fd)
            os.close(fd)
            fd = below
        return open(os.open(parts[-1], os.O_RDONLY | os.O_NOFOLLOW, dir_fd=fd), "rb")
    finally:
        os.close(fd)


def servable(name: str) -> bool:
    """Whether a file or folder name may be listed and served: valid UTF-8 (no surrogates from
    undecodable bytes) and no control characters (a newline would break every URL of it)."""
    return not any(c < " " or c == "\x7f" or "\ud800" <= c <= "\udfff" for c in name)


def check_relative(rel: str) -> None:
    """Refuse a path that is not plainly relative (NUL, backslash, empty, '.' or '..'
    segments) or names what is never served (see :func:`servable`)."""
    if "\x00" in rel or "\\" in rel:
        raise InputError("NUL bytes and backslashes are not allowed in paths", where=rel[:80])
    if rel.startswith("/") or any(p in ("", ".", "..") for p in rel.split("/")):
        raise InputError("paths must be relative, without empty, '.' or '..' segments")
    if not servable(rel):
        raise NotFoundError("no such file", where=repr(rel[:80]))


def safe_path(root: Path, rel: str) -> Path:
    """The resolved path of ``rel`` under ``root``; refuses anything that could escape it."""
    check_relative(rel)
    base = root.resolve()
    try:
        resolved = (base / rel).resolve(strict=True)
    except (OSError, RuntimeError) as exc:
        raise NotFoundError("no such file", where=rel[:80]) from exc
    if not resolved.is_relative_to(base):
        raise NotFoundError("no such file", where=rel[:80])
    return resolved


def version_of(st: os.stat_result, name: str) -> FileVersion:
    """The version of a regular file from its stat, NotFoundError for anything else."""
    if not stat.S_ISREG(st.st_mode):
        raise NotFoundError("not a regular file", where=name)
    return FileVersion(st.st_size, st.st_mtime_ns, st.st_ino, st.st_ctime_ns)


def locate(root: Path, rel: str) -> tuple[Path, FileVersion]:
    """The resolved path of the regular file ``rel`` under the resolved ``root``, and its
    version: one ``lstat`` per component when none is a symlink (the common case, and cheaper
    than resolving from ``/``), else :func:`safe_path`."""
    check_relative(rel)
    path = root
    try:
        for part in rel.split("/"):
            path = path / part
            st = os.lstat(path)
            if stat.S_ISLNK(st.st_mode):
                path = safe_path(root, rel)
                st = path.stat()
                break
    except OSError as exc:
        raise NotFoundError("no such file", where=rel[:80]) from exc
    return path, version_of(st, path.name)


def container_etag(head: bytes, where: str) -> str | None:
    """The ETag rule of every catalog, for a file whose first bytes are ``head``: a container's
    identity (the index SHA-256 its header names), so the ETag changes exactly when the
    container does; None for any other file (the catalog then tags its content)."""
    if not is_container(head):
        return None
    try:
        return f'"{Header.unpack(head[:HEADER_SIZE], where=where).index_sha256.hex()}"'
    except TsogError:
        return None


def _content_etag(root: Path, path: Path) -> str:
    """Strong ETag of a local file: :func:`container_etag`, else the SHA-256 of the content."""
    with open_beneath(root, path) as f:
        identity = container_etag(f.read(HEADER_SIZE), path.name)
        if identity is None:
            f.seek(0)
            identity = f'"{hashlib.file_digest(f, "sha256").hexdigest()}"'
    return identity


def media_type(path: Path) -> str:
    """The media type of a file, from its extension."""
    if path.suffix == CONTAINER_SUFFIX:
        return CONTAINER_TYPE
    return MEDIA_TYPES.get(path.suffix.lower(), "application/octet-stream")


class Catalog:
    """Files and scenes under one root folder, or one file (only that file is served, and a
    container as the scene ``<name without .tsogs>``). :class:`~.object_catalog.ObjectCatalog`
    changes how names are found, tagged, read and listed; caching and the ETag rule stay here.
    """

    def __init__(self, root: Path) -> None:
        resolved = root.resolve()
        only = resolved.name if resolved.is_file() else None
        self._setup(resolved.parent if only is not None else resolved, only)

    def _setup(self, root: Path, only: str | None) -> None:
        """The root, the one file served (None: all) and empty caches."""
        self.root, self.only = root, only
        self._etags: FIFOCache[Path, tuple[FileVersion, str]] = FIFOCache(MAX_CACHED)
        self._scenes: FIFOCache[Path, tuple[FileVersion, SceneEntry]] = FIFOCache(MAX_CACHED)
        self._pending: dict[tuple[str, Path, FileVersion], asyncio.Future[Any]] = {}

    def check_only(self, rel: str) -> None:
        """In single-file mode, anything but that file (and, for a container, the thumbnail
        beside it, which the scene list shows) is not found."""
        if self.only is None or rel == self.only:
            return
        if not (self.only.endswith(CONTAINER_SUFFIX) and rel == thumbnail_path(self.only)):
            raise NotFoundError("no such file", where=rel[:80])

    async def find(self, rel: str) -> tuple[Path, FileVersion]:
        """The file ``rel`` names (relative to the root) and its version; NotFoundError when
        there is none."""
        self.check_only(rel)
        return locate(self.root, rel)

    async def file(self, rel: str) -> Representation:
        """The whole file at ``rel`` (relative to the root)."""
        return await self.file_at(*await self.find(rel))

    async def file_at(self, path: Path, version: FileVersion) -> Representation:
        """The whole file :meth:`find` found, its ETag computed once per version
        (:func:`container_etag`, else one of the content)."""
        try:
            tag = await self._once(self._etags, "etag", path, version, lambda: self._tag(path))
        except OSError as exc:  # vanished or unreadable since the stat
            raise unreadable(exc, "no such file", path.name) from exc
        return self._whole(path, version, tag)

    async def _tag(self, path: Path) -> str:
        """The ETag of the file at ``path``, read in a worker thread."""
        return await asyncio.to_thread(_content_etag, self.root, path)

    def source_of(self, path: Path) -> ByteSource:
        """The bytes of the file at ``path`` (a path as :meth:`find` gives), read async."""
        return FileSource(path)

    def _whole(self, path: Path, version: FileVersion, etag: str) -> Representation:
        """The representation of a whole file under the root."""
        mtime = version.mtime_ns / 1e9
        return Representation(path, 0, version.size, etag, mtime, media_type(path), self.root)

    async def _once(
        self,
        cache: FIFOCache[Path, tuple[FileVersion, _T]],
        kind: str,
        path: Path,
        version: FileVersion,
        work: Callable[[], Awaitable[_T]],
    ) -> _T:
        """The ``cache``d value of this file version, else ``work()``, run once however many
        requests ask at the same time: a cold cache must not cost one read or parse each."""
        cached = cache.get(path)
        if cached is not None and cached[0] == version:
            return cached[1]
        key = (kind, path, version)
        task = self._pending.get(key)
        if task is None:
            started: asyncio.Future[Any] = asyncio.ensure_future(work())
            self._pending[key] = task = started
            started.add_done_callback(lambda t: _retrieved(self._pending.pop(key, t)))
        # shielded: a client leaving does not cancel the others' wait; the kind keys the type
        value = cast(_T, await asyncio.shield(task))
        cache[path] = (version, value)
        return value

    async def scene_file(self, scene_id: str) -> SceneFile:
        """The file of the scene ``scene_id``: ``<id>.tsogs`` if it exists, else the manifest
        of the folder ``<id>/``."""
        try:
            return SceneFile(*await self.find(scene_id + CONTAINER_SUFFIX), True)
        except NotFoundError:
            return SceneFile(*await self.find(f"{scene_id}/{MANIFEST}"), False)

    async def scene(self, scene_id: str, found: SceneFile | None = None) -> SceneEntry:
        """The scene ``scene_id``, opened once per version of its file (``found``: what
        :meth:`scene_file` gave, when it was asked already)."""
        if found is None:
            found = await self.scene_file(scene_id)
        work = functools.partial(self._open, scene_id, found)
        scene = await self._once(self._scenes, "scene", found.path, found.version, work)
        # ids that alias one file through symlinks share one cache entry, named as asked
        return scene if scene.id == scene_id else replace(scene, id=scene_id)

    async def _open(self, scene_id: str, found: SceneFile) -> SceneEntry:
        """Open a container or an unpacked manifest (refused over MAX_INDEX_BYTES before it is
        read) through the async reader; NotFoundError when unreadable, BusyError when out of
        file descriptors."""
        path, version, packed = found
        source = self.source_of(path)
        raw: bytes | None = None
        try:
            if packed:
                index = await read_index(source)
            elif version.size > MAX_INDEX_BYTES:
                raise SourceError(f"manifest over {MAX_INDEX_BYTES} bytes", where=source.name)
            else:
                raw = await source.read(ByteRange(0, version.size))
                index = unpacked_index(raw, where=source.name)
            text, per_frame = await asyncio.to_thread(_describe, index, raw)
        except TsogError as exc:
            raise unreadable(exc, f"not a readable scene: {exc.message}", scene_id) from exc
        size = version.size if packed else len(text) + index.manifest.payload_bytes
        mtime = version.mtime_ns / 1e9
        return SceneEntry(scene_id, path, packed, index, text, mtime, size, per_frame)

    def relative(self, path: Path) -> str:
        """The root-relative form of a resolved path under the root."""
        return path.relative_to(self.root).as_posix()

    def scene_relative(self, scene: SceneEntry | SceneFile) -> str:
        """The root-relative path of a scene: its container file or its folder."""
        return self.relative(scene.path if scene.packed else scene.path.parent)

    def has_file(self, rel: str) -> bool:
        """Whether the regular file ``rel`` exists under the root (blocking)."""
        try:
            locate(self.root, rel)
        except (NotFoundError, InputError):
            return False
        return True

    def scene_ids(self) -> list[str]:
        """Ids of every container and unpacked layout served (blocking: a walk), sorted."""
        if self.only is not None:
            suffixed = self.only.endswith(CONTAINER_SUFFIX)
            return [self.only.removesuffix(CONTAINER_SUFFIX)] if suffixed else []
        return sorted(self._all_ids())

    def _all_ids(self) -> set[str]:
        """Scene ids under the root folder (symlinks not followed; names that are not
        :func:`servable` skipped, with the folders below them)."""
        ids: set[str] = set()
        for folder, dirs, files in os.walk(self.root):
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and servable(d))
            rel = Path(folder).relative_to(self.root)
            if MANIFEST in files and rel != Path("."):
                ids.add(rel.as_posix())
            for name in files:
                if name.endswith(CONTAINER_SUFFIX) and not name.startswith(".") and servable(name):
                    ids.add((rel / name).as_posix().removesuffix(CONTAINER_SUFFIX))
        return ids

    def chunk(self, scene: SceneEntry, chunk_id: int) -> Representation:
        """The bytes of one chunk, its ETag the chunk's SHA-256."""
        chunks = scene.index.manifest.chunks
        if not 0 <= chunk_id < len(chunks):
            raise NotFoundError(f"no chunk {chunk_id} (it has {len(chunks)})", where=scene.id)
        entry: ChunkEntry = chunks[chunk_id]
        return self._chunk(scene, entry, f'"{entry.sha256}"')

    def _chunk(self, scene: SceneEntry, entry: ChunkEntry, etag: str) -> Representation:
        """One chunk: a slice of the container, or a file of the unpacked layout."""
        if scene.packed:
            return Representation(
                scene.path, entry.offset, entry.length, etag, scene.mtime, SOG_TYPE
            )
        path, version = locate(scene.path.parent, entry.file)
        mtime = version.mtime_ns / 1e9
        return Representation(path, 0, version.size, etag, mtime, SOG_TYPE, self.root)


def _describe(index: StreamIndex, manifest_json: bytes | None) -> tuple[bytes, int]:
    """The manifest JSON (``manifest_json`` when read from an unpacked layout) and the
    Gaussians per frame of a scene (run in a worker thread)."""
    text = manifest_json if manifest_json is not None else dump_manifest(index.manifest)
    return text, gaussians_per_frame(index.manifest)


def _retrieved(task: asyncio.Future[Any]) -> None:
    """Mark a task's exception as seen (its waiters may all have gone)."""
    if not task.cancelled():
        task.exception()
