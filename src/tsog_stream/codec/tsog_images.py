"""TSOG images: the timeline and the temporal polynomial coefficients, 16-bit split into l/u.

Every value is quantised linearly over a per-channel [min, max] (per order for coefficients)
and stored as a low-byte image (``_l``) and a high-byte image (``_u``), index-aligned with the
SOG images. Channels map to R, G, B, A in order; unused channels hold 0 and alpha 255.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from ..errors import InputError
from ..model import Timeline, TimelineType
from .layout import from_image, to_image
from .positions import dequantize_u16, join_u16, quantize_u16, split_u16
from .rotations import canonical_factor

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


def _u16_texels(codes: npt.NDArray[np.uint16]) -> tuple[U8, U8]:
    """(low, high) (N, 4) texels of up to four 16-bit channels; alpha 255 unless a 4th channel."""
    n, channels = codes.shape
    low, high = split_u16(codes)
    out_l = np.zeros((n, 4), np.uint8)
    out_u = np.zeros((n, 4), np.uint8)
    out_l[:, 3] = out_u[:, 3] = 255
    out_l[:, :channels] = low
    out_u[:, :channels] = high
    return out_l, out_u


def _codes(
    images: Mapping[str, U8], files: tuple[str, str], count: int, channels: int
) -> npt.NDArray[np.uint16]:
    """16-bit codes of the first ``channels`` channels of an l/u image pair."""
    low = from_image(images[files[0]], count)[:, :channels]
    high = from_image(images[files[1]], count)[:, :channels]
    return join_u16(low, high)


def _ranges(values: F64) -> tuple[F64, F64]:
    """Per-channel min and max of (N, C) values (zeros when N = 0)."""
    if values.shape[0] == 0:
        return np.zeros(values.shape[1]), np.zeros(values.shape[1])
    return values.min(axis=0), values.max(axis=0)


def scale_cap(timeline: Timeline) -> float:
    """Largest type-2 scale worth storing: SCALE_CAP_SPANS times the scene's span.

    A larger scale changes the temporal opacity factor by less than 0.13 % anywhere in the
    scene, while an unbounded one (a float16 overflow in .splatv gives 65504) would stretch the
    linear 16-bit range so far that short lifespans lose all precision.
    """
    if timeline.scene_length:
        span = float(timeline.scene_length)
    elif len(timeline):
        span = float(timeline.t0.max() - timeline.t0.min())
    else:
        span = 0.0
    return C.SCALE_CAP_SPANS * max(span, 1e-3)


def _whole_frames(timeline: Timeline, mins: F64, maxs: F64) -> bool:
    """Type-1 lifespans in whole frames that fit a 16-bit range (they can be stored exactly)."""
    return bool(
        timeline.type is TimelineType.START_DURATION
        and timeline.fps is not None
        and np.all(maxs - mins <= C.U16_MAX)
        and np.all(timeline.t0 == np.rint(timeline.t0))
        and np.all(timeline.t1 == np.rint(timeline.t1))
    )


def encode_timeline(
    timeline: Timeline, width: int, height: int
) -> tuple[dict[str, U8], dict[str, Any]]:
    """Timeline images and ``timeline`` meta (R = frame/start/centre, G = duration/scale)."""
    values = np.stack([timeline.t0, timeline.t1], axis=1)
    if timeline.type is TimelineType.FRAME:
        values[:, 1] = 0.0  # G is unused for frame ids: stored as 0 with range [0, 0]
    if timeline.type is TimelineType.CENTER_SCALE:
        values[:, 1] = np.minimum(values[:, 1], scale_cap(timeline))
    mins, maxs = _ranges(values)
    if _whole_frames(timeline, mins, maxs):
        maxs = mins + C.U16_MAX  # a step of exactly one frame: start and duration decode exactly
    if timeline.type is TimelineType.FRAME and maxs[0] - mins[0] > C.U16_MAX:
        raise InputError(
            f"frame ids span {maxs[0] - mins[0]:.0f} frames; one chunk holds at most "
            f"{C.U16_MAX + 1} (split the scene with tsog segment)",
            where="timeline",
        )
    low, high = _u16_texels(quantize_u16(values, mins, maxs))
    images = {
        C.TIMELINE_L: to_image(low, width, height),
        C.TIMELINE_U: to_image(high, width, height),
    }
    meta: dict[str, Any] = {"type": int(timeline.type)}
    if timeline.fps is not None:
        meta["fps"] = float(timeline.fps)
    if timeline.scene_length is not None:
        meta["scene_length"] = float(timeline.scene_length)
    meta.update(mins=[float(v) for v in mins], maxs=[float(v) for v in maxs])
    meta["files"] = [C.TIMELINE_L, C.TIMELINE_U]
    return images, meta


def decode_timeline(meta: Any, images: Mapping[str, U8], count: int) -> Timeline:
    """Timeline from its meta object and images; type-0 frame ids are rounded to integers."""
    mins = np.asarray(meta.mins, np.float64)
    maxs = np.asarray(meta.maxs, np.float64)
    values = dequantize_u16(_codes(images, tuple(meta.files), count, 2), mins, maxs)
    kind = TimelineType(int(meta.type))
    if kind is TimelineType.FRAME:
        values[:, 0] = np.rint(values[:, 0])
        values[:, 1] = 0.0
    return Timeline(kind, values[:, 0], values[:, 1], meta.fps, meta.scene_length)


def encode_temporal(
    temporal: Mapping[str, F32], quats: F32, width: int, height: int
) -> tuple[dict[str, U8], dict[str, Any]]:
    """Coefficient images and the ``temporal`` meta object, attributes in TEMPORAL_CHANNELS order.

    Quaternion coefficients are scaled by the factor that canonicalises the base quaternion
    (sign and norm), so base + coefficients stay consistent with the stored base rotation.
    """
    images: dict[str, U8] = {}
    meta: dict[str, Any] = {}
    for attr in C.TEMPORAL_CHANNELS:
        if attr not in temporal:
            continue
        coeffs = temporal[attr].astype(np.float64)
        if attr == "quats":
            coeffs = coeffs * canonical_factor(quats)[0][:, None, None]
        entry: dict[str, Any] = {"mins": [], "maxs": [], "files": []}
        for order in range(1, coeffs.shape[1] + 1):
            values = coeffs[:, order - 1, :]
            mins, maxs = _ranges(values)
            low, high = _u16_texels(quantize_u16(values, mins, maxs))
            names = (C.temporal_file(attr, order, "l"), C.temporal_file(attr, order, "u"))
            images[names[0]] = to_image(low, width, height)
            images[names[1]] = to_image(high, width, height)
            entry["mins"].append([float(v) for v in mins])
            entry["maxs"].append([float(v) for v in maxs])
            entry["files"].extend(names)
        meta[attr] = entry
    return images, meta


def decode_temporal(
    meta: Mapping[str, Any], images: Mapping[str, U8], count: int
) -> dict[str, F32]:
    """attr -> (N, order, channels) coefficients from the ``temporal`` meta object and images."""
    out: dict[str, F32] = {}
    for attr, entry in meta.items():
        channels = C.TEMPORAL_CHANNELS[attr]
        orders = []
        for k in range(len(entry.mins)):
            files = (entry.files[2 * k], entry.files[2 * k + 1])
            mins = np.asarray(entry.mins[k], np.float64)
            maxs = np.asarray(entry.maxs[k], np.float64)
            orders.append(dequantize_u16(_codes(images, files, count, channels), mins, maxs))
        out[attr] = np.stack(orders, axis=1).astype(np.float32)
    return out
