"""Plain 3DGS PLY files: bytes <-> :class:`~tsog_stream.model.Gaussians`.

:func:`parse_ply` maps the standard 3DGS ``vertex`` layout (any property order, any numeric
type, ASCII or binary of either byte order; PlayCanvas compressed PLY too) to float32 Gaussians;
:func:`read_ply` reads a binary file a block of rows at a time, never whole; :func:`ply_bytes`
and :func:`write_ply` (atomic) write the layout every 3DGS tool reads. Bytes past the declared
rows are a note (the header is the contract), fewer are a PlyError; non-finite values are kept
and noted, absurd ones refused or clamped (:mod:`~tsog_stream.io.ply_values`); normals are
ignored and other properties kept as :attr:`PlyContents.extra`."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import BinaryIO, Final

import numpy as np
import numpy.typing as npt

from ..columns import rows_per_block
from ..constants import GENERATOR
from ..errors import InputError, PlyError
from ..model import F32, Gaussians
from .compressed_ply import is_compressed_ply, parse_compressed_ply
from .files import Readable, atomic_write_bytes, open_regular, read_bytes, read_from
from .ply_columns import (
    F_REST_COUNTS,
    PlyContents,
    extras_note,
    gather_column_groups,
    gather_rows,
    nonfinite_notes,
    sh_column_order,
    unmapped_columns,
)
from .ply_header import (
    MAGICS,
    MAX_HEADER_BYTES,
    PlyFormat,
    PlyHeader,
    element_dtype,
    locate_binary,
    parse_header,
    read_elements,
)
from .ply_values import clamp_absurd

POSITION: Final = ("x", "y", "z")
NORMALS: Final = ("nx", "ny", "nz")
SCALES: Final = ("scale_0", "scale_1", "scale_2")
ROTATION: Final = ("rot_0", "rot_1", "rot_2", "rot_3")
OPACITY: Final = "opacity"
F_DC: Final = ("f_dc_0", "f_dc_1", "f_dc_2")
REQUIRED: Final = (*POSITION, *SCALES, *ROTATION, OPACITY, *F_DC)
"""Required vertex properties, in the column order of the gathered matrix."""

_F_REST = re.compile(r"f_rest_(0|[1-9][0-9]*)")
_PROPERTY_NAME = re.compile(r"[!-~]+")
"""A property name a PLY header can hold: printable ASCII, no whitespace."""

PathLike = str | os.PathLike[str]


def sniff_ply(data: bytes | memoryview) -> bool:
    """True when ``data`` starts with the PLY magic line (``ply\\n`` or ``ply\\r\\n``)."""
    return bytes(data[:5]).startswith(MAGICS)


def parse_ply(data: bytes | memoryview, *, name: str = "<bytes>") -> PlyContents:
    """Decode a 3DGS PLY (plain or PlayCanvas compressed) held in memory."""
    header = parse_header(data, name=name)
    if is_compressed_ply(header):
        return parse_compressed_ply(data, name=name)
    vertex = header.element("vertex")
    if vertex is None:
        raise PlyError("the header declares no 'vertex' element", where=name)
    layout = _VertexLayout.of(vertex.names, name)
    body = read_elements(data, header, ("vertex",), name=name)
    records = body.records["vertex"]
    columns = gather_column_groups(records, layout.groups)  # each its own array
    notes = body.notes
    notes.extend(clamp_absurd(columns, layout.names, header.format, where=name))
    notes.extend(nonfinite_notes(columns, layout.names))
    extra = unmapped_columns(records, layout.mapped, notes)
    return PlyContents(layout.gaussians(columns), extra, notes, header)


@dataclass(frozen=True)
class _VertexLayout:
    """Which vertex properties make which Gaussian attribute: the groups of columns gathered
    (POSITION, SCALES, ROTATION, OPACITY, F_DC, then f_rest in :func:`sh_column_order`)."""

    k: int
    groups: tuple[Sequence[str], ...]

    @classmethod
    def of(cls, names: Sequence[str], where: str) -> _VertexLayout:
        """The layout of a vertex element's properties (a PlyError if one is missing)."""
        k = _sh_coefficients(names, where)
        return cls(k, (POSITION, SCALES, ROTATION, (OPACITY,), F_DC, sh_column_order(k)))

    @property
    def names(self) -> tuple[str, ...]:
        """Every gathered column, in order."""
        return tuple(n for group in self.groups for n in group)

    @property
    def mapped(self) -> set[str]:
        """Properties that are not extras: the gathered ones and the normals."""
        return {*self.names, *NORMALS}

    def gaussians(self, columns: Sequence[F32]) -> Gaussians:
        """Gaussians of the gathered columns, taken as they are (:func:`_gaussians_of`)."""
        return _gaussians_of(columns, self.k)


