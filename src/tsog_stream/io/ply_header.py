"""PLY container: the text header and the element bodies it describes (sans-I/O, bytes only).

:func:`parse_header` reads ``format`` (ascii, binary little/big endian 1.0), ``element``,
``property`` (every scalar type and its sized alias, and ``list``), ``comment`` and
``obj_info``; :func:`read_elements` locates the body's elements and decodes the wanted ones with
one vectorised call each. Every declared count is checked against the bytes present before
anything is allocated. Elements from the first one with a list property on are skipped (noted)."""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from ..errors import PlyError, UnsupportedError

MAX_HEADER_BYTES: Final = 64 * 1024
"""A header that does not end within this many bytes is rejected."""
MAGICS: Final = (b"ply\n", b"ply\r\n")
MAX_COUNT_DIGITS: Final = 18
"""Longest element count accepted (10^18 rows is far beyond any file)."""

PLY_TYPES: Final[Mapping[str, str]] = {
    name: code
    for code, names in {
        "i1": "char int8",
        "u1": "uchar uint8",
        "i2": "short int16",
        "u2": "ushort uint16",
        "i4": "int int32",
        "u4": "uint uint32",
        "f4": "float float32",
        "f8": "double float64",
    }.items()
    for name in names.split()
}
"""PLY scalar type names (classic and sized aliases) -> numpy type codes without byte order."""

_END_HEADER = re.compile(rb"\nend_header[ \t]*\r?\n")

Records = npt.NDArray[np.void]


class PlyFormat(StrEnum):
    """The ``format`` line's encoding; values are the header spellings."""

    ASCII = "ascii"
    BINARY_LE = "binary_little_endian"
    BINARY_BE = "binary_big_endian"

    @property
    def byte_order(self) -> str:
        """The numpy byte-order prefix of stored values (native for ASCII, parsed from text)."""
        return {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}[self.value]


@dataclass(frozen=True, slots=True)
class PlyProperty:
    """One property; ``type`` is a numpy code ("f4", "u1"...), ``count_type`` is set for lists."""

    name: str
    type: str
    count_type: str | None = None

    @property
    def is_list(self) -> bool:
        """True for ``property list <count type> <item type> <name>``."""
        return self.count_type is not None


@dataclass(frozen=True, slots=True)
class PlyElement:
    """One ``element`` line: its name, declared row count and properties in stored order."""

    name: str
    count: int
    properties: tuple[PlyProperty, ...]

    @property
    def is_fixed(self) -> bool:
        """True when every row has the same size (no list property)."""
        return not any(p.is_list for p in self.properties)

    @property
    def names(self) -> tuple[str, ...]:
        """Property names in stored order."""
        return tuple(p.name for p in self.properties)


@dataclass(frozen=True, slots=True)
class PlyHeader:
    """A parsed header; ``size`` is its length in bytes, ``end_header`` line included."""

    format: PlyFormat
    elements: tuple[PlyElement, ...]
    size: int
    comments: tuple[str, ...] = ()
    obj_info: tuple[str, ...] = ()

    def element(self, name: str) -> PlyElement | None:
        """The element called ``name``, if declared."""
        return next((e for e in self.elements if e.name == name), None)


@dataclass(frozen=True, slots=True)
class PlyBody:
    """Decoded elements as structured arrays (by element name) and notes on what was skipped.

    Binary records are read-only views of the input bytes; copy what must outlive them.
    """

    records: dict[str, Records]
    notes: list[str] = field(default_factory=list)


def parse_header(data: bytes | memoryview, *, name: str = "<bytes>") -> PlyHeader:
    """Parse the header at the start of ``data`` (only the first 64 KiB are looked at)."""
    head = bytes(data[:MAX_HEADER_BYTES])
    if not head.startswith(MAGICS):
        raise PlyError(f"expected the magic line 'ply', found {head[:16]!r}", where=name)
    match = _END_HEADER.search(head)
    if match is None:
        if len(head) < MAX_HEADER_BYTES:
            raise PlyError(f"no 'end_header' line in the {len(head)} bytes of the file", where=name)
        raise PlyError(
            f"no 'end_header' line within the first {MAX_HEADER_BYTES} bytes", where=name
        )
    try:
        text = head[: match.end()].decode("ascii")
    except UnicodeDecodeError as exc:
        raise PlyError(f"non-ASCII byte in the header at offset {exc.start}", where=name) from None
    return _parse_lines(text.splitlines()[1:-1], match.end(), name)


