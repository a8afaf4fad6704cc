"""Helpers shared by tests: quantisation bounds and aligned comparisons."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tsog_stream.codec.positions import log_transform
from tsog_stream.constants import U16_MAX


def means_log_step(mins: list[float], maxs: list[float]) -> npt.NDArray[np.float64]:
    """One 16-bit step of the log-space position code, per axis."""
    return (np.asarray(maxs, np.float64) - np.asarray(mins, np.float64)) / U16_MAX


def log_space_error(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """|f(a) - f(b)| per coordinate, f the symmetric log transform of SOG positions."""
    return np.abs(log_transform(a) - log_transform(b))
