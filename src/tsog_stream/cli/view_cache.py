"""The cache of ``tsog view``'s segmented copies: bounded, newest version of each input kept.

One folder per input version (named by its fingerprint) holds the container and a
``source.json`` naming the input and its reading options. Making a copy removes the copies of
earlier versions of the same input read the same way (the input changed: they can never be
used again), then the least recently used others while the cache holds more than
MAX_CACHE_BYTES. A running ``tsog view`` holds a shared lock on its folder's ``source.json``,
so a copy being served is never removed, and an exclusive lock on the folder itself while it
checks or makes the copy, so a second ``tsog view`` of the same input waits, then reuses it.

Whatever a folder's place holds that is not a complete copy (a symbolic link, a file, a run's
leftovers, a damaged container) is removed and made again; links are removed, never followed,
and nothing outside the cache folder is ever touched.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import stat
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from ..errors import SourceError

MAX_CACHE_BYTES = 4 << 30
"""Bytes of copies kept at most, besides the ones being made or served."""
SOURCE_FILE = "source.json"
"""Each copy's record of its input (path, options); its mtime says when it was last used."""
KEY_LENGTH = 24
"""Hex digits of a copy's folder name (the input's fingerprint): other names are not ours."""
CLAIM_ATTEMPTS = 8
"""Claims of a copy's folder removed while we waited for its lock, before giving up."""


@dataclass(frozen=True)
class Copy:
    """One segmented copy in the cache."""

    folder: Path
    source: dict[str, Any]
    used: float
    """When it was last made or reused (seconds since the epoch)."""
    size: int


def record(folder: Path, source: dict[str, Any]) -> None:
    """Write the copy's record, after its container: a copy without one is unfinished."""
    (folder / SOURCE_FILE).write_text(json.dumps(source, sort_keys=True))


@contextlib.contextmanager
def claimed(root: Path, key: str, waiting: Callable[[str], None]) -> Iterator[Path]:
    """The folder ``root/key`` (a link or file in its place removed, never followed), held
    exclusively until exit so two runs never make one copy at once (the second waits, said by
    ``waiting``). An unusable cache is a one-line :class:`SourceError`."""
    folder = root / key
    for _ in range(CLAIM_ATTEMPTS):
        handle = _open_folder(root, folder)
        try:
            _lock(handle, waiting)
            if _same_file(handle, folder):  # not removed while we waited for it
                yield folder
                return
        finally:
            os.close(handle)
    raise SourceError(
        "its folders keep disappearing; is another program clearing it?", where=str(root)
    )


def _open_folder(root: Path, folder: Path) -> int:
    """Make ``folder`` (a real folder in ``root``) and open it without following links."""
    try:
        root.mkdir(parents=True, exist_ok=True)
        if entry_kind(folder) not in ("folder", "missing"):
            folder.unlink()  # a link or a file in the copy's place: the entry itself goes
        folder.mkdir(exist_ok=True)
        return os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as exc:
        raise unusable_cache(root, exc) from None


def unusable_cache(root: Path, exc: OSError) -> SourceError:
    """The one-line error of a cache folder that cannot be made or written."""
    if isinstance(exc, FileExistsError):
        why = "it is not a folder"
    elif isinstance(exc, NotADirectoryError):
        why = "a part of this path is a file, not a folder"
    elif isinstance(exc, FileNotFoundError):
        why = "no folder can be made here"  # /proc, /sys: present, yet nothing can be added
    else:
        why = (exc.strerror or str(exc)).lower()
    return SourceError(
        f"cannot keep segmented copies here: {why} (--cache DIR chooses another folder)",
        where=str(root),
    )


def _lock(handle: int, waiting: Callable[[str], None]) -> None:
    """Lock the open folder exclusively, announcing a wait for another run."""
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        waiting("waiting for another tsog view making the same copy")
        fcntl.flock(handle, fcntl.LOCK_EX)
    except OSError:
        return  # a file system without locks: the copy is made unguarded


def _same_file(handle: int, path: Path) -> bool:
    """Whether ``path`` (unfollowed) is still the folder open as ``handle``."""
    try:
        found = path.lstat()
    except OSError:
        return False
    held = os.fstat(handle)
    return (found.st_dev, found.st_ino) == (held.st_dev, held.st_ino)


