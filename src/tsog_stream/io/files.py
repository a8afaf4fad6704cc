"""Atomic file publishing: nothing half-written is ever left under the final name.

A file is written under a hidden temp name beside its target, ``.<name>.<pid>-<token>.tmp``,
then renamed. A run killed outright (SIGKILL, power loss) cannot remove its temp file; the pid
in the name lets the next run recognise it as stale (its writer is gone) and remove it.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import stat
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import BinaryIO, cast

from ..errors import SourceError
from .objects import (
    ObjectPath,
    as_location,
    check_destination,
    is_object_url,
    object_at,
    put_object,
)

Readable = str | os.PathLike[str] | ObjectPath
"""What the readers accept: a local path, a storage URL or an ObjectPath."""

_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[0-9a-f]{12}\.tmp$")


def temp_path(target: str | os.PathLike[str]) -> Path:
    """A fresh temp name beside ``target``, tagged with this process id."""
    path = Path(target)
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(6)}.tmp")


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one we may not signal counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def stale_temp_files(target: str | os.PathLike[str]) -> list[Path]:
    """Temp files of ``target`` left by writers that no longer run (sorted by name; none for
    a storage URL, where an upload is never visible before it completes)."""
    if is_object_url(target):
        return []
    path = Path(target)
    parent = path.parent if str(path.parent) else Path(".")
    stale = []
    with contextlib.suppress(OSError):
        for entry in parent.iterdir():
            m = _TEMP.match(entry.name)
            if not m or m["name"] != path.name or int(m["pid"]) == os.getpid():
                continue
            if not _alive(int(m["pid"])) and entry.is_file():
                stale.append(entry)
    return sorted(stale)


def remove_stale_temp_files(target: str | os.PathLike[str]) -> list[Path]:
    """Remove the stale temp files of ``target``; returns the ones removed."""
    removed = []
    for entry in stale_temp_files(target):
        try:
            entry.unlink()
        except OSError:
            continue
        removed.append(entry)
    return removed


def refuse_existing(path: str | os.PathLike[str], *, overwrite: bool) -> None:
    """Refuse to replace ``path`` unless ``overwrite``, or to write into a missing bucket
    (checked before any work is done)."""
    if is_object_url(path):
        check_destination(os.fspath(path))
    if not overwrite and as_location(path).exists():
        raise SourceError("already exists (pass --force to replace it)", where=str(path))


def atomic_write_bytes(
    path: str | os.PathLike[str], data: bytes | Sequence[bytes | memoryview]
) -> None:
    """Write ``data`` (or its parts, in order) to a temp file beside ``path``, then rename it.

    The temp file is created with the umask's permissions (unlike ``mkstemp``), fsynced, and
    removed on any failure, so the target is either the old file or the complete new one.
    """
    parts = [data] if isinstance(data, bytes | bytearray | memoryview) else data
    if is_object_url(path):
        put_object(os.fspath(path), b"".join(parts))
        return
    target = Path(path)
    tmp = temp_path(target)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        msg = f"cannot create a file in {str(target.parent)!r}: {exc.strerror or exc}"
        raise SourceError(msg, where=str(target)) from exc
    try:
        with os.fdopen(fd, "wb") as out:
            for part in parts:
                out.write(part)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise SourceError(f"cannot write: {exc.strerror or exc}", where=str(target)) from exc
        raise


def atomic_write_folder(
    path: str | os.PathLike[str], files: Mapping[str, bytes], *, overwrite: bool
) -> None:
    """Publish ``files`` as a folder: filled under a temp name, then renamed into place."""
    target = Path(path)
    refuse_existing(target, overwrite=overwrite)
    parent = target.parent if str(target.parent) else Path(".")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=parent))
    except OSError as exc:
        raise SourceError(
            f"cannot create a folder here: {exc.strerror}", where=str(target)
        ) from exc
    try:
        for name, data in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise SourceError(f"cannot write: {exc.strerror}", where=str(target)) from exc
        raise


def _open_regular(path: str | os.PathLike[str]) -> int:
    """A descriptor of the regular file ``path``. Opened without blocking and refused unless
    regular: a FIFO would wait forever for a writer, a device could never end."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_BINARY", 0))
    except IsADirectoryError as exc:
        raise SourceError("is a folder, expected a file", where=str(path)) from exc
    except OSError as exc:
        raise SourceError(f"cannot read: {exc.strerror}", where=str(path)) from exc
    mode = os.fstat(fd).st_mode
    if stat.S_ISREG(mode):
        return fd
    os.close(fd)
    if stat.S_ISDIR(mode):
        raise SourceError("is a folder, expected a file", where=str(path))
    raise SourceError("not a regular file (a FIFO, device or socket): refused", where=str(path))


def read_bytes(path: Readable) -> bytes:
    """The bytes of a regular file (or a stored object), or a SourceError that names it."""
    return read_head(path, -1)


def open_regular(path: Readable) -> BinaryIO:
    """A regular file (or a stored object) opened for binary reading (a FIFO, device or
    folder: a SourceError)."""
    if is_object_url(path):
        return object_at(path).open()
    return os.fdopen(_open_regular(cast("str | os.PathLike[str]", path)), "rb")


def read_head(path: Readable, limit: int) -> bytes:
    """At most ``limit`` first bytes of a regular file or stored object (all of it for -1),
    or a SourceError."""
    if is_object_url(path):
        return object_at(path).read_head(limit)
    with open_regular(path) as f:
        return read_from(f, limit, str(path))


def read_from(file: BinaryIO, limit: int, where: str) -> bytes:
    """At most ``limit`` next bytes of an open file (all the rest for -1), or a SourceError
    that names ``where``."""
    try:
        return file.read(limit)
    except OSError as exc:
        raise SourceError(f"cannot read: {exc.strerror}", where=where) from exc
