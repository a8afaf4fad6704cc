"""Writing a container: chunk payloads in order, then the header and the index.

A container whose payloads total at most ``COMPACT_MAX`` is *compact*: the payloads are held
until :meth:`PayloadWriter.finish` and written right after the index, with no padding (16 KiB
of it is 9 % of a 180 kB container). A larger one streams its payloads after a reserved 16 KiB
prefix and at finish the index goes into that prefix when it fits (so a reader needs one
request), else after the payloads. The file is built under a temporary name and renamed into
place, so an interrupted write leaves nothing (a killed one leaves a temp file that the next
run removes: see ``io.files``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, Protocol

from ..errors import SourceError
from ..io.files import local_path, make_parents, remove_made, temp_path
from ..schemas.manifest import Manifest
from .header import (
    COMPACT_MAX,
    HEADER_SIZE,
    INDEX_ZSTD,
    PREFIX_SIZE,
    VERSION_MAJOR,
    VERSION_MINOR,
    Header,
)
from .index import encode_index


class Sink(Protocol):
    """Where a container's bytes go: appended in order, then the reserved prefix (and the
    index, when it does not fit there) written at finish. A file, or an upload holding its
    first part until the end (container/objects.py)."""

    def write(self, data: bytes, /) -> int:
        """Write at the current position."""
        ...

    def seek(self, offset: int, /) -> int:
        """Move the position (the writer only goes back into the prefix, or to the end)."""
        ...

    def truncate(self) -> int:
        """End the stream at the current position."""
        ...


class PayloadWriter:
    """Appends chunk payloads to a seekable binary stream and finishes it with header + index.

    Offsets returned by :meth:`add` count from the reserved 16 KiB prefix; a compact container
    moves every chunk back by the same amount at finish, in the index it writes.
    """

    def __init__(self, out: Sink) -> None:
        self.out = out
        self.out.seek(0)
        self.position = PREFIX_SIZE
        self._held: list[bytes] | None = []
        """Payloads not yet written, while the container may still be compact."""

    def add(self, payload: bytes) -> tuple[int, int, str]:
        """Append one chunk; returns (offset, length, SHA-256 hex)."""
        offset = self.position
        if self._held is not None and offset - PREFIX_SIZE + len(payload) <= COMPACT_MAX:
            self._held.append(payload)
        else:
            self._reserve_prefix()
            self.out.write(payload)
        self.position += len(payload)
        return offset, len(payload), hashlib.sha256(payload).hexdigest()

    def _reserve_prefix(self) -> None:
        """Give up on a compact container: the 16 KiB prefix, then the payloads held."""
        if self._held is None:
            return
        self.out.write(b"\x00" * PREFIX_SIZE)
        for payload in self._held:
            self.out.write(payload)
        self._held = None

    def finish(self, manifest: Manifest) -> int:
        """Write the index and the header; returns the file length."""
        index, digest, raw_length = encode_index(manifest)
        if self._held is not None:
            compact = _compact_index(manifest, HEADER_SIZE + len(index))
            if compact is not None:
                return self._finish_compact(*compact)
            self._reserve_prefix()
        if HEADER_SIZE + len(index) <= PREFIX_SIZE:
            index_offset = HEADER_SIZE
            file_length = self.position
        else:
            index_offset = self.position
            file_length = self.position + len(index)
        self.out.seek(index_offset)
        self.out.write(index)
        self.out.seek(0)
        self.out.write(_header(index, digest, raw_length, index_offset, file_length).pack())
        self.out.seek(file_length)
        self.out.truncate()
        return file_length

    def _finish_compact(self, index: bytes, digest: bytes, raw_length: int, start: int) -> int:
        """Header, index, zeros up to ``start``, then the payloads held."""
        file_length = start + self.position - PREFIX_SIZE
        header = _header(index, digest, raw_length, HEADER_SIZE, file_length)
        self.out.write(header.pack() + index + bytes(start - HEADER_SIZE - len(index)))
        for payload in self._held or ():
            self.out.write(payload)
        self._held = None
        self.out.truncate()
        return file_length


def _header(index: bytes, digest: bytes, raw_length: int, offset: int, length: int) -> Header:
    return Header(
        VERSION_MAJOR,
        VERSION_MINOR,
        0,
        0,
        INDEX_ZSTD,
        offset,
        len(index),
        raw_length,
        length,
        digest,
    )


def _compact_index(manifest: Manifest, start: int) -> tuple[bytes, bytes, int, int] | None:
    """(index, digest, raw length, payload start) of ``manifest`` with its payloads moved to
    right after the index, or None when the index does not fit the first 16 KiB; ``start``:
    where the index at the offsets ``add`` gave ends. Moving the chunks changes the index's
    length, so starts are tried until the index ends at one (the lowest start it fits before
    is kept: any gap is a few zero bytes)."""
    best = None
    for _ in range(8):
        if start > PREFIX_SIZE:
            break
        index, digest, raw_length = encode_index(_moved(manifest, start - PREFIX_SIZE))
        end = HEADER_SIZE + len(index)
        if end <= start and (best is None or start < best[3]):
            best = (index, digest, raw_length, start)
        if end == start:
            break
        start = end
    return best


def payloads_at(manifest: Manifest, start: int) -> Manifest:
    """``manifest`` with every chunk moved by the same amount so the first starts at
    ``start`` (their order and the gaps between them kept)."""
    if not manifest.chunks:
        return manifest
    return _moved(manifest, start - min(c.offset for c in manifest.chunks))


def _moved(manifest: Manifest, shift: int) -> Manifest:
    """``manifest`` with every chunk's offset moved by ``shift`` bytes."""
    chunks = [dataclasses.replace(c, offset=c.offset + shift) for c in manifest.chunks]
    return manifest.model_copy(update={"chunks": chunks})


class ContainerFile:
    """A container being written to ``path``: temp file beside it, renamed on success.

    Use as a context manager; leaving it by an exception (Ctrl-C included) removes the temp
    file and leaves the destination untouched (and removes the folders above it that it
    made). An OSError while writing (a full disk) becomes a SourceError naming the destination.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = local_path(path)
        self.tmp = temp_path(self.path)
        self._file: BinaryIO | None = None
        self.writer: PayloadWriter | None = None
        self.length = 0
        self._made: list[Path] = []

    def __enter__(self) -> PayloadWriter:
        self._made = make_parents(self.path)
        try:
            self._file = open(self.tmp, "w+b")
        except OSError as exc:
            remove_made(self._made)
            raise SourceError(
                f"cannot create a file here: {exc.strerror}", where=str(self.path)
            ) from exc
        self.writer = PayloadWriter(self._file)
        return self.writer

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        file = self._file
        if file is None:
            return
        try:
            if kind is None:
                file.flush()
                os.fsync(file.fileno())
            file.close()
            if kind is None:
                os.replace(self.tmp, self.path)
        except OSError as err:
            kind = type(err)
            raise _write_error(err, self.path) from err
        finally:
            if kind is not None:
                with contextlib.suppress(OSError):
                    file.close()
                with contextlib.suppress(OSError):
                    self.tmp.unlink()
                remove_made(self._made)
        if isinstance(exc, OSError):
            raise _write_error(exc, self.path) from exc


def _write_error(err: OSError, path: Path) -> SourceError:
    """A SourceError naming the destination (e.g. 'No space left on device')."""
    return SourceError(f"cannot write: {err.strerror or err}", where=str(path))
