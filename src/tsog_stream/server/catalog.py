"""What the server may send: safe paths under the root, file ETags, scenes and their chunks.

Every path a client names is checked here: NUL bytes, backslashes, absolute paths and ``.``
or ``..`` segments are refused (:class:`~tsog_stream.errors.InputError`, 400); the path is
then resolved with symlinks followed and must stay inside the resolved root, else
:class:`NotFoundError` (404), the same answer as for a missing file, so nothing leaks.
Scenes are ``.tsogs`` containers and unpacked layouts (folders with ``manifest.json``); each is
reopened when it changes (size, mtime, inode or ctime). A root that is one file serves only
that file.
"""

from __future__ import annotations

import asyncio
import errno
import hashlib
import os
import stat
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple, TypeVar, cast

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
PNG_TYPE = "image/png"
_HASH_BLOCK = 1 << 20
MAX_CACHED = 4096
"""Files remembered per cache (ETags, opened scenes): only the current version of each."""
OUT_OF_FDS = (errno.EMFILE, errno.ENFILE)
_V = TypeVar("_V")
_K = TypeVar("_K")
_T = TypeVar("_T")


class NotFoundError(SourceError):
    """Nothing servable at this path or id (missing, outside the root, not a regular file)."""


class BusyError(SourceError):
    """The server is out of file descriptors for a moment: 503 with Retry-After, never a 404
    (which a client would take as permanent)."""


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
    """The served root this file was checked to lie under (resolved, no symlink left in
    ``path``): it is opened with :func:`open_beneath`. None for the server's own files."""
    source: ByteSource | None = None
    """Where the bytes are read when they are not a local file: a stored object (ranged GETs,
    server/object_catalog.py); ``path`` is then its name relative to the served prefix."""

    def open(self) -> BinaryIO:
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
    """The most Gaussians shown at one time (:func:`.shown.gaussians_per_frame`), computed
    once when the scene is opened."""


def open_beneath(root: Path, path: Path) -> BinaryIO:
    """Open ``path``, a resolved path under the resolved ``root``, refusing a symlink at any
    component below the root (OSError ELOOP or ENOTDIR).

    :func:`safe_path` resolved the path with symlinks followed and checked it lies under the
    root; a component swapped for a symlink between that check and this open (pointing out of
    the root) is refused here, walking down from the root one ``openat(O_NOFOLLOW)`` at a time:
    the effect of ``openat2(RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS)``, portable to every POSIX.
    """
    return os.fdopen(open_fd_beneath(str(root), path.relative_to(root).as_posix()), "rb")


def open_fd_beneath(root: str, rel: str) -> int:
    """:func:`open_beneath` on strings, returning the descriptor (``rel`` already passed
    :func:`check_relative`)."""
    parts = rel.split("/")
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
    try:
        for part in parts[:-1]:
            below = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fd)
            os.close(fd)
            fd = below
        return os.open(parts[-1], os.O_RDONLY | os.O_NOFOLLOW, dir_fd=fd)
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


class FileVersion(NamedTuple):
    """What tells one version of a file from the next: a file replaced by rename gets a new
    inode, one rewritten in place a new ctime (which, unlike mtime, no tool can set back)."""

    size: int
    mtime_ns: int
    inode: int
    ctime_ns: int


def _signature(path: Path) -> FileVersion:
    """The version of a regular file, NotFoundError otherwise."""
    try:
        st = path.stat()
    except OSError as exc:
        raise NotFoundError("no such file", where=path.name) from exc
    return version_of(st, path.name)


def version_of(st: os.stat_result, name: str) -> FileVersion:
    """The version of a regular file from its stat, NotFoundError for anything else."""
    if not stat.S_ISREG(st.st_mode):
        raise NotFoundError("not a regular file", where=name)
    return FileVersion(st.st_size, st.st_mtime_ns, st.st_ino, st.st_ctime_ns)


def locate(root: Path, rel: str) -> tuple[Path, FileVersion]:
    """The resolved path of the regular file ``rel`` under the resolved ``root``, and its
    version: :func:`safe_path` and :func:`_signature` in one, with one ``lstat`` per
    component of ``rel`` when none is a symlink (the common case on every request; resolving
    from ``/`` cost a quarter of a small range's time), else the full resolution."""
    check_relative(rel)
    path = root
    for part in rel.split("/"):
        path = path / part
        try:
            st = os.lstat(path)
        except OSError as exc:
            raise NotFoundError("no such file", where=rel[:80]) from exc
        if stat.S_ISLNK(st.st_mode):
            resolved = safe_path(root, rel)
            return resolved, _signature(resolved)
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
        if identity is not None:
            return identity
        f.seek(0)
        digest = hashlib.sha256()
        while block := f.read(_HASH_BLOCK):
            digest.update(block)
    return f'"{digest.hexdigest()}"'