def entry_kind(path: Path) -> str:
    """What ``path`` itself is, unfollowed: missing, folder, file, symbolic link or other."""
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return "missing"
    if stat.S_ISLNK(mode):
        return "symbolic link"
    if stat.S_ISDIR(mode):
        return "folder"
    return "file" if stat.S_ISREG(mode) else "other"


def has_record(folder: Path) -> bool:
    """Whether a copy's folder holds its record, a regular file that reads as one."""
    return _read_source(folder / SOURCE_FILE) is not None


def clear(folder: Path) -> bool:
    """Remove what the claimed ``folder`` holds (links unfollowed); whether it held anything."""
    found = False
    for path in folder.iterdir():
        found = True
        if entry_kind(path) == "folder":
            shutil.rmtree(path)  # removes the links inside, never what they point to
        else:
            path.unlink(missing_ok=True)
    return found


def mark_used(folder: Path) -> None:
    """Mark a reused copy as used now (the eviction order)."""
    with contextlib.suppress(OSError):
        os.utime(folder / SOURCE_FILE)


@contextlib.contextmanager
def serving(folder: Path) -> Iterator[None]:
    """Hold the copy while it is served: eviction skips a folder whose record is locked."""
    try:
        handle: IO[str] | None = open(folder / SOURCE_FILE)  # noqa: SIM115 - held until exit
    except OSError:
        handle = None  # no record: nothing evicts a copy without one
    try:
        if handle is not None:
            fcntl.flock(handle, fcntl.LOCK_SH)
        yield
    finally:
        if handle is not None:
            handle.close()


def evict(root: Path, made: Path, limit: int = MAX_CACHE_BYTES) -> list[Path]:
    """After ``made``: remove earlier copies of its input read the same way, then the least
    recently used while the cache holds more than ``limit`` bytes; never ``made`` nor a copy
    being served. Returns the folders removed."""
    copies = [c for c in _copies(root) if c.folder != made]
    mine = _read_source(made / SOURCE_FILE)
    same = ("input", "options")  # the older copy: of earlier files or an earlier program
    removed = [
        c.folder
        for c in copies
        if mine is not None and all(c.source.get(k) == mine.get(k) for k in same)
    ]
    kept = [c for c in copies if c.folder not in removed]
    total = sum(c.size for c in kept) + _folder_size(made)
    for copy in sorted(kept, key=lambda c: c.used):
        if total <= limit:
            break
        removed.append(copy.folder)
        total -= copy.size
    return [folder for folder in removed if _remove_unless_served(folder)]


def _copies(root: Path) -> list[Copy]:
    """The copies in the cache with a record (folders of other names are left alone)."""
    found = []
    with contextlib.suppress(OSError):
        for folder in root.iterdir():
            if len(folder.name) != KEY_LENGTH or folder.is_symlink() or not folder.is_dir():
                continue
            path = folder / SOURCE_FILE
            source = _read_source(path)
            if source is None:
                continue
            with contextlib.suppress(OSError):
                found.append(Copy(folder, source, path.stat().st_mtime, _folder_size(folder)))
    return found


def _read_source(path: Path) -> dict[str, Any] | None:
    """A copy's record; None when missing, not a regular file, or unreadable."""
    if entry_kind(path) != "file":
        return None
    try:
        source = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return source if isinstance(source, dict) else None


def _folder_size(folder: Path) -> int:
    """Bytes of the regular files directly in ``folder`` (container, thumbnail, record)."""
    total = 0
    with contextlib.suppress(OSError):
        for path in folder.iterdir():
            with contextlib.suppress(OSError):
                if path.is_file() and not path.is_symlink():
                    total += path.stat().st_size
    return total


def _remove_unless_served(folder: Path) -> bool:
    """Remove a copy unless a running ``tsog view`` holds it; whether it was removed."""
    try:
        with open(folder / SOURCE_FILE) as handle:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            (folder / SOURCE_FILE).unlink()  # no record from here: never read as a copy
    except OSError:
        return False  # served now (the lock is held), or gone already
    shutil.rmtree(folder, ignore_errors=True)
    return True