def _parse_lines(lines: list[str], size: int, name: str) -> PlyHeader:
    """Build a header from the lines between the magic and ``end_header``."""
    fmt: PlyFormat | None = None
    elements: list[PlyElement] = []
    comments: list[str] = []
    obj_info: list[str] = []
    for lineno, line in enumerate(lines, start=2):
        where = f"{name}: header line {lineno}"
        words = line.split()
        if not words:
            continue
        key, rest = words[0], line.strip()[len(words[0]) :].strip()
        if key == "comment":
            comments.append(rest)
        elif key == "obj_info":
            obj_info.append(rest)
        elif key == "format":
            if fmt is not None or elements:
                raise PlyError("'format' must appear once, before any element", where=where)
            fmt = _parse_format(words, where)
        elif key == "element":
            elements.append(_parse_element(words, elements, where))
        elif key == "property":
            if not elements:
                raise PlyError("'property' before any 'element'", where=where)
            elements[-1] = _add_property(elements[-1], words, where)
        else:
            raise PlyError(f"unknown header keyword {key!r}", where=where)
    if fmt is None:
        raise PlyError("header has no 'format' line", where=name)
    return PlyHeader(fmt, tuple(elements), size, tuple(comments), tuple(obj_info))


def _parse_format(words: list[str], where: str) -> PlyFormat:
    """``format <encoding> 1.0``: only version 1.0 exists."""
    if len(words) != 3:
        raise PlyError(f"expected 'format <encoding> 1.0', found {' '.join(words)!r}", where=where)
    try:
        fmt = PlyFormat(words[1])
    except ValueError:
        raise PlyError(f"unknown format {words[1]!r}", where=where) from None
    if words[2] not in ("1.0", "1"):
        raise UnsupportedError(f"PLY version {words[2]!r} (only 1.0 is defined)", where=where)
    return fmt


def _parse_element(words: list[str], seen: list[PlyElement], where: str) -> PlyElement:
    """``element <name> <count>`` with a unique name and a non-negative integer count."""
    if len(words) != 3 or not words[2].isdigit():
        raise PlyError(f"expected 'element <name> <count>', found {' '.join(words)!r}", where=where)
    if any(e.name == words[1] for e in seen):
        raise PlyError(f"element {words[1]!r} declared twice", where=where)
    digits = words[2].lstrip("0") or "0"
    if len(digits) > MAX_COUNT_DIGITS:  # int() refuses over 4300 digits; no file holds 10^18
        raise PlyError(f"element {words[1]!r} declares {len(digits)}-digit count", where=where)
    return PlyElement(words[1], int(digits), ())


def _add_property(element: PlyElement, words: list[str], where: str) -> PlyElement:
    """``property <type> <name>`` or ``property list <count type> <item type> <name>``."""
    is_list = len(words) > 1 and words[1] == "list"
    if len(words) != (5 if is_list else 3):
        raise PlyError(f"malformed property line {' '.join(words)!r}", where=where)
    prop_name = words[-1]
    if prop_name in element.names:
        raise PlyError(f"property {prop_name!r} declared twice in {element.name!r}", where=where)
    types = [_ply_type(w, where) for w in words[1 + is_list : -1]]
    prop = PlyProperty(prop_name, types[-1], types[0] if is_list else None)
    return PlyElement(element.name, element.count, (*element.properties, prop))


def _ply_type(word: str, where: str) -> str:
    """The numpy code of a PLY type name."""
    try:
        return PLY_TYPES[word]
    except KeyError:
        raise PlyError(f"unknown property type {word!r}", where=where) from None


def element_dtype(element: PlyElement, fmt: PlyFormat) -> np.dtype[np.void]:
    """The packed structured dtype of one row of ``element`` (scalar properties only)."""
    lists = [p.name for p in element.properties if p.is_list]
    if lists:
        raise UnsupportedError(
            f"element {element.name!r} has list properties ({', '.join(lists)}); "
            "only elements of scalar properties can be decoded"
        )
    order = fmt.byte_order
    return np.dtype([(p.name, order + p.type) for p in element.properties])


def read_elements(
    data: bytes | memoryview, header: PlyHeader, wanted: Collection[str], *, name: str = "<bytes>"
) -> PlyBody:
    """Locate every element after the header and decode those named in ``wanted``."""
    fixed, skipped = _split_at_first_list(header)
    for element in skipped:
        if element.name in wanted:
            raise UnsupportedError(
                f"element {element.name!r} cannot be located: it follows list element "
                f"{skipped[0].name!r} (list properties are not supported)",
                where=name,
            )
    if header.format is PlyFormat.ASCII:
        body = _read_ascii(data, header, fixed, wanted, name)
    else:
        body = _read_binary(data, header, fixed, wanted, name)
    if skipped:
        names = ", ".join(repr(e.name) for e in skipped)
        body.notes.append(f"skipped element(s) {names}: list properties are not supported")
    return body


def _split_at_first_list(header: PlyHeader) -> tuple[list[PlyElement], list[PlyElement]]:
    """Elements before the first one with a list property, and that one with all after it."""
    for i, element in enumerate(header.elements):
        if not element.is_fixed:
            return list(header.elements[:i]), list(header.elements[i:])
    return list(header.elements), []