class Catalog:
    """Files and scenes under one root, with caches holding one entry per resolved file (its
    current version only, at most MAX_CACHED files).

    The root is a folder, or one file (single-file mode): then only that file is served, as
    ``/files/<name>`` and, for a ``.tsogs`` container, as the scene ``<name without .tsogs>``.
    """

    def __init__(self, root: Path) -> None:
        resolved = root.resolve()
        self.only: str | None = resolved.name if resolved.is_file() else None
        self.root = resolved.parent if self.only is not None else resolved
        self._etags: dict[Path, tuple[FileVersion, str]] = {}
        self._scenes: dict[Path, tuple[FileVersion, SceneEntry]] = {}
        self._pending: dict[tuple[str, Path, FileVersion], asyncio.Future[Any]] = {}

    def check_only(self, rel: str) -> None:
        """In single-file mode, anything but that file (and, for a container, the thumbnail
        beside it, which the scene list shows) is not found."""
        if self.only is not None and rel != self.only and rel != _thumbnail_of(self.only):
            raise NotFoundError("no such file", where=rel[:80])

    async def file(self, rel: str) -> Representation:
        """The whole file at ``rel`` (relative to the root), its ETag computed once per
        version (:func:`container_etag`, else one of the content)."""
        path, version = await self._find(rel)
        cached = self._etags.get(path)
        if cached is None or cached[0] != version:
            try:
                tag = await self._once("etag", path, version, lambda: self._tag(path))
            except OSError as exc:  # vanished or unreadable since the stat
                raise unreadable(exc, "no such file", path.name) from exc
            remember(self._etags, path, cached := (version, tag))
        return self._whole(path, version, cached[1])

    async def _find(self, rel: str) -> tuple[Path, FileVersion]:
        """The file ``rel`` names and its version (NotFoundError when there is none)."""
        self.check_only(rel)
        return locate(self.root, rel)

    async def _tag(self, path: Path) -> str:
        """The ETag of the file at ``path``, read in a worker thread."""
        return await asyncio.to_thread(_content_etag, self.root, path)

    def source_of(self, path: Path) -> ByteSource:
        """The bytes of the file at ``path`` (a path as :meth:`_find` gives), read async."""
        return FileSource(path)

    def _whole(self, path: Path, version: FileVersion, etag: str) -> Representation:
        """The representation of a whole file under the root."""
        kind = CONTAINER_TYPE if path.suffix == CONTAINER_SUFFIX else guess_type(path)
        return Representation(path, 0, version.size, etag, version.mtime_ns / 1e9, kind, self.root)

    async def _once(
        self, kind: str, path: Path, version: FileVersion, work: Callable[[], Awaitable[_T]]
    ) -> _T:
        """``work()`` run once per (kind, file version) however many requests ask at the same
        time: a cold cache must not cost one full read or parse per request."""
        key = (kind, path, version)
        task = self._pending.get(key)
        if task is None:
            started: asyncio.Future[Any] = asyncio.ensure_future(work())
            self._pending[key] = task = started
            started.add_done_callback(lambda t: _retrieved(self._pending.pop(key, t)))
        # shielded: a client leaving does not cancel the others' wait; the kind keys the type
        return cast(_T, await asyncio.shield(task))

    async def scene(self, scene_id: str) -> SceneEntry:
        """The scene ``scene_id``: ``<id>.tsogs`` if it exists, else the folder ``<id>/``."""
        path, version, packed = await self._scene_file(scene_id)
        cached = self._scenes.get(path)
        if cached is None or cached[0] != version:
            scene = await self._once(
                "scene", path, version, lambda: self._open(scene_id, path, packed, version)
            )
            remember(self._scenes, path, cached := (version, scene))
        return _named(cached[1], scene_id)

    async def _scene_file(self, scene_id: str) -> tuple[Path, FileVersion, bool]:
        """The container or manifest file of a scene, its version, and whether it is packed."""
        try:
            path, version = await self._find(scene_id + CONTAINER_SUFFIX)
            return path, version, True
        except NotFoundError:
            path, version = await self._find(f"{scene_id}/{MANIFEST}")
            return path, version, False

    async def _open(
        self, scene_id: str, path: Path, packed: bool, version: FileVersion
    ) -> SceneEntry:
        """Open a container or read an unpacked manifest through the async reader
        (NotFoundError when unreadable, BusyError when out of file descriptors)."""
        try:
            index, manifest_json, per_frame = await _read_scene(
                self.source_of(path), packed, version.size
            )
        except TsogError as exc:
            raise unreadable(exc, f"not a readable scene: {exc.message}", scene_id) from exc
        size = len(manifest_json) + index.manifest.payload_bytes if not packed else version.size
        mtime = version.mtime_ns / 1e9
        return SceneEntry(scene_id, path, packed, index, manifest_json, mtime, size, per_frame)

    def relative(self, path: Path) -> str:
        """The root-relative form of a resolved path under the root."""
        return path.relative_to(self.root).as_posix()

    def scene_relative(self, scene: SceneEntry) -> str:
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
        """Ids of every container and unpacked layout under the root (symlinks not followed;
        names that are not :func:`servable` skipped, with the folders below them)."""
        if self.only is not None:
            suffixed = self.only.endswith(CONTAINER_SUFFIX)
            return [self.only.removesuffix(CONTAINER_SUFFIX)] if suffixed else []
        ids: set[str] = set()
        for folder, dirs, files in os.walk(self.root):
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and servable(d))
            rel = Path(folder).relative_to(self.root)
            if MANIFEST in files and rel != Path("."):
                ids.add(rel.as_posix())
            for name in files:
                if name.endswith(CONTAINER_SUFFIX) and not name.startswith(".") and servable(name):
                    ids.add((rel / name).as_posix().removesuffix(CONTAINER_SUFFIX))
        return sorted(ids)

    def chunk(self, scene: SceneEntry, chunk_id: int) -> Representation:
        """The bytes of one chunk: a slice of the container or a file of the unpacked layout;
        its ETag the chunk's SHA-256."""
        chunks = scene.index.manifest.chunks
        if not 0 <= chunk_id < len(chunks):
            raise NotFoundError(f"no chunk {chunk_id} (it has {len(chunks)})", where=scene.id)
        entry: ChunkEntry = chunks[chunk_id]
        return self._chunk(scene, entry, f'"{entry.sha256}"')

    def _chunk(self, scene: SceneEntry, entry: ChunkEntry, etag: str) -> Representation:
        """The representation of one chunk of ``scene`` (see :meth:`chunk`)."""
        if scene.packed:
            return Representation(
                scene.path, entry.offset, entry.length, etag, scene.mtime, SOG_TYPE
            )
        path, version = locate(scene.path.parent, entry.file)
        mtime = version.mtime_ns / 1e9
        return Representation(path, 0, version.size, etag, mtime, SOG_TYPE, self.root)


