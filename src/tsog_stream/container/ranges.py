"""``ByteRange``: the one value type for a span of bytes, with an exclusive end.

Only the HTTP layer turns it into the inclusive ``Range: bytes=a-b`` syntax (RFC 9110 §14.1.2).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from ..errors import InputError


@dataclass(frozen=True, slots=True, order=True)
class ByteRange:
    """Bytes ``[start, end)`` of a file."""

    start: int
    end: int

    def __post_init__(self) -> None:
        if self.start < 0 or self.end < self.start:
            raise InputError(f"invalid byte range [{self.start}, {self.end})")

    @classmethod
    def sized(cls, start: int, length: int) -> ByteRange:
        """The range of ``length`` bytes from ``start``."""
        return cls(start, start + length)

    @property
    def length(self) -> int:
        """Number of bytes in the range."""
        return self.end - self.start

    def http_header(self) -> str:
        """The value of an HTTP ``Range`` header asking for exactly this range (inclusive end)."""
        if self.length == 0:
            raise InputError("an empty range cannot be requested over HTTP")
        return f"bytes={self.start}-{self.end - 1}"

    def within(self, size: int) -> bool:
        """True when the range lies inside a file of ``size`` bytes."""
        return self.end <= size


def coalesce(ranges: Iterable[ByteRange], gap: int = 0) -> list[ByteRange]:
    """Sorted ranges with overlapping ones, and ones at most ``gap`` bytes apart, merged."""
    out: list[ByteRange] = []
    for r in sorted(ranges):
        if out and r.start <= out[-1].end + gap:
            if r.end > out[-1].end:
                out[-1] = ByteRange(out[-1].start, r.end)
        else:
            out.append(r)
    return out
