"""Writing a container: chunk payloads streamed after a reserved 16 KiB prefix, index last.

At :meth:`ContainerWriter.finish` the index goes into the prefix right after the header when
it fits (so a reader needs one request), else it is appended after the payloads. The file is
built under a temporary name and renamed into place, so an interrupted write leaves nothing
(a killed one leaves a temp file that the next run removes: see ``io.files``).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, Protocol

from ..errors import SourceError
from ..io.files import temp_path
from ..schemas.manifest import Manifest
from .header import HEADER_SIZE, INDEX_ZSTD, PREFIX_SIZE, VERSION_MAJOR, VERSION_MINOR, Header
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
    """Appends chunk payloads to a seekable binary stream and finishes it with header + index."""

    def __init__(self, out: Sink) -> None:
        self.out = out
        self.out.seek(0)
        self.out.write(b"\x00" * PREFIX_SIZE)
        self.position = PREFIX_SIZE

    def add(self, payload: bytes) -> tuple[int, int, str]:
        """Append one chunk; returns (offset, length, SHA-256 hex)."""
        offset = self.position
        self.out.write(payload)
        self.position += len(payload)
        return offset, len(payload), hashlib.sha256(payload).hexdigest()

    def finish(self, manifest: Manifest) -> int:
        """Write the index and the header; returns the file length."""
        index, digest, raw_length = encode_index(manifest)
        if HEADER_SIZE + len(index) <= PREFIX_SIZE:
            index_offset = HEADER_SIZE
            file_length = self.position
        else:
            index_offset = self.position
            file_length = self.position + len(index)
        header = Header(
            VERSION_MAJOR,
            VERSION_MINOR,
            0,
            0,
            INDEX_ZSTD,
            index_offset,
            len(index),
            raw_length,
            file_length,
            digest,
        )
        self.out.seek(index_offset)
        self.out.write(index)
        self.out.seek(0)
        self.out.write(header.pack())
        self.out.seek(file_length)
        self.out.truncate()
        return file_length


class ContainerFile:
    """A container being written to ``path``: temp file beside it, renamed on success.

    Use as a context manager; leaving it by an exception (Ctrl-C included) removes the temp
    file and leaves the destination untouched. An OSError while writing (a full disk) becomes
    a SourceError naming the destination.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.tmp = temp_path(self.path)
        self._file: BinaryIO | None = None
        self.writer: PayloadWriter | None = None
        self.length = 0

    def __enter__(self) -> PayloadWriter:
        try:
            self._file = open(self.tmp, "w+b")
        except OSError as exc:
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
        if isinstance(exc, OSError):
            raise _write_error(exc, self.path) from exc


def _write_error(err: OSError, path: Path) -> SourceError:
    """A SourceError naming the destination (e.g. 'No space left on device')."""
    return SourceError(f"cannot write: {err.strerror or err}", where=str(path))