def read_ply(path: Readable) -> PlyContents:
    """Read and decode a PLY file; I/O failures raise :class:`SourceError`. A plain binary
    one is read a block of rows at a time into its arrays (its bytes whole beside them took a
    500k SH3 frame's read to 2.06x its arrays); any other kind is read whole and parsed."""
    name = str(path)
    with open_regular(path) as file:
        header = parse_header(read_from(file, MAX_HEADER_BYTES, name), name=name)
        if _by_blocks(header) and file.seekable():
            return _read_by_blocks(file, header, name)
    return parse_ply(read_bytes(path), name=name)


def _by_blocks(header: PlyHeader) -> bool:
    """Whether a file of this header can be read a block of rows at a time: binary, every
    element of fixed size, a vertex element, not compressed."""
    return (
        header.format is not PlyFormat.ASCII
        and all(element.is_fixed for element in header.elements)
        and header.element("vertex") is not None
        and not is_compressed_ply(header)
    )


def _read_by_blocks(file: BinaryIO, header: PlyHeader, name: str) -> PlyContents:
    """:func:`parse_ply` of a file :func:`_by_blocks` takes, its vertex rows read and
    gathered a block (``columns.rows_per_block``) at a time: the same Gaussians, extras and
    notes, the file's bytes never held whole."""
    vertex = header.element("vertex")
    assert vertex is not None
    layout = _VertexLayout.of(vertex.names, name)
    located = locate_binary(header, list(header.elements), ("vertex",), _size(file), name=name)
    dtype = element_dtype(vertex, header.format)  # counts checked above: now allocate
    extra = {
        n: np.empty(vertex.count, dtype[n].newbyteorder("="))
        for n in vertex.names
        if n not in layout.mapped
    }
    columns = [np.empty((vertex.count, len(names)), np.float32) for names in layout.groups]
    step = rows_per_block(dtype.itemsize)
    file.seek(located.offsets["vertex"][1])
    for start in range(0, vertex.count, step):
        rows = min(step, vertex.count - start)
        block = np.frombuffer(_read_exactly(file, rows * dtype.itemsize, name), dtype)
        gather_rows(block, layout.groups, columns, start)
        for n, out in extra.items():
            out[start : start + rows] = block[n]
    notes = located.notes
    notes.extend(clamp_absurd(columns, layout.names, header.format, where=name))
    notes.extend(nonfinite_notes(columns, layout.names))
    notes.extend(extras_note(list(extra)))
    return PlyContents(layout.gaussians(columns), extra, notes, header)


def _size(file: BinaryIO) -> int:
    """The bytes of a seekable file."""
    return file.seek(0, os.SEEK_END)


def _read_exactly(file: BinaryIO, size: int, name: str) -> bytes:
    """The next ``size`` bytes of ``file``; a PlyError where it ends first (it was cut short
    while being read)."""
    piece = read_from(file, size, name)
    while len(piece) < size:
        more = read_from(file, size - len(piece), name)
        if not more:
            raise PlyError(f"the file ended {size - len(piece)} bytes early", where=name)
        piece += more
    return piece


def _sh_coefficients(names: Sequence[str], where: str) -> int:
    """Check the required properties; return K, the SH coefficients per colour channel."""
    missing = [n for n in REQUIRED if n not in names]
    if missing:
        raise PlyError(f"missing required vertex property {', '.join(missing)}", where=where)
    indices = sorted(int(m.group(1)) for n in names if (m := _F_REST.fullmatch(n)))
    if len(indices) not in F_REST_COUNTS:
        raise PlyError(
            f"expected 0, 9, 24 or 45 f_rest properties, found {len(indices)}", where=where
        )
    for expected, found in zip(range(len(indices)), indices, strict=True):
        if expected != found:
            raise PlyError(f"f_rest properties skip f_rest_{expected}", where=where)
    return len(indices) // 3


