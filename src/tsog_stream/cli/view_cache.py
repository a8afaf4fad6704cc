"""The cache of ``tsog view``'s segmented copies: bounded, newest version of each input kept.

One folder per input version (named by its fingerprint) holds the container and a
``source.json`` naming the input and its reading options. Making a copy removes the copies of
earlier versions of the same input read the same way (the input changed: they can never be
used again), then the least recently used others while the cache holds more than
MAX_CACHE_BYTES. A running ``tsog view`` holds a shared lock on its folder's ``source.json``,
so a copy being served is never removed.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

MAX_CACHE_BYTES = 4 << 30
"""Bytes of segmented copies kept at most (least recently used removed first), besides the
ones being made or served."""
SOURCE_FILE = "source.json"
"""Each copy's record of its input (path, options) and when it was last used (its mtime)."""
KEY_LENGTH = 24
"""Hex digits of a copy's folder name (the input's fingerprint): other names are not ours."""


@dataclass(frozen=True)
class Copy:
    """One segmented copy in the cache."""

    folder: Path
    source: dict[str, Any]
    used: float
    """When it was last made or reused (seconds since the epoch)."""
    size: int


def record(folder: Path, source: dict[str, Any]) -> None:
    """Write the copy's record of its input (after the container, so a copy without one is
    a copy being made, or one a failed run left)."""
    (folder / SOURCE_FILE).write_text(json.dumps(source, sort_keys=True))


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
    """After ``made`` was made: remove earlier versions of its input read the same way, then
    the least recently used copies while the cache holds more than ``limit`` bytes. Copies
    being served, and ``made`` itself, stay. Returns the folders removed."""
    copies = [c for c in _copies(root) if c.folder != made]
    mine = _read_source(made / SOURCE_FILE)
    removed = [c.folder for c in copies if mine is not None and _same_input(c.source, mine)]
    kept = [c for c in copies if c.folder not in removed]
    total = sum(c.size for c in kept) + _folder_size(made)
    for copy in sorted(kept, key=lambda c: c.used):
        if total <= limit:
            break
        removed.append(copy.folder)
        total -= copy.size
    return [folder for folder in removed if _remove_unless_served(folder)]


def _same_input(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two copies are of the same input read with the same options (then the older
    one is of an earlier version of its files, or of this program)."""
    return a.get("input") == b.get("input") and a.get("options") == b.get("options")


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
    """A copy's record, or None when it has none (being made) or it cannot be read."""
    try:
        source = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return source if isinstance(source, dict) else None


def _folder_size(folder: Path) -> int:
    """Bytes of the regular files directly in ``folder`` (a copy's container, its thumbnail
    and record)."""
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


__all__ = [
    "KEY_LENGTH",
    "MAX_CACHE_BYTES",
    "SOURCE_FILE",
    "evict",
    "mark_used",
    "record",
    "serving",
]