def _read_binary(
    data: bytes | memoryview,
    header: PlyHeader,
    fixed: list[PlyElement],
    wanted: Collection[str],
    name: str,
) -> PlyBody:
    """Walk the fixed-size elements by byte offset; decoded ones are zero-copy views."""
    located = locate_binary(header, fixed, wanted, len(data), name=name)
    body = PlyBody({}, located.notes)
    for element, offset in located.offsets.values():
        dtype = element_dtype(element, header.format)
        body.records[element.name] = np.frombuffer(data, dtype, element.count, offset)
    return body


@dataclass(frozen=True, slots=True)
class Located:
    """Each wanted element (by name: the last of that name) and the byte offset where its rows
    start; notes on the rest."""

    offsets: dict[str, tuple[PlyElement, int]]
    notes: list[str]


def locate_binary(
    header: PlyHeader,
    fixed: list[PlyElement],
    wanted: Collection[str],
    total: int,
    *,
    name: str = "<bytes>",
) -> Located:
    """The byte offset of each wanted element among the fixed-size ones of a binary file of
    ``total`` bytes: a PlyError where the file is shorter than they declare, a note for each
    skipped element and for trailing bytes."""
    located = Located({}, [])
    offset = header.size
    for element in fixed:
        row = element_dtype(element, header.format).itemsize
        size = element.count * row
        if offset + size > total:
            raise PlyError(
                f"the header declares {element.count} {element.name!r} rows of {row} "
                f"bytes: expected {size} bytes at offset {offset}, found {max(total - offset, 0)}",
                where=name,
            )
        if element.name in wanted:
            located.offsets[element.name] = (element, offset)
        else:
            located.notes.append(f"skipped element {element.name!r} ({element.count} rows)")
        offset += size
    if offset < total and len(fixed) == len(header.elements) and fixed:
        last = fixed[-1]
        located.notes.append(
            f"ignored {total - offset} trailing bytes after the declared {last.count} "
            f"{last.name!r} rows"
        )
    return located


def _read_ascii(
    data: bytes | memoryview,
    header: PlyHeader,
    fixed: list[PlyElement],
    wanted: Collection[str],
    name: str,
) -> PlyBody:
    """Parse the whitespace-separated body in one vectorised call, then slice it per element."""
    needed = sum(e.count * len(e.properties) for e in fixed)
    text = bytes(data[header.size :])
    if len(text) < 2 * needed - 1:
        rows = ", ".join(f"{e.count} {e.name!r} rows" for e in fixed)
        raise PlyError(
            f"the header declares {rows} ({needed} values): expected at least "
            f"{2 * needed - 1} bytes of text, found {len(text)}",
            where=name,
        )
    tokens = text.split()
    if len(tokens) < needed:
        raise PlyError(f"expected {needed} values in the body, found {len(tokens)}", where=name)
    values = _parse_numbers(tokens[:needed], name)
    body, start = PlyBody({}), 0
    for element in fixed:
        width = len(element.properties)
        block = values[start : start + element.count * width].reshape(element.count, width)
        start += element.count * width
        if element.name in wanted:
            body.records[element.name] = _ascii_records(block, element, name)
        else:
            body.notes.append(f"skipped element {element.name!r} ({element.count} rows)")
    if len(tokens) > needed and len(fixed) == len(header.elements) and fixed:
        last = fixed[-1]
        body.notes.append(
            f"ignored {len(tokens) - needed} trailing values after the declared {last.count} "
            f"{last.name!r} rows"
        )
    return body


def _parse_numbers(tokens: list[bytes], name: str) -> npt.NDArray[np.float64]:
    """Convert ASCII tokens to float64 at once; on failure, name the first bad token."""
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for i, token in enumerate(tokens):
            try:
                float(token)
            except ValueError:
                msg = f"value {i} of the body is not a number: {token[:32]!r}"
                raise PlyError(msg, where=name) from None
        raise PlyError("the body holds a value that is not a number", where=name) from None


def _ascii_records(block: npt.NDArray[np.float64], element: PlyElement, name: str) -> Records:
    """Pack parsed columns into the element's structured dtype, checking integer columns."""
    records = np.empty(element.count, element_dtype(element, PlyFormat.ASCII))
    for j, prop in enumerate(element.properties):
        column = block[:, j]
        kind = np.dtype(prop.type)
        if kind.kind in "iu":
            info = np.iinfo(kind)
            ok = (column == np.trunc(column)) & (column >= info.min) & (column <= info.max)
            if not np.all(ok):
                bad = column[np.argmin(ok)]
                raise PlyError(
                    f"{element.name}.{prop.name}: {bad!r} is not a valid {kind.name}", where=name
                )
        with np.errstate(over="ignore"):  # 1e300 in a float column is inf, kept as read
            records[prop.name] = column
    return records
