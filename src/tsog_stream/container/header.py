"""The fixed 128-byte header at offset 0 of a ``.tsogs`` container (docs/spec.md §8).

All integers little-endian. A reader MUST refuse a major version it does not know and any
flag bit it does not understand in ``required_flags``; it MAY ignore ``optional_flags``.
"""

from __future__ import annotations

import struct
from dataclasses import astuple, dataclass
from typing import ClassVar, Final

from ..constants import CONTAINER_MAGIC as MAGIC
from ..errors import FormatError, UnsupportedError

VERSION_MAJOR: Final = 1
VERSION_MINOR: Final = 1
"""1: payloads may start right after an index at offset 128 (a compact container)."""
HEADER_SIZE: Final = 128
PREFIX_SIZE: Final = 16 * 1024
"""What a reader fetches first: the index whenever it fits (one request), then payloads
(or payloads right after the index in a compact container)."""
COMPACT_MAX: Final = 4 * 1024 * 1024
"""Payload bytes up to which writers make a container compact: beyond, the 16 KiB prefix
costs under 0.4 % of the file."""
KNOWN_REQUIRED_FLAGS: Final = 0
INDEX_ZSTD: Final = 1
"""The only index compression code defined."""


@dataclass(frozen=True, slots=True)
class Header:
    """Where the index is and how to check it."""

    STRUCT: ClassVar[struct.Struct] = struct.Struct("<8sHHIIIQQQQ32s40x")

    version_major: int
    version_minor: int
    required_flags: int
    optional_flags: int
    index_codec: int
    index_offset: int
    index_length: int
    index_raw_length: int
    file_length: int
    index_sha256: bytes

    @classmethod
    def of_index(cls, offset: int, index: tuple[bytes, bytes, int], file_length: int) -> Header:
        """This version's header for ``index`` (its bytes, the SHA-256 and length of its JSON,
        as :func:`~.index.encode_index` gives them) at ``offset`` of a ``file_length`` file."""
        data, sha256, raw_length = index
        current = (VERSION_MAJOR, VERSION_MINOR, 0, 0, INDEX_ZSTD)
        return cls(*current, offset, len(data), raw_length, file_length, sha256)

    def pack(self) -> bytes:
        """The 128 header bytes."""
        return self.STRUCT.pack(MAGIC, *astuple(self))

    @classmethod
    def unpack(cls, data: bytes, *, where: str = "<container>") -> Header:
        """Parse and check the first 128 bytes of a container."""
        if len(data) < HEADER_SIZE:
            raise FormatError(
                f"file is {len(data)} bytes, shorter than the {HEADER_SIZE}-byte header",
                where=where,
            )
        fields = cls.STRUCT.unpack_from(data)
        if fields[0] != MAGIC:
            raise FormatError(f"not a .tsogs container (magic {fields[0]!r})", where=where)
        header = cls(*fields[1:])
        header.check(where)
        return header

    def check(self, where: str) -> None:
        """Refuse versions and flags this reader does not understand."""
        if self.version_major != VERSION_MAJOR:
            raise UnsupportedError(
                f"container version {self.version_major}.{self.version_minor}; this reader "
                f"understands {VERSION_MAJOR}.x",
                where=where,
            )
        unknown = self.required_flags & ~KNOWN_REQUIRED_FLAGS
        if unknown:
            raise UnsupportedError(f"unknown required flags 0x{unknown:08x}", where=where)
        if self.index_codec != INDEX_ZSTD:
            raise UnsupportedError(f"unknown index codec {self.index_codec}", where=where)
        if (
            self.index_offset < HEADER_SIZE
            or self.index_offset + self.index_length > self.file_length
        ):
            raise FormatError(
                f"index [{self.index_offset}, +{self.index_length}) lies outside the "
                f"{self.file_length}-byte file",
                where=where,
            )

    def payload_area(self) -> tuple[int, int]:
        """[start, end) where chunk payloads may lie: after an index inside the first 16 KiB,
        else from 16 KiB up to the index appended after them."""
        if self.index_offset < PREFIX_SIZE:
            return self.index_offset + self.index_length, self.file_length
        return PREFIX_SIZE, min(self.index_offset, self.file_length)


def container_length(payload_bytes: int | float, index_bytes: int | float) -> float:
    """Bytes of the container a writer makes of these payloads and compressed index."""
    if HEADER_SIZE + index_bytes > PREFIX_SIZE:
        return PREFIX_SIZE + payload_bytes + index_bytes
    if payload_bytes <= COMPACT_MAX:
        return HEADER_SIZE + index_bytes + payload_bytes
    return PREFIX_SIZE + payload_bytes