def _gaussians_of(columns: Sequence[F32], k: int) -> Gaussians:
    """Gaussians of the gathered columns of each attribute (POSITION, SCALES, ROTATION,
    OPACITY, F_DC, then f_rest in :func:`sh_column_order`), taken as they are: one matrix of
    every column, cut into the attributes' copies, held a 500k SH3 file's Gaussians twice
    beside its bytes."""
    means, scales, quats, opacity, sh0, rest = columns
    return Gaussians(means, scales, quats, opacity.reshape(-1), sh0, rest.reshape(len(rest), k, 3))


def standard_names(k: int) -> list[str]:
    """Property names of the standard 3DGS vertex layout with ``k`` SH coefficients per channel."""
    rest = [f"f_rest_{i}" for i in range(3 * k)]
    return [*POSITION, *NORMALS, *F_DC, *rest, OPACITY, *SCALES, *ROTATION]


def ply_bytes(gaussians: Gaussians, extra: Mapping[str, npt.ArrayLike] | None = None) -> bytes:
    """Encode as a binary little-endian 3DGS PLY, extra float columns appended to each row."""
    header, matrix = _encode(gaussians, extra)
    return header + matrix.tobytes()


def write_ply(
    path: PathLike, gaussians: Gaussians, extra: Mapping[str, npt.ArrayLike] | None = None
) -> None:
    """Write :func:`ply_bytes` output to ``path`` atomically (nothing half-written on failure)."""
    header, matrix = _encode(gaussians, extra)
    atomic_write_bytes(path, (header, matrix.reshape(-1).view(np.uint8).data))  # N may be 0


def _encode(
    gaussians: Gaussians, extra: Mapping[str, npt.ArrayLike] | None
) -> tuple[bytes, npt.NDArray[np.float32]]:
    """The header bytes and the (N, columns) little-endian float32 body of a 3DGS PLY."""
    n, k = len(gaussians), gaussians.shN.shape[1]
    names = standard_names(k)
    columns = _extra_columns(n, extra, set(names))
    matrix = np.zeros((n, len(names) + len(columns)), dtype="<f4")
    matrix[:, 0:3] = gaussians.means  # columns 3:6 are the zero normals
    matrix[:, 6:9] = gaussians.sh0
    matrix[:, 9 : 9 + 3 * k] = gaussians.shN.transpose(0, 2, 1).reshape(n, 3 * k)
    tail = 9 + 3 * k
    matrix[:, tail] = gaussians.opacities
    matrix[:, tail + 1 : tail + 4] = gaussians.scales
    matrix[:, tail + 4 : tail + 8] = gaussians.quats
    for j, values in enumerate(columns.values(), start=tail + 8):
        matrix[:, j] = values
    lines = ["ply", "format binary_little_endian 1.0", f"comment Generated by {GENERATOR}"]
    lines.append(f"element vertex {n}")
    lines.extend(f"property float {p}" for p in (*names, *columns))
    lines.append("end_header\n")
    return "\n".join(lines).encode("ascii"), matrix


def _extra_columns(
    n: int, extra: Mapping[str, npt.ArrayLike] | None, reserved: set[str]
) -> dict[str, F32]:
    """Validate the extra columns: PLY-safe unique names and shape (N,)."""
    columns: dict[str, F32] = {}
    for key, value in (extra or {}).items():
        if not isinstance(key, str) or not _PROPERTY_NAME.fullmatch(key) or key in reserved:
            raise InputError(f"{key!r} cannot name an extra property", where="extra")
        try:
            array = np.asarray(value, dtype=np.float32)
        except (TypeError, ValueError) as exc:
            raise InputError(f"not convertible to float32: {exc}", where=f"extra.{key}") from None
        if array.shape != (n,):
            raise InputError(f"expected shape ({n},), got {array.shape}", where=f"extra.{key}")
        columns[key] = array
    return columns


__all__ = [
    "PlyContents",
    "parse_ply",
    "ply_bytes",
    "read_ply",
    "sniff_ply",
    "standard_names",
    "write_ply",
]
