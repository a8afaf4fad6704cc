"""TSOG images: the timeline and the temporal coefficients as 16-bit codes over a per-channel
[min, max] (per order for coefficients), in a low-byte (``_l``) and a high-byte (``_u``) image
index-aligned with the SOG images; channels are R, G, B, A, unused ones 0 (alpha 255).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from ..columns import down
from ..errors import InputError
from ..model import Timeline, TimelineType
from ..temporal import scale_cap
from .budgets import Budgets
from .coarsen import coarsen_motion, coarsen_timeline
from .layout import from_image, to_image
from .positions import dequantize_u16, join_u16, quantize_u16, split_u16
from .rotations import canonical_factor

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


def _u16_images(
    codes: npt.NDArray[np.uint16], names: tuple[str, str], width: int, height: int
) -> dict[str, U8]:
    """The low and high images of up to four 16-bit channels; alpha 255 unless a 4th."""
    images = {}
    for name, part in zip(names, split_u16(codes), strict=True):
        texels = np.zeros((len(codes), 4), np.uint8)
        texels[:, 3] = 255
        texels[:, : codes.shape[1]] = part
        images[name] = to_image(texels, width, height)
    return images


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
    return down(np.min, values), down(np.max, values)


def _whole_frames(timeline: Timeline, mins: F64, maxs: F64) -> bool:
    """Type-1 lifespans in whole frames that fit a 16-bit range (they can be stored exactly)."""
    return bool(
        timeline.type is TimelineType.START_DURATION
        and timeline.fps is not None
        and np.all(maxs - mins <= C.U16_MAX)
        and np.all(timeline.t0 == np.rint(timeline.t0))
        and np.all(timeline.t1 == np.rint(timeline.t1))
    )


@dataclass(frozen=True)
class TimelineCodes:
    """A timeline's 16-bit codes (R = frame/start/centre, G = duration/scale) and ranges."""

    type: TimelineType
    codes: npt.NDArray[np.uint16]
    mins: F64
    maxs: F64

    def reference_units(self) -> F64:
        """The reference times a decoder reads (frame, start or centre, timeline units)."""
        return _timeline_values(self.type, self.codes, self.mins, self.maxs)[:, 0]


def _timeline_values(
    kind: TimelineType, codes: npt.NDArray[np.uint16], mins: F64, maxs: F64
) -> F64:
    """(N, 2) timeline values as a reader takes them: type-0 frame ids rounded (G: 0)."""
    values = dequantize_u16(codes, mins, maxs)
    if kind is TimelineType.FRAME:
        values[:, 0] = np.rint(values[:, 0])
        values[:, 1] = 0.0
    return values


def quantize_timeline(timeline: Timeline, budget: F64 | None = None) -> TimelineCodes:
    """A timeline's codes; with a ``budget`` (codec/precision.py) they keep only the bits it
    needs, except frame ids and whole frames, which stay exact."""
    values = np.stack([timeline.t0, timeline.t1], axis=1)
    if timeline.type is TimelineType.FRAME:
        values[:, 1] = 0.0  # G is unused for frame ids: stored as 0 with range [0, 0]
    if timeline.type is TimelineType.CENTER_SCALE:
        values[:, 1] = np.minimum(values[:, 1], scale_cap(timeline))
    mins, maxs = _ranges(values)
    whole = _whole_frames(timeline, mins, maxs)
    if whole:
        maxs = mins + C.U16_MAX  # a step of exactly one frame: start and duration decode exactly
    if timeline.type is TimelineType.FRAME and maxs[0] - mins[0] > C.U16_MAX:
        span = f"frame ids span {maxs[0] - mins[0]:.0f} frames; one chunk holds at most"
        found = f"{span} {C.U16_MAX + 1} (split the scene with tsog segment)"
        raise InputError(found, where="timeline")
    codes = quantize_u16(values, mins, maxs)
    if budget is not None and not (whole or timeline.type is TimelineType.FRAME):
        codes = coarsen_timeline(codes, mins, maxs, budget)
    return TimelineCodes(timeline.type, codes, mins, maxs)


def timeline_images(
    timeline: Timeline, codes: TimelineCodes, width: int, height: int
) -> tuple[dict[str, U8], dict[str, Any]]:
    """Timeline images and ``timeline`` meta of a timeline's codes."""
    images = _u16_images(codes.codes, (C.TIMELINE_L, C.TIMELINE_U), width, height)
    meta: dict[str, Any] = {"type": int(timeline.type)}
    if timeline.fps is not None:
        meta["fps"] = float(timeline.fps)
    if timeline.scene_length is not None:
        meta["scene_length"] = float(timeline.scene_length)
    meta.update(mins=[float(v) for v in codes.mins], maxs=[float(v) for v in codes.maxs])
    meta["files"] = [C.TIMELINE_L, C.TIMELINE_U]
    return images, meta


def decode_timeline(meta: Any, images: Mapping[str, U8], count: int) -> Timeline:
    """Timeline from its meta object and images; type-0 frame ids are rounded to integers."""
    mins = np.asarray(meta.mins, np.float64)
    maxs = np.asarray(meta.maxs, np.float64)
    kind = TimelineType(int(meta.type))
    values = _timeline_values(kind, _codes(images, tuple(meta.files), count, 2), mins, maxs)
    return Timeline(kind, values[:, 0], values[:, 1], meta.fps, meta.scene_length)


