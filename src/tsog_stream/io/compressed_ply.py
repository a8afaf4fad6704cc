"""PlayCanvas "compressed PLY" (SuperSplat, splat-transform): packed chunks -> Gaussians.

One ``chunk`` row (position, log-scale and optional colour bounds) per 256 vertices; each vertex
packs position and scale (11/10/11 bits within the bounds), a smallest-three rotation and
rgba bytes into uint32s; an optional ``sh`` element holds f_rest as bytes. The formulas follow
@playcanvas/splat-transform 3.7.0 (checked attribute by attribute in
tests/test_compressed_ply.py), except that alpha bytes 0 and 255 give logits of +-13.8 (noted),
not the reference's infinities."""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from ..constants import ALPHA_EPS, SH_C0
from ..errors import PlyError
from ..model import Gaussians
from ..opacity import alpha_to_logit
from .ply_columns import (
    F_REST_COUNTS,
    PlyContents,
    gather_columns,
    nonfinite_notes,
    sh_column_order,
    unmapped_columns,
)
from .ply_header import PlyHeader, Records, parse_header, read_elements
from .ply_values import clamp_absurd

CHUNK_SIZE: Final = 256
"""Vertices per ``chunk`` row."""
POSITION_BOUNDS: Final = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")
SCALE_BOUNDS: Final = tuple(f"{e}_scale_{a}" for e in ("min", "max") for a in "xyz")
COLOR_BOUNDS: Final = tuple(f"{e}_{c}" for e in ("min", "max") for c in "rgb")
PACKED: Final = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
ROTATION_RANGE: Final = 1.0 / (math.sqrt(2.0) * 0.5)
"""Stored [0, 1] -> (u - 0.5) * this, i.e. [-1/sqrt2, 1/sqrt2] (written as the reference does)."""

F64 = npt.NDArray[np.float64]
U32 = npt.NDArray[np.uint32]


def is_compressed_ply(header: PlyHeader) -> bool:
    """True for a PlayCanvas compressed PLY: a ``chunk`` element and a packed ``vertex``."""
    vertex = header.element("vertex")
    return (
        header.element("chunk") is not None
        and vertex is not None
        and "packed_position" in vertex.names
    )


