"""Rows put in a new order in their own memory: the values ``np.take`` gives, without a
copy of the array beside it."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from tsog_stream.inplace import compact_rows, permute_rows


@pytest.mark.parametrize("block_rows", [1, 3, 64, 10_000])
@pytest.mark.parametrize("shape", [(1,), (2, 3), (257,), (1000, 45), (999, 2, 3)])
def test_rows_end_where_take_puts_them(shape: tuple[int, ...], block_rows: int) -> None:
    rng = np.random.default_rng(len(shape) * 1000 + block_rows)
    array = rng.normal(size=shape).astype(np.float32)
    row_bytes = array.nbytes // len(array)
    for order in (rng.permutation(len(array)), np.arange(len(array)), np.arange(len(array))[::-1]):
        expected = np.take(array, order, axis=0)
        permute_rows(array, order, block_bytes=block_rows * row_bytes)
        np.testing.assert_array_equal(array, expected)


@pytest.mark.parametrize("block_rows", [1, 4, 10_000])
def test_rows_kept_are_gathered_to_the_front(block_rows: int) -> None:
    rng = np.random.default_rng(block_rows)
    array = rng.normal(size=(500, 3, 2)).astype(np.float32)
    for kept in (np.flatnonzero(rng.random(500) < 0.4), np.arange(500), np.array([499])):
        expected = np.take(array, kept, axis=0)
        front = compact_rows(array, kept, block_bytes=block_rows * 24)
        assert np.shares_memory(front, array) and len(front) == len(kept)
        np.testing.assert_array_equal(front, expected)


def test_integer_rows_and_a_sort_by_labels() -> None:
    rng = np.random.default_rng(5)
    labels = rng.integers(0, 50, 5000)
    array = np.stack([labels, np.arange(5000)], axis=1)
    permute_rows(array, np.argsort(labels, kind="stable"), block_bytes=16 * 100)
    assert np.all(np.diff(array[:, 0]) >= 0)
    assert sorted(array[:, 1].tolist()) == list(range(5000))


def test_it_holds_blocks_not_a_copy() -> None:
    """30 MiB of rows in 1 MiB blocks: the most allocated beside them is two blocks and the
    two position arrays (an entry per row), nowhere near the copy ``np.take`` makes."""
    rows = 175_000
    array = np.random.default_rng(1).normal(size=(rows, 45)).astype(np.float32)
    order = np.random.default_rng(2).permutation(rows)
    expected = np.take(array, order, axis=0)
    tracemalloc.start()
    try:
        permute_rows(array, order, block_bytes=1 << 20)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(array, expected)
    positions = 2 * rows * np.dtype(np.intp).itemsize
    assert peak < 2 * (1 << 20) + positions + (2 << 20)
    assert peak < array.nbytes / 4
