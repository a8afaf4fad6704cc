"""Atomic file publishing: nothing half-written is ever left under the final name.

An output location is checked before any work (:func:`check_output`); the folders above it
are made when missing, and removed again if the write fails.

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
_PROBE = ".tsog-write-probe"
"""The name whose temp files test that a folder takes new files (:func:`_check_can_create`)."""


def local_path(path: str | os.PathLike[str]) -> Path:
    """The local Path a path or ``file://`` URL names (a storage URL is not one: callers
    check :func:`is_object_url` first)."""
    return cast(Path, as_location(path))


def temp_path(target: str | os.PathLike[str]) -> Path:
    """A fresh temp name beside ``target``, tagged with this process id."""
    path = local_path(target)
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
    """Temp files of ``target`` (and write probes in its folder) left by writers that no
    longer run (sorted by name; none for a storage URL, where an upload is never visible
    before it completes)."""
    if is_object_url(target):
        return []
    path = local_path(target)
    parent = path.parent if str(path.parent) else Path(".")
    stale = []
    with contextlib.suppress(OSError):
        for entry in parent.iterdir():
            m = _TEMP.match(entry.name)
            if not m or m["name"] not in (path.name, _PROBE) or int(m["pid"]) == os.getpid():
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


def check_output(
    path: str | os.PathLike[str], *, overwrite: bool, folder: bool | None = False
) -> None:
    """Refuse, before any work, an output location the writers could not publish to: one
    that exists, unless ``overwrite``; a folder where a file is wanted (``folder`` False) or a
    file where a folder is (True; None: either); a device, FIFO or socket; a path below a
    regular file; a folder in which nothing can be created (tried with a temp file: the
    permission bits do not say it for root or on /proc); a missing storage bucket. Missing
    parent folders are fine: the writers make them (:func:`make_parents`). One clear error,
    so a long read or encode never ends in a refusal to write."""
    where = os.fspath(path)
    if is_object_url(path):
        check_destination(where)
        if not overwrite and as_location(path).exists():
            raise SourceError("already exists (pass --force to replace it)", where=where)
        return
    target = local_path(path)
    if folder is False and where.endswith(("/", os.sep)):
        raise SourceError("ends with a path separator: expected a file name", where=where)
    _check_target(target, where, overwrite=overwrite, folder=folder)
    _check_can_create(_nearest_folder(target, where), where)


def _check_target(target: Path, where: str, *, overwrite: bool, folder: bool | None) -> None:
    """Refuse what is at ``target`` already, if anything, as :func:`check_output` says."""
    try:
        mode = os.stat(target).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return  # nothing there (or below a file: the parents' check says so)
    except OSError as exc:
        raise SourceError(f"cannot write here: {exc.strerror}", where=where) from exc
    if stat.S_ISDIR(mode) and folder is False:
        raise SourceError("is a folder: expected the name of a file to write", where=where)
    if stat.S_ISREG(mode) and folder is True:
        raise SourceError("is a file: expected the name of a folder to write", where=where)
    if not (stat.S_ISDIR(mode) or stat.S_ISREG(mode)):
        raise SourceError("is a device, FIFO or socket: refused as an output", where=where)
    if not overwrite:
        raise SourceError("already exists (pass --force to replace it)", where=where)


def _nearest_folder(target: Path, where: str) -> Path:
    """The nearest existing folder above ``target``; a SourceError when a regular file (or
    anything but a folder) stands in the way."""
    parent = target.absolute().parent
    for place in (parent, *parent.parents):
        try:
            mode = os.stat(place).st_mode
        except (FileNotFoundError, NotADirectoryError):
            continue
        except OSError as exc:
            msg = f"cannot write in {str(place)!r}: {exc.strerror}"
            raise SourceError(msg, where=where) from exc
        if stat.S_ISDIR(mode):
            return place
        msg = f"{str(place)!r} is a file, not a folder: nothing can be written below it"
        raise SourceError(msg, where=where)
    raise SourceError("no existing folder above it", where=where)


def _check_can_create(folder: Path, where: str) -> None:
    """Create and remove a temp file in ``folder``: a SourceError if that fails."""
    probe = temp_path(folder / _PROBE)
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except OSError as exc:
        msg = f"cannot create files in {str(folder)!r}: {exc.strerror or exc}"
        raise SourceError(msg, where=where) from exc
    with contextlib.suppress(OSError):
        probe.unlink()


def make_parents(target: str | os.PathLike[str]) -> list[Path]:
    """Make the missing folders above ``target``; returns those made, outermost first (for
    :func:`remove_made` when the write fails: nothing is left behind)."""
    made: list[Path] = []
    parent = local_path(target).parent
    missing = [p for p in (parent, *parent.parents) if not p.exists()]
    for place in reversed(missing):
        try:
            place.mkdir()
        except FileExistsError:
            continue  # made by another writer meanwhile (or a file: the write says so)
        except OSError as exc:
            for done in reversed(made):
                with contextlib.suppress(OSError):
                    done.rmdir()
            raise SourceError(
                f"cannot make the folder {str(place)!r}: {exc.strerror}", where=str(target)
            ) from exc
        made.append(place)
    return made


def remove_made(made: Sequence[Path]) -> None:
    """Remove the folders :func:`make_parents` made, innermost first, each only if empty."""
    for place in reversed(made):
        with contextlib.suppress(OSError):
            place.rmdir()


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
    target = local_path(path)
    tmp = temp_path(target)
    made = make_parents(target)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        remove_made(made)
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
        remove_made(made)
        if isinstance(exc, OSError):
            raise SourceError(f"cannot write: {exc.strerror or exc}", where=str(target)) from exc
        raise


def atomic_write_folder(
    path: str | os.PathLike[str], files: Mapping[str, bytes], *, overwrite: bool
) -> None:
    """Publish ``files`` as a folder: filled under a temp name, then renamed into place (the
    folders above it made if missing)."""
    target = local_path(path)
    check_output(target, overwrite=overwrite, folder=True)
    parent = target.parent if str(target.parent) else Path(".")
    made = make_parents(target)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=parent))
    except OSError as exc:
        remove_made(made)
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
        remove_made(made)
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
