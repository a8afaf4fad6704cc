"""Atomic file publishing: nothing half-written is ever left under the final name."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path

from ..errors import SourceError


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to a temp file beside ``path``, fsync it, then rename it into place."""
    target = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f".{target.name}.", suffix=".tmp", dir=target.parent or "."
        )
    except OSError as exc:
        raise SourceError(f"cannot create a file here: {exc.strerror}", where=str(target)) from exc
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise SourceError(f"cannot write: {exc.strerror}", where=str(target)) from exc
        raise


def atomic_write_folder(
    path: str | os.PathLike[str], files: Mapping[str, bytes], *, overwrite: bool
) -> None:
    """Publish ``files`` as a folder: filled under a temp name, then renamed into place."""
    target = Path(path)
    if target.exists() and not overwrite:
        raise SourceError("already exists (pass --force to replace it)", where=str(target))
    parent = target.parent if str(target.parent) else Path(".")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=parent))
    except OSError as exc:
        raise SourceError(
            f"cannot create a folder here: {exc.strerror}", where=str(target)
        ) from exc
    try:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise SourceError(f"cannot write: {exc.strerror}", where=str(target)) from exc
        raise


def read_bytes(path: str | os.PathLike[str]) -> bytes:
    """The bytes of a file, or a SourceError that names it."""
    try:
        return Path(path).read_bytes()
    except IsADirectoryError as exc:
        raise SourceError("is a folder, expected a file", where=str(path)) from exc
    except OSError as exc:
        raise SourceError(f"cannot read: {exc.strerror}", where=str(path)) from exc
