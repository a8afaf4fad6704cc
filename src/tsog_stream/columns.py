"""Reductions of (N, C) arrays column by column or pairwise (numpy reduces a short axis far
slower: docs/design/quantizers.md), and rows a block at a time."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from typing import Any, Final

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[Any]

BLOCK_ROWS: Final = 1 << 16
"""Rows worked on at a time by row-wise work done in blocks (bounds its temporaries)."""


def down(pick: Any, values: Array, **options: Any) -> Array:
    """``pick`` (np.min, np.max) of each column of (N, C) ``values``: the values and dtype of
    ``pick(values, axis=0, **options)`` (NaN included; ``initial`` for an empty array)."""
    columns = [pick(values[:, c], **options) for c in range(values.shape[1])]
    return np.asarray(columns, dtype=values.dtype).reshape(values.shape[1])


def across(pick: np.ufunc, values: Array) -> Array:
    """``pick`` (np.minimum, np.maximum) over the columns of (N, C) ``values``, row by row:
    the same values as ``.min(axis=1)``, NaN included, in less time."""
    return np.asarray(functools.reduce(pick, values.T))


def row_blocks(count: int) -> Iterator[slice]:
    """Slices of ``count`` rows, BLOCK_ROWS at a time."""
    for start in range(0, count, BLOCK_ROWS):
        yield slice(start, min(count, start + BLOCK_ROWS))
