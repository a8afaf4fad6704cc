"""Rotations: smallest-three quaternion bytes with the 252+m tag (SOG v2 quats.webp)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..constants import QUAT_TAG_BASE

F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]
U32 = npt.NDArray[np.uint32]
SQRT2 = float(np.sqrt(2.0))


def canonical_factor(quats: F32) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.intp]]:
    """(sign/norm making each quaternion unit with its largest part >= 0, that part's index);
    temporal coefficients are scaled alike. A zero quaternion gets 1 (it becomes the identity).
    Column by column, the norm summed in ``np.linalg.norm``'s order: the same bits, faster."""
    q = quats.astype(np.float64)
    squares = [q[:, k] * q[:, k] for k in range(4)]
    norm = np.sqrt(((squares[0] + squares[1]) + squares[2]) + squares[3])
    largest = largest_component(quats)  # float32 compares as its float64 values do
    at_largest = np.take(q.reshape(-1), 4 * np.arange(q.shape[0]) + largest)
    sign = np.where(at_largest < 0, -1.0, 1.0)
    return np.divide(sign, norm, out=np.ones_like(norm), where=norm > 0), largest


def largest_component(q: npt.NDArray[np.floating]) -> npt.NDArray[np.intp]:
    """``np.argmax(np.abs(q), axis=1)`` of (N, 4) ``q`` (the first of equals; a NaN counts as
    the largest), column by column where every value is finite."""
    if not np.isfinite(q).all():
        return np.asarray(np.argmax(np.abs(q), axis=1), np.intp)
    a = [np.abs(q[:, k]) for k in range(4)]
    second, fourth = a[1] > a[0], a[3] > a[2]  # strictly: the first of equals wins
    later_pair = np.maximum(a[2], a[3]) > np.maximum(a[0], a[1])
    return np.asarray(np.where(later_pair, 2 + fourth.astype(np.intp), second.astype(np.intp)))


def canonical_quats(quats: F32) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.intp]]:
    """Unit quaternions whose largest component is positive, and that component's index
    (a zero or non-finite quaternion, which names no rotation, becomes the identity)."""
    factor, largest = canonical_factor(quats)
    with np.errstate(invalid="ignore"):  # inf x 0: those rows become the identity below
        q = quats.astype(np.float64) * factor[:, None]
    nonzero = (quats[:, 0] != 0) | (quats[:, 1] != 0) | (quats[:, 2] != 0) | (quats[:, 3] != 0)
    finite = np.isfinite(q)
    zero = ~nonzero | ~(finite[:, 0] & finite[:, 1] & finite[:, 2] & finite[:, 3])
    if zero.any():
        q[zero] = (1.0, 0.0, 0.0, 0.0)  # no rotation to keep: the identity
        largest[zero] = 0
    return q, largest


def encode_quats(quats: F32) -> U8:
    """(N, 4) texels: the three smaller components as bytes, alpha = 252 + dropped index."""
    q, largest = canonical_quats(quats)
    codes = np.clip(np.rint(255.0 * (q * SQRT2 * 0.5 + 0.5)), 0, 255).astype(np.uint8)
    out = np.empty((q.shape[0], 4), np.uint8)
    for j in range(3):  # component j before the dropped one, else the one after it
        out[:, j] = np.where(largest > j, codes[:, j], codes[:, j + 1])
    out[:, 3] = QUAT_TAG_BASE + largest
    return out


def decode_quats(texels: U8) -> F32:
    """Unit (w, x, y, z) quaternions from smallest-three texels; a bad tag gives identity.

    Column by column from byte tables holding the float64 formula's values, each column
    picked by bit masks of the tag: exact, and cheaper than ``np.where`` (chunk-codec.md).
    """
    tag = texels[:, 3] - np.uint8(QUAT_TAG_BASE)  # a bad tag wraps above 3
    s0, s1, s2 = (np.take(_COMPONENT_BITS_OF_BYTE, texels[:, k]) for k in range(3))
    first_two = np.ascontiguousarray(texels).view(np.uint16)[:, 0]  # bytes 0 and 1 as one key
    rest = np.take(_SQUARES_OF_BYTE_PAIR, first_two)  # in place from here: fewer fresh pages
    rest += np.take(_SQUARE_OF_BYTE, texels[:, 2])
    np.subtract(1.0, rest, out=rest)
    np.maximum(rest, 0.0, out=rest)
    dropped = np.sqrt(rest, out=rest).astype(np.float32).view(np.uint32)
    w, x, y, z = (np.take(mask, tag) for mask in _DROPPED_AT)  # which component was dropped
    columns = (
        _pick(s0, dropped, w),
        _pick(_pick(s1, s0, w), dropped, x),
        _pick(_pick(s1, dropped, y), s2, z),
        _pick(s2, dropped, z),
    )
    q = np.stack(columns, axis=1).view(np.float32)
    bad = tag > 3
    if bad.any():
        q[bad] = (1.0, 0.0, 0.0, 0.0)
    return q


def _pick(base: U32, other: U32, mask: U32) -> U32:
    """``other`` where ``mask`` is all ones, ``base`` where it is zero (float32 bit patterns)."""
    out = np.bitwise_xor(base, other)
    out &= mask
    out ^= base
    return out


_COMPONENT_F64 = (np.arange(256, dtype=np.float64) / 255.0 * 2.0 - 1.0) / SQRT2
_COMPONENT_OF_BYTE = _COMPONENT_F64.astype(np.float32)
"""A stored byte's quaternion component: the inverse of encode_quats' rounding."""
_COMPONENT_BITS_OF_BYTE = _COMPONENT_OF_BYTE.view(np.uint32)
"""The same float32 values as bit patterns, for :func:`_pick`."""
_SQUARE_OF_BYTE = _COMPONENT_F64 * _COMPONENT_F64
"""Its square in float64, for the dropped component's sqrt(1 - a² - b² - c²)."""
_BYTE_PAIRS = np.arange(1 << 16, dtype=np.uint16).view(np.uint8).reshape(-1, 2)
_SQUARES_OF_BYTE_PAIR = _SQUARE_OF_BYTE[_BYTE_PAIRS[:, 0]] + _SQUARE_OF_BYTE[_BYTE_PAIRS[:, 1]]
"""a² + b² of the first two bytes, indexed by the two bytes read as one uint16 (native order)."""
_DROPPED_AT = tuple(
    np.where(np.arange(256) == k, np.uint32(0xFFFFFFFF), np.uint32(0)).astype(np.uint32)
    for k in range(4)
)
"""Per tag value (0-255 after the base is taken off): all ones where component k was dropped."""