async def _read_scene(
    source: ByteSource, packed: bool, size: int
) -> tuple[StreamIndex, bytes, int]:
    """The index, manifest JSON and Gaussians per frame of a container or an unpacked manifest
    of ``size`` bytes, read through ``source`` (the one async reader for files and stores); an
    unpacked manifest over MAX_INDEX_BYTES is refused before it is read."""
    if packed:
        index, manifest_json = await read_index(source), None
    else:
        if size > MAX_INDEX_BYTES:
            raise SourceError(f"manifest over {MAX_INDEX_BYTES} bytes", where=source.name)
        manifest_json = await source.read(ByteRange(0, size))
        index = unpacked_index(manifest_json, where=source.name)
    text, per_frame = await asyncio.to_thread(_describe, index, manifest_json)
    return index, text, per_frame


def _describe(index: StreamIndex, manifest_json: bytes | None) -> tuple[bytes, int]:
    """The manifest JSON (``manifest_json`` when read from an unpacked layout) and the
    Gaussians per frame of a scene: run in a worker thread, so a large index never stalls the
    event loop."""
    text = manifest_json if manifest_json is not None else dump_manifest(index.manifest)
    return text, gaussians_per_frame(index.manifest)


def _named(scene: SceneEntry, scene_id: str) -> SceneEntry:
    """``scene`` under the id it was asked by: ids that alias one file through symlinks share
    one cache entry, not one entry each."""
    return scene if scene.id == scene_id else replace(scene, id=scene_id)


def _retrieved(task: asyncio.Future[Any]) -> None:
    """Mark a task's exception as seen (its waiters may all have gone)."""
    if not task.cancelled():
        task.exception()


def remember(cache: dict[_K, _V], path: _K, value: _V) -> None:
    """Store ``value`` as the only version of ``path``, the oldest entry dropped past the cap."""
    cache.pop(path, None)
    cache[path] = value
    if len(cache) > MAX_CACHED:
        del cache[next(iter(cache))]


def _thumbnail_of(name: str) -> str | None:
    """The thumbnail file of a container name (None for any other file)."""
    return thumbnail_path(name) if name.endswith(CONTAINER_SUFFIX) else None


def guess_type(path: Path) -> str:
    """A media type from the extension (octet-stream when unknown)."""
    known = {
        ".json": "application/json",
        ".sog": SOG_TYPE,
        ".png": PNG_TYPE,
        ".ply": "application/octet-stream",
    }
    return known.get(path.suffix.lower(), "application/octet-stream")
