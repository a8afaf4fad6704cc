"""The vertex columns every PLY reader shares (:mod:`~tsog_stream.io.ply`,
:mod:`~tsog_stream.io.compressed_ply`): properties gathered into float32 matrices a block of
rows at a time, the notes on what they hold, the unmapped ones kept as extras, and what a
reader returns (:class:`PlyContents`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from ..columns import rows_per_block
from ..model import F32, Gaussians
from .ply_header import PlyHeader, Records

F_REST_COUNTS: Final = (0, 9, 24, 45)
"""Allowed numbers of f_rest properties (SH degree 0, 1, 2, 3)."""


@dataclass(frozen=True, slots=True)
class PlyContents:
    """What a PLY file held: Gaussians, unmapped vertex properties, warnings and the header."""

    gaussians: Gaussians
    extra: dict[str, npt.NDArray[np.generic]]
    notes: list[str]
    header: PlyHeader


def sh_column_order(k: int) -> tuple[str, ...]:
    """f_rest names in (coefficient, channel) order: the file is channel-major, shN is not."""
    return tuple(f"f_rest_{c * k + i}" for i in range(k) for c in range(3))


def gather_columns(records: Records, names: Sequence[str]) -> F32:
    """Columns ``names`` as one (N, len(names)) float32 matrix."""
    return gather_column_groups(records, [names])[0]


def gather_column_groups(records: Records, groups: Sequence[Sequence[str]]) -> list[F32]:
    """Each group of columns as its own (N, len(group)) float32 matrix, in one pass over the
    rows, a block at a time when the fields share one type (each block copied once when the
    body is unaligned, then every group taken from it: a whole body's copy was as large as
    the file)."""
    outs = [np.empty((len(records), len(names)), np.float32) for names in groups]
    step = rows_per_block(records.dtype.itemsize)
    for start in range(0, len(records), step):
        gather_rows(records[start : start + step], groups, outs, start)
    return outs


def gather_rows(
    records: Records, groups: Sequence[Sequence[str]], outs: Sequence[F32], start: int
) -> None:
    """Each group of columns of a block of rows into ``outs`` from row ``start`` on (the
    block copied once if unaligned when the fields share one type, then every group taken
    from it; else column by column)."""
    stop = start + len(records)
    base = _uniform_base(records.dtype)
    if base is None:
        for out, names in zip(outs, groups, strict=True):
            for j, column in enumerate(names):
                out[start:stop, j] = records[column]
        return
    fields = records.dtype.names or ()
    position = {n: i for i, n in enumerate(fields)}
    block = np.require(records.view(base).reshape(len(records), len(fields)), requirements="A")
    for out, names in zip(outs, groups, strict=True):
        pick = [position[n] for n in names]
        if block.dtype == out.dtype:
            np.take(block, pick, axis=1, out=out[start:stop])
        else:
            out[start:stop] = np.take(block, pick, axis=1)


def _uniform_base(dtype: np.dtype[np.void]) -> np.dtype[np.generic] | None:
    """The field type when a record is a packed run of one scalar type (viewable as 2-D)."""
    if not dtype.names or dtype.fields is None:
        return None
    base: np.dtype[np.generic] = dtype.fields[dtype.names[0]][0]
    for i, field_name in enumerate(dtype.names):
        field_type, offset = dtype.fields[field_name][:2]
        if field_type != base or offset != i * base.itemsize:
            return None
    return base if dtype.itemsize == base.itemsize * len(dtype.names) else None


def nonfinite_notes(matrices: Sequence[F32], names: Sequence[str]) -> list[str]:
    """A note counting NaN/inf per column of the matrices side by side (``names`` in that
    order), or nothing when every value is finite."""
    counts = np.concatenate([_nonfinite_per_column(matrix) for matrix in matrices])
    where = [f"{n}: {int(c)}" for n, c in zip(names, counts, strict=True) if c]
    if not where:
        return []
    total = int(counts.sum())
    return [f"kept {total} non-finite values as read ({', '.join(where)})"]


def _nonfinite_per_column(matrix: F32) -> npt.NDArray[np.intp]:
    """NaN/inf in each column of ``matrix``; a sum first (cheap) when all are finite."""
    with np.errstate(invalid="ignore", over="ignore"):  # inf + -inf is NaN: that is the test
        if np.isfinite(matrix.sum(dtype=np.float64)):  # cheap test: no NaN/inf anywhere
            return np.zeros(matrix.shape[1], np.intp)
    return np.asarray(np.count_nonzero(~np.isfinite(matrix), axis=0), np.intp)


def unmapped_columns(
    records: Records, mapped: set[str], notes: list[str]
) -> dict[str, npt.NDArray[np.generic]]:
    """Native-order copies of the columns not in ``mapped`` (copies: they must not pin the
    input buffer), noted by name."""
    names = [n for n in records.dtype.names or () if n not in mapped]
    notes.extend(extras_note(names))
    return {n: np.array(records[n], dtype=records.dtype[n].newbyteorder("=")) for n in names}


def extras_note(names: Sequence[str]) -> list[str]:
    """The note naming the unknown properties kept as extras (none without them)."""
    return [f"unknown properties kept as extras: {', '.join(names)}"] if names else []