def stored_temporal(temporal: Mapping[str, F32]) -> dict[str, F64]:
    """The coefficients as ``meta.json`` stores them (docs/spec.md §6): opacity's in the A
    channel of ``sh0`` as in SOG's ``sh0.webp`` (the shorter padded with zeros), others as is."""
    stored = {a: np.asarray(c, np.float64) for a, c in temporal.items() if a != "opacity"}
    if "opacity" not in temporal:
        return stored
    opacity = np.asarray(temporal["opacity"], np.float64)
    sh0 = stored.get("sh0", np.zeros((*opacity.shape[:2], 3)))
    orders = max(sh0.shape[1], opacity.shape[1])
    combined = np.zeros((len(opacity), orders, 4))
    combined[:, : sh0.shape[1], :3] = sh0
    combined[:, : opacity.shape[1], C.OPACITY_IN_SH0] = opacity[:, :, 0]
    stored["sh0"] = combined
    return stored


def encode_temporal(
    temporal: Mapping[str, F32],
    quats: F32,
    width: int,
    height: int,
    budgets: Budgets | None = None,
) -> tuple[dict[str, U8], dict[str, Any]]:
    """Coefficient images and the ``temporal`` meta, attributes in TEMPORAL_CHANNELS order;
    with ``budgets`` (codec/precision.py) motion keeps only the bits its budget needs.

    Quaternion coefficients are scaled by the factor that canonicalises the base quaternion,
    so base + coefficients stay consistent with the stored base rotation.
    """
    images: dict[str, U8] = {}
    meta: dict[str, Any] = {}
    stored = stored_temporal(temporal)
    for attr in C.TEMPORAL_CHANNELS:
        if attr not in stored:
            continue
        coeffs = stored[attr]
        if attr == "quats":
            coeffs = coeffs * canonical_factor(quats)[0][:, None, None]
        entry: dict[str, Any] = {"mins": [], "maxs": [], "files": []}
        for order in range(1, coeffs.shape[1] + 1):
            values = coeffs[:, order - 1, :]
            mins, maxs = _ranges(values)
            codes = quantize_u16(values, mins, maxs)
            if budgets is not None:
                orders = coeffs.shape[1]
                codes = coarsen_motion(
                    codes, mins, maxs, attr=attr, order=order, orders=orders, budgets=budgets
                )
            names = (C.temporal_file(attr, order, "l"), C.temporal_file(attr, order, "u"))
            images.update(_u16_images(codes, names, width, height))
            entry["mins"].append([float(v) for v in mins])
            entry["maxs"].append([float(v) for v in maxs])
            entry["files"].extend(names)
        meta[attr] = entry
    return images, meta


def _used_orders(entry: Any, channels: slice) -> int:
    """Orders up to the last whose range on ``channels`` is not [0, 0] (the rest are padding)."""
    zero = [
        all(lo == hi == 0.0 for lo, hi in zip(mins[channels], maxs[channels], strict=True))
        for mins, maxs in zip(entry.mins, entry.maxs, strict=True)
    ]
    return max((k + 1 for k, z in enumerate(zero) if not z), default=0)


def decode_temporal(
    meta: Mapping[str, Any], images: Mapping[str, U8], count: int
) -> dict[str, F32]:
    """attr -> (N, order, channels) coefficients of the ``temporal`` meta and images, in
    every stored form (docs/spec.md §6): opacity in sh0's A channel or its own attribute;
    ``quats`` in 4 channels or the paper's 3 (x, y, z; w's coefficient 0)."""
    out: dict[str, F32] = {}
    for attr, entry in meta.items():
        channels = len(entry.mins[0])
        orders = []
        for k in range(len(entry.mins)):
            files = (entry.files[2 * k], entry.files[2 * k + 1])
            mins = np.asarray(entry.mins[k], np.float64)
            maxs = np.asarray(entry.maxs[k], np.float64)
            orders.append(dequantize_u16(_codes(images, files, count, channels), mins, maxs))
        coeffs = np.stack(orders, axis=1).astype(np.float32)
        if attr == "quats" and channels == 3:
            coeffs = np.concatenate([np.zeros_like(coeffs[:, :, :1]), coeffs], axis=2)
        if attr == "sh0" and channels == 4:
            out.update(_split_sh0(entry, coeffs))
            continue
        out[attr] = coeffs
    return {attr: out[attr] for attr in C.TEMPORAL_CHANNELS if attr in out}


def _split_sh0(entry: Any, coeffs: F32) -> dict[str, F32]:
    """sh0's colour (R, G, B) and opacity (A) coefficients of a 4-channel entry, each without
    the zero orders the writer padded it with."""
    parts: dict[str, F32] = {}
    colour_orders = _used_orders(entry, slice(0, 3))
    if colour_orders:
        parts["sh0"] = np.ascontiguousarray(coeffs[:, :colour_orders, :3])
    opacity_orders = _used_orders(entry, slice(C.OPACITY_IN_SH0, C.OPACITY_IN_SH0 + 1))
    if opacity_orders:
        parts["opacity"] = np.ascontiguousarray(coeffs[:, :opacity_orders, 3:4])
    return parts
