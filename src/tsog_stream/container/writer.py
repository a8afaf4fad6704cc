"""Writing a container: chunk payloads in order, then the header and the index.

Payloads of at most ``COMPACT_MAX`` in all are held and written right after the index (16 KiB
of padding is 9 % of a 180 kB container); more stream after a reserved 16 KiB prefix, which
takes the index at the end when it fits (one request for a reader), else the index follows
them. Files are built under a temporary name and renamed into place (``io.files``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
from collections.abc import Iterator
from typing import Protocol

from ..errors import SourceError
from ..io.files import local_path, make_parents, remove_made, temp_path
from ..schemas.manifest import Manifest
from .header import COMPACT_MAX, HEADER_SIZE, PREFIX_SIZE, Header
from .index import encode_index


class Sink(Protocol):
    """Where a container's bytes go: appended in order, then the prefix (and the index, when
    it does not fit there) written at finish; a file, or an upload holding its first part."""

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
    """Appends chunk payloads to a :class:`Sink` and finishes it with header + index.

    Offsets :meth:`add` returns count from after the 16 KiB prefix; a compact container moves
    every chunk back by the same amount at finish, in the index it writes.
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
        index = encode_index(manifest)
        size = len(index[0])
        if self._held is not None:
            compact = _compact_index(manifest, HEADER_SIZE + size)
            if compact is not None:
                return self._finish_compact(*compact)
            self._reserve_prefix()
        in_prefix = HEADER_SIZE + size <= PREFIX_SIZE
        offset = HEADER_SIZE if in_prefix else self.position
        file_length = self.position if in_prefix else self.position + size
        self.out.seek(offset)
        self.out.write(index[0])
        self.out.seek(0)
        self.out.write(Header.of_index(offset, index, file_length).pack())
        self.out.seek(file_length)
        self.out.truncate()
        return file_length

    def _finish_compact(self, index: tuple[bytes, bytes, int], start: int) -> int:
        """Header, index, zeros up to ``start``, then the payloads held."""
        file_length = start + self.position - PREFIX_SIZE
        header = Header.of_index(HEADER_SIZE, index, file_length).pack()
        self.out.write(header + index[0] + bytes(start - HEADER_SIZE - len(index[0])))
        for payload in self._held or ():
            self.out.write(payload)
        self._held = None
        self.out.truncate()
        return file_length


def _compact_index(manifest: Manifest, start: int) -> tuple[tuple[bytes, bytes, int], int] | None:
    """(index, payload start) of ``manifest`` with its payloads right after the index, or None
    when it does not fit the first 16 KiB; ``start``: where the index at the offsets ``add``
    gave ends. Moving the chunks changes the index's length, so starts are tried until the
    index ends at one (the lowest start it fits before is kept: a gap is a few zero bytes)."""
    best = None
    for _ in range(8):
        if start > PREFIX_SIZE:
            break
        index = encode_index(_moved(manifest, start - PREFIX_SIZE))
        end = HEADER_SIZE + len(index[0])
        if end <= start and (best is None or start < best[1]):
            best = (index, start)
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


@contextlib.contextmanager
def container_file(path: str | os.PathLike[str]) -> Iterator[PayloadWriter]:
    """A container being written to ``path``: a temp file beside it, renamed on success.

    Leaving by an exception (Ctrl-C included) removes the temp file and the folders it made,
    the destination untouched; an OSError (a full disk) becomes a SourceError naming it.
    """
    target = local_path(path)
    tmp, made = temp_path(target), make_parents(target)
    done, doing = False, "create a file here"
    try:
        with open(tmp, "w+b") as file:
            doing = "write"
            yield PayloadWriter(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, target)
        done = True
    except OSError as err:
        raise SourceError(f"cannot {doing}: {err.strerror or err}", where=str(target)) from err
    finally:
        if not done:
            with contextlib.suppress(OSError):
                tmp.unlink()
            remove_made(made)
