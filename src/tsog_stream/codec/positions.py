"""Positions: symmetric-log 16-bit codes split into low/high byte images (SOG v2 means)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..columns import down, row_blocks
from ..constants import U16_MAX

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


def log_transform(v: npt.ArrayLike) -> F64:
    """f(v) = sign(v) * ln(1 + |v|), the transform SOG applies before quantising positions."""
    a = np.asarray(v, dtype=np.float64)
    return np.sign(a) * np.log1p(np.abs(a))


def quantize_u16(values: F64, mins: F64, maxs: F64) -> npt.NDArray[np.uint16]:
    """Round ``values`` (N, C) to 16-bit codes over per-channel [mins, maxs] (0 where max = min)."""
    span = maxs - mins
    safe = np.where(span > 0, span, 1.0)
    q = np.rint((values - mins) / safe * U16_MAX)
    q = np.where(span > 0, q, 0.0)
    return np.asarray(np.clip(q, 0, U16_MAX), dtype=np.uint16)


def dequantize_u16(codes: npt.NDArray[np.uint16], mins: F64, maxs: F64) -> F64:
    """Values of 16-bit codes over per-channel [mins, maxs]."""
    return mins + (maxs - mins) * (codes.astype(np.float64) / U16_MAX)


def split_u16(codes: npt.NDArray[np.uint16]) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """(low byte, high byte) of 16-bit codes."""
    return (codes & 0xFF).astype(np.uint8), (codes >> 8).astype(np.uint8)


def join_u16(low: npt.NDArray[np.uint8], high: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint16]:
    """16-bit codes from their low and high bytes."""
    return low.astype(np.uint16) | (high.astype(np.uint16) << np.uint16(8))


def encode_means(means: F32) -> tuple[F64, F64, npt.NDArray[np.uint16]]:
    """(mins, maxs, codes) of positions: ranges in log space, (N, 3) codes; in blocks of rows
    (the same codes, without float64 temporaries of every row)."""
    if means.shape[0] == 0:
        zeros = np.zeros(3)
        return zeros, zeros.copy(), np.zeros((0, 3), np.uint16)
    mins, maxs = np.full(3, np.inf), np.full(3, -np.inf)
    for rows in row_blocks(len(means), 8 * means.shape[1]):
        logs = log_transform(means[rows])
        mins, maxs = np.minimum(mins, down(np.min, logs)), np.maximum(maxs, down(np.max, logs))
    codes = np.empty((len(means), 3), np.uint16)
    for rows in row_blocks(len(means), 8 * means.shape[1]):
        codes[rows] = quantize_u16(log_transform(means[rows]), mins, maxs)
    return mins, maxs, codes


def decode_means(
    low: npt.NDArray[np.uint8], high: npt.NDArray[np.uint8], mins: F64, maxs: F64
) -> F32:
    """Positions of the low and high bytes of their 16-bit codes (a zero range decodes to the
    min, as splat-transform does): per channel a gather from a table of all 65536 codes."""
    out = np.empty(low.shape, np.float32)
    for channel in range(low.shape[1]):
        codes = (high[:, channel].astype(np.intp) << 8) | low[:, channel]
        table = decode_means_table(float(mins[channel]), float(maxs[channel]))
        np.take(table, codes, out=out[:, channel])
    return out


def decode_means_table(low: float, high: float) -> F32:
    """The float32 position of every 16-bit code over one channel's log-space [low, high]."""
    span = high - low if high != low else 1.0
    logs = np.arange(U16_MAX + 1, dtype=np.float64)  # in place from here: fewer fresh pages
    np.divide(logs, U16_MAX, out=logs)
    np.multiply(logs, span, out=logs)
    np.add(logs, low, out=logs)
    values = np.abs(logs)
    np.expm1(values, out=values)
    return np.copysign(values, logs, out=values).astype(np.float32)  # the inverse of log_transform