def parse_compressed_ply(data: bytes | memoryview, *, name: str = "<bytes>") -> PlyContents:
    """Decode a compressed PLY held in memory into float32 Gaussians (SH from ``sh`` if any)."""
    header = parse_header(data, name=name)
    if not is_compressed_ply(header):
        raise PlyError("not a compressed PLY: no 'chunk' element or no packed vertex", where=name)
    _check_properties(header, name)
    body = read_elements(data, header, ("chunk", "vertex", "sh"), name=name)
    vertex, chunk = body.records["vertex"], body.records["chunk"]
    n = len(vertex)
    needed = -(-n // CHUNK_SIZE)
    if len(chunk) < needed:
        raise PlyError(f"{n} vertices need {needed} chunk rows, found {len(chunk)}", where=name)
    bounds_names = _bound_names(chunk)
    bounds = gather_columns(chunk, bounds_names)
    notes = body.notes
    notes.extend(clamp_absurd([bounds], bounds_names, header.format, where=name))
    notes.extend(nonfinite_notes([bounds], bounds_names))
    per_vertex = bounds.astype(np.float64)[np.arange(n) // CHUNK_SIZE]
    packed = {p: np.asarray(vertex[p], dtype=np.uint32) for p in PACKED}
    color, alpha = _unpack_color(packed["packed_color"], per_vertex, len(bounds_names) > 12)
    opacities, clamped = _opacity_logits(alpha)
    if clamped:
        notes.append(f"clamped {clamped} opacities with alpha byte 0 or 255 to logit ±13.8")
    position = _unorm_11_10_11(packed["packed_position"])
    scale = _unorm_11_10_11(packed["packed_scale"])
    gaussians = Gaussians(
        means=_lerp(per_vertex[:, 0:3], per_vertex[:, 3:6], position),
        scales=_lerp(per_vertex[:, 6:9], per_vertex[:, 9:12], scale),
        quats=_unpack_rotation(packed["packed_rotation"]),
        opacities=opacities,
        sh0=((color - 0.5) / SH_C0).astype(np.float32),
        shN=_decode_sh(body.records.get("sh"), n, name),
    )
    if len(chunk) > needed:
        notes.append(f"ignored {len(chunk) - needed} chunk rows beyond the {needed} needed")
    extra = unmapped_columns(vertex, set(PACKED), notes)
    return PlyContents(gaussians, extra, notes, header)


def _check_properties(header: PlyHeader, name: str) -> None:
    """Name the first required chunk or vertex property the header lacks."""
    for element_name, required in (("chunk", POSITION_BOUNDS + SCALE_BOUNDS), ("vertex", PACKED)):
        element = header.element(element_name)
        if element is None:
            raise PlyError(f"no {element_name!r} element", where=name)
        missing = [p for p in required if p not in element.names]
        if missing:
            raise PlyError(f"{element.name!r} lacks property {', '.join(missing)}", where=name)
        for prop in element.properties:
            if prop.name in PACKED and prop.type not in ("u4", "i4"):
                msg = f"{prop.name} must be a 32-bit integer, found {prop.type}"
                raise PlyError(msg, where=name)


def _bound_names(chunk: Records) -> tuple[str, ...]:
    """Chunk bound columns in decoding order; colour bounds only when all six are present."""
    names = chunk.dtype.names or ()
    base = POSITION_BOUNDS + SCALE_BOUNDS
    return base + COLOR_BOUNDS if all(c in names for c in COLOR_BOUNDS) else base


def _unorm(packed: U32, shift: int, bits: int) -> F64:
    """The ``bits``-wide field at ``shift`` as a fraction of its maximum, in [0, 1]."""
    mask = (1 << bits) - 1
    return ((packed >> np.uint32(shift)) & np.uint32(mask)) / float(mask)


def _unorm_11_10_11(packed: U32) -> F64:
    """The three fields of an 11/10/11-bit word (x in the top bits) as (N, 3) fractions."""
    return np.stack([_unorm(packed, 21, 11), _unorm(packed, 11, 10), _unorm(packed, 0, 11)], 1)


def _lerp(low: F64, high: F64, t: F64) -> npt.NDArray[np.float32]:
    """``low (1 - t) + high t`` in float64, rounded once to float32 (the reference's order)."""
    return (low * (1.0 - t) + high * t).astype(np.float32)


def _unpack_rotation(packed: U32) -> npt.NDArray[np.float32]:
    """Smallest-three quaternions to (N, 4) w, x, y, z; the dropped largest is the positive root."""
    others = np.stack([(_unorm(packed, s, 10) - 0.5) * ROTATION_RANGE for s in (20, 10, 0)], 1)
    a, b, c = others[:, 0], others[:, 1], others[:, 2]
    largest = np.sqrt(np.maximum(0.0, 1.0 - (a * a + b * b + c * c)))
    index = (packed >> np.uint32(30)).astype(np.intp)
    quats = np.empty((len(packed), 4), np.float64)
    for j in range(4):  # per output column, not per Gaussian
        source = np.clip(j - (index < j), 0, 2)
        quats[:, j] = np.where(
            index == j, largest, np.take_along_axis(others, source[:, None], 1)[:, 0]
        )
    return quats.astype(np.float32)


def _unpack_color(packed: U32, per_vertex: F64, has_bounds: bool) -> tuple[F64, F64]:
    """(N, 3) colour in [0, 1] (within chunk colour bounds when present) and (N,) alpha."""
    color = np.stack([_unorm(packed, s, 8) for s in (24, 16, 8)], 1)
    if has_bounds:
        color = per_vertex[:, 12:15] * (1.0 - color) + per_vertex[:, 15:18] * color
    return color, _unorm(packed, 0, 8)


def _opacity_logits(alpha: F64) -> tuple[npt.NDArray[np.float32], int]:
    """Logits of alpha clamped away from 0 and 1, and how many needed the clamp."""
    clamped = int(np.count_nonzero((alpha < ALPHA_EPS) | (alpha > 1.0 - ALPHA_EPS)))
    return alpha_to_logit(alpha), clamped


def _decode_sh(records: Records | None, n: int, name: str) -> npt.NDArray[np.float32]:
    """(N, K, 3) SH coefficients from the optional ``sh`` element of uchar f_rest_*."""
    if records is None:
        return np.zeros((n, 0, 3), np.float32)
    names = records.dtype.names or ()
    rest = [f"f_rest_{i}" for i in range(len(names)) if f"f_rest_{i}" in names]
    if len(rest) not in F_REST_COUNTS or len(rest) != len(names):
        raise PlyError(
            f"'sh' must hold f_rest_0..f_rest_K-1 with K in 9/24/45, found {len(names)} "
            f"properties ({len(rest)} numbered f_rest_0 onwards)",
            where=name,
        )
    if len(records) != n:
        raise PlyError(f"'sh' has {len(records)} rows, 'vertex' has {n}", where=name)
    k = len(rest) // 3
    raw = gather_columns(records, sh_column_order(k)).astype(np.float64)
    unit = np.where(raw == 0, 0.0, np.where(raw == 255, 1.0, (raw + 0.5) / 256.0))
    return ((unit - 0.5) * 8.0).astype(np.float32).reshape(n, k, 3)
