"""Reductions of (N, C) arrays column by column or pairwise (numpy reduces a short axis far
slower: docs/design/quantizers.md), and rows a block at a time."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from .constants import BLOCK_BYTES

Array = npt.NDArray[Any]


def down(pick: Any, values: Array, **options: Any) -> Array:
    """``pick`` (np.min, np.max) of each column of (N, C) ``values``: the values and dtype of
    ``pick(values, axis=0, **options)`` (NaN included; ``initial`` for an empty array)."""
    columns = [pick(values[:, c], **options) for c in range(values.shape[1])]
    return np.asarray(columns, dtype=values.dtype).reshape(values.shape[1])


def across(pick: np.ufunc, values: Array) -> Array:
    """``pick`` (np.minimum, np.maximum) over the columns of (N, C) ``values``, row by row:
    the same values as ``.min(axis=1)``, NaN included, in less time."""
    return np.asarray(functools.reduce(pick, values.T))


def rows_per_block(row_bytes: int) -> int:
    """Rows whose temporaries of ``row_bytes`` each fill one block (BLOCK_BYTES), at least 1."""
    return max(1, BLOCK_BYTES // max(1, row_bytes))


def row_blocks(count: int, row_bytes: int) -> Iterator[slice]:
    """Slices of ``count`` rows, :func:`rows_per_block` at a time."""
    step = rows_per_block(row_bytes)
    for start in range(0, count, step):
        yield slice(start, min(count, start + step))
