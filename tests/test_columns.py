"""Column and row reductions of (N, C) arrays: the values numpy's own reductions give."""

from __future__ import annotations

import numpy as np
import pytest

from tsog_stream.columns import across, down


def _hostile(dtype: type[np.floating]) -> np.ndarray:
    """Rows with NaN, infinities, equal values and huge magnitudes."""
    values = np.random.default_rng(6).normal(size=(5000, 3)).astype(dtype)
    values[::7, 0] = np.nan
    values[::11, 1] = np.inf
    values[::13, 2] = -np.inf
    values[::17] = 2.5
    values[::19, 1] = np.finfo(dtype).max
    return values


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_down_and_across_equal_numpy_s_reductions(dtype: type[np.floating]) -> None:
    values = _hostile(dtype)
    finite = np.nan_to_num(values, nan=0.0)
    for pick, reduce in ((np.min, np.minimum), (np.max, np.maximum)):
        for array in (values, finite):
            got = down(pick, array)
            assert got.dtype == array.dtype and got.shape == (3,)
            assert np.array_equal(got, pick(array, axis=0), equal_nan=True)
            assert np.array_equal(across(reduce, array), pick(array, axis=1), equal_nan=True)
    empty = np.zeros((0, 3), dtype)
    assert np.array_equal(down(np.min, empty, initial=np.inf), np.full(3, np.inf))
    with pytest.raises(ValueError):
        down(np.max, empty)  # as numpy: no identity for an empty maximum
