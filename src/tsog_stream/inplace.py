"""Rows of an array put in a new order, or some of them gathered to its front, in its own
memory a block at a time: the SH palette's kernels reorder their own working arrays this way,
where ``a[...] = np.take(a, order, axis=0)`` would hold a whole copy beside them."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from .columns import rows_per_block


def permute_rows(
    array: npt.NDArray[Any], order: npt.NDArray[np.intp], *, block_bytes: int | None = None
) -> None:
    """Put ``array``'s rows in ``order`` (a permutation of its rows: row i becomes the row that
    was at ``order[i]``), in place; ``block_bytes``: rows moved per step (BLOCK_BYTES).

    Positions are filled a block at a time: the block's rows are gathered, the rows they
    displace (not yet placed, wanted later) move into the slots the gathered rows left behind
    outside the block, then the block is written. Every row moves at most twice; the extra
    memory is two blocks of rows and two int arrays of one entry per row (the position of
    each row and the row at each position), taken only when there is more than one block.
    """
    count = len(array)
    step = _rows_per_step(array, block_bytes)
    if step >= count:
        array[...] = np.take(array, order, axis=0)
        return
    where = np.arange(count)  # where[r]: the position now holding the row first at r
    held = np.arange(count)  # held[p]: which first row position p now holds
    for start in range(0, count, step):
        stop = min(count, start + step)
        wanted = order[start:stop]
        sources = where[wanted]  # all at or after start: earlier positions are final
        block = np.take(array, sources, axis=0)
        inside = sources[sources < stop] - start
        staying = np.zeros(stop - start, np.bool_)
        staying[inside] = True
        evicted = start + np.flatnonzero(~staying)  # positions whose rows are wanted later
        freed = sources[sources >= stop]  # as many slots, left by the gathered rows
        array[freed] = np.take(array, evicted, axis=0)
        moved = held[evicted]
        held[freed] = moved
        where[moved] = freed
        array[start:stop] = block
        held[start:stop] = wanted
        where[wanted] = np.arange(start, stop)


def compact_rows(
    array: npt.NDArray[Any], kept: npt.NDArray[np.intp], *, block_bytes: int | None = None
) -> npt.NDArray[Any]:
    """``array[kept]`` (``kept`` ascending) moved to the front of ``array`` in place, a block
    at a time, returned as a view of it: no row moves backwards, so a row is only written
    over once every block that reads it is done."""
    step = _rows_per_step(array, block_bytes)
    for start in range(0, len(kept), step):
        block = kept[start : start + step]
        array[start : start + len(block)] = np.take(array, block, axis=0)
    return array[: len(kept)]


def _rows_per_step(array: npt.NDArray[Any], block_bytes: int | None) -> int:
    """Rows of ``array`` a block of ``block_bytes`` (default: ``columns.rows_per_block``)
    holds, at least one: the most this holds beside the array, twice (the rows a block takes
    and the rows it evicts)."""
    row_bytes = max(1, array.nbytes // max(1, len(array)))
    if block_bytes is None:
        return rows_per_block(row_bytes)
    return max(1, block_bytes // row_bytes)


__all__ = ["compact_rows", "permute_rows"]
