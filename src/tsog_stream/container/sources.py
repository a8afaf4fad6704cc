"""Byte sources: the one async interface (size, read a range) every container reader runs on,
so HTTP, object stores, memory and local files share one reader; each counts its requests and
bytes. :func:`read_index` opens a container over any of them in one request of <= 16 KiB.
"""

from __future__ import annotations

import asyncio
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from ..errors import SourceError
from .header import PREFIX_SIZE, Header
from .ranges import ByteRange
from .stream_index import StreamIndex, check_file_length, container_index, index_span


@dataclass
class ReadStats:
    """Requests made and bytes received through a source."""

    requests: int = 0
    bytes: int = 0

    def add(self, n: int) -> None:
        """Record one request that returned ``n`` bytes."""
        self.requests += 1
        self.bytes += n


class ByteSource(Protocol):
    """Random access to the bytes of one file."""

    name: str
    stats: ReadStats

    async def size(self) -> int:
        """Length of the file in bytes."""
        ...

    async def read(self, span: ByteRange) -> bytes:
        """Exactly the bytes of ``span`` (SourceError if the file is shorter)."""
        ...


def counted(data: bytes, span: ByteRange, source: ByteSource) -> bytes:
    """``data``, counted in the source's stats, if it has the span's length; else SourceError."""
    if len(data) != span.length:
        found = f"asked for bytes [{span.start}, {span.end}), got {len(data)} bytes"
        raise SourceError(found, where=source.name)
    source.stats.add(len(data))
    return data


class MemorySource:
    """A byte source over bytes already in memory."""

    def __init__(self, data: bytes, name: str = "<memory>") -> None:
        self.data = data
        self.name = name
        self.stats = ReadStats()

    async def size(self) -> int:
        """Length of the data."""
        return len(self.data)

    async def read(self, span: ByteRange) -> bytes:
        """A slice of the data."""
        return counted(self.data[span.start : span.end], span, self)


class FileSource:
    """A byte source over a local file, read with ``pread`` in a worker thread."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.name = str(path)
        self.stats = ReadStats()

    async def size(self) -> int:
        """Current size of the file (a FIFO, device or socket is refused: it may never end)."""
        try:
            st = await asyncio.to_thread(os.stat, self.path)
        except OSError as exc:
            raise SourceError(f"cannot read: {exc.strerror}", where=self.name) from exc
        if not stat.S_ISREG(st.st_mode):
            kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO, device or socket"
            raise SourceError(f"not a regular file ({kind}): refused", where=self.name)
        return st.st_size

    def _pread(self, span: ByteRange) -> bytes:
        with open(self.path, "rb") as f:
            return os.pread(f.fileno(), span.length, span.start)

    async def read(self, span: ByteRange) -> bytes:
        """The bytes of ``span`` from the file."""
        try:
            data = await asyncio.to_thread(self._pread, span)
        except OSError as exc:
            raise SourceError(f"cannot read: {exc.strerror}", where=self.name) from exc
        return counted(data, span, self)


async def read_index(source: ByteSource) -> StreamIndex:
    """Read and check the header and index of the container behind ``source``."""
    size = await source.size()
    first = await source.read(ByteRange(0, min(size, PREFIX_SIZE)))
    header = Header.unpack(first, where=source.name)
    check_file_length(header, size, where=source.name)
    span = index_span(header)
    data = first[span.start : span.end] if span.end <= len(first) else await source.read(span)
    return container_index(header, data, where=source.name)
