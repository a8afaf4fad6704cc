"""Parsing a ``Range`` request header against a representation length (RFC 9110 §14).

Sans-I/O: a header value and a length in, a verdict out, never an exception:
:class:`Serve` (206: the ranges clipped, sorted, overlapping or adjacent ones coalesced, as
§14.2 allows), :class:`Ignore` (200, the whole representation: no header, another unit, invalid
syntax, which §14.2 says a server MUST ignore, or more than ``max_ranges`` ranges, our cap
against amplification), :class:`Unsatisfiable` (416: valid, but no range overlaps, e.g.
``bytes=LEN-`` or ``bytes=-0``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from ..container.ranges import ByteRange, coalesce

MAX_RANGES: Final = 32
"""More ranges than this in one header and the header is ignored (whole file, 200)."""

_SPEC = re.compile(r"([0-9]*)-([0-9]*)", re.ASCII)
_UNIT = re.compile(r"[ \t]*bytes[ \t]*=", re.ASCII | re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class Serve:
    """Send these ranges (non-empty, sorted, disjoint, non-adjacent, inside the length)."""

    ranges: tuple[ByteRange, ...]


@dataclass(frozen=True, slots=True)
class Ignore:
    """Ignore the header: send the whole representation with 200."""

    reason: str


@dataclass(frozen=True, slots=True)
class Unsatisfiable:
    """No requested range overlaps the representation: 416."""


RangeVerdict = Serve | Ignore | Unsatisfiable


def _num(digits: str, length: int) -> int:
    """A decimal position, exact up to ``length + 1``: every larger one clips the same way, and
    Python refuses to convert huge digit strings, so they are never converted."""
    digits = digits.lstrip("0") or "0"
    if len(digits) > len(str(length)) + 1:
        return length + 1
    return min(int(digits), length + 1)


def _order(digits: str) -> tuple[int, str]:
    """A sort key giving decimal strings of any length their numeric order."""
    digits = digits.lstrip("0") or "0"
    return len(digits), digits


def _one(spec: str, length: int) -> ByteRange | bool | None:
    """One range-spec: its clipped range, None when unsatisfiable, False when invalid."""
    m = _SPEC.fullmatch(spec)
    if m is None:
        return False
    first, last = m.group(1), m.group(2)
    if not first:
        if not last:
            return False
        n = _num(last, length)
        if n == 0 or length == 0:
            return None
        return ByteRange(max(0, length - n), length)
    if last and _order(last) < _order(first):
        return False
    start = _num(first, length)
    if start >= length:
        return None
    end = length if not last else min(_num(last, length) + 1, length)
    return ByteRange(start, end)


def parse_range(value: str | None, length: int, *, max_ranges: int = MAX_RANGES) -> RangeVerdict:
    """The verdict on a ``Range`` header value for a representation of ``length`` bytes."""
    if value is None:
        return Ignore("no Range header")
    unit = _UNIT.match(value)
    if unit is None:
        return Ignore("not a bytes range")
    specs = [s.strip(" \t") for s in value[unit.end() :].split(",")]
    specs = [s for s in specs if s]  # RFC 9110 §5.6.1: empty list elements do not count
    if not specs:
        return Ignore("no range in the header")
    if len(specs) > max_ranges:
        return Ignore(f"more than {max_ranges} ranges")
    wanted: list[ByteRange] = []
    for spec in specs:
        r = _one(spec, length)
        if r is False:
            return Ignore(f"invalid range {spec[:40]!r}")
        if isinstance(r, ByteRange):
            wanted.append(r)
    if not wanted:
        return Unsatisfiable()
    return Serve(tuple(coalesce(wanted)))


def content_range(span: ByteRange, length: int) -> str:
    """The ``Content-Range`` value of a served range (inclusive end)."""
    return f"bytes {span.start}-{span.end - 1}/{length}"


def unsatisfied_range(length: int) -> str:
    """The ``Content-Range`` value of a 416 response."""
    return f"bytes */{length}"
