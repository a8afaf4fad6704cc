"""splaTV ``.splatv`` files (Spacetime Gaussians for the web) -> a type-2 :class:`Scene`.

Layout (little-endian): uint32 magic ``0x674B``, uint32 JSON length, a JSON list of chunks
``{"type", "size", ...}`` whose bodies follow in list order; the ``splat`` chunk holds 64-byte
records (:data:`RECORD`). Time is normalised to [0, 1]: one unit becomes ``duration_s`` seconds
(assumed 1 s, the file does not say). The field mapping, the viewer's equations it reproduces
and every repair and drop (each counted in a note): docs/inputs.md, "splaTV .splatv"."""

from __future__ import annotations

import json
import math
import os
import struct
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from ..constants import SH_C0
from ..errors import FormatError
from ..model import F32, Gaussians, Scene, Timeline, TimelineType
from ..opacity import alpha_to_logit
from ..schemas.cameras import Camera, cameras_from_json
from .files import read_bytes, read_head
from .loaded import ASSUMED_LENGTH_S, Loaded4D, length_s

MAGIC: Final = 0x674B
PREAMBLE: Final = struct.Struct("<II")
"""magic, JSON length."""
MAX_JSON_BYTES: Final = 16 * 1024 * 1024
"""A JSON header longer than this is rejected before it is read."""
ASSUMED_DURATION_S: Final = ASSUMED_LENGTH_S
ASSUMED_DURATION: Final = (
    "splatv time is normalised to [0, 1] and the file does not say how long the clip is: "
    "read as 1 s (pass --duration-s)"
)
"""The note on a clip read without duration_s (``Loaded4D.duration_assumed`` says it too; the
CLI says it first, as a warning)."""
RECORD: Final = np.dtype(
    [
        ("position", "<f4", (3,)),
        ("rotation", "<f2", (4,)),
        ("scale", "<f2", (3,)),
        ("pad0", "<u2"),
        ("rgba", "u1", (4,)),
        ("motion", "<f2", (9,)),
        ("pad1", "<u2"),
        ("omega", "<f2", (4,)),
        ("trbf_center", "<f2"),
        ("trbf_scale", "<f2"),
    ]
)
"""One Gaussian of the ``splat`` chunk (64 bytes)."""
F16_MAX: Final = 65504.0
F16_TINY: Final = 2.0**-24
"""Smallest positive float16 (subnormal): the floor for zero scales."""

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SplatChunk:
    """Where the ``splat`` chunk's records are: byte offset, record count, declared slots."""

    offset: int
    count: int
    slots: int


def sniff_splatv(head: bytes | memoryview) -> bool:
    """True when ``head`` starts with the splatv magic (uint32 0x674B, little-endian)."""
    return len(head) >= 4 and bytes(head[:4]) == MAGIC.to_bytes(4, "little")


def read_splatv(path: str | os.PathLike[str], *, duration_s: float | None = None) -> Loaded4D:
    """Read and decode a ``.splatv`` file (see :func:`parse_splatv`)."""
    return parse_splatv(read_bytes(path), name=str(path), duration_s=duration_s)


def parse_splatv(
    data: bytes | memoryview, *, name: str = "<bytes>", duration_s: float | None = None
) -> Loaded4D:
    """Decode a ``.splatv`` held in memory; one normalised time unit = ``duration_s`` seconds."""
    duration = length_s(duration_s, "duration_s")
    chunks, body = _read_header(data, name)
    notes: list[str] = []
    chunk = _locate_splat(chunks, body, len(data), name, notes)
    records = np.frombuffer(data, RECORD, count=chunk.count, offset=chunk.offset)
    keep = _keep_mask(records, notes)
    scene = _to_scene(records[keep], duration, notes)
    assumed = duration_s is None
    if assumed:
        notes.insert(0, ASSUMED_DURATION)
    return Loaded4D(scene, notes, _header_cameras(chunks, name, notes), duration_assumed=assumed)


def read_splatv_cameras(path: str | os.PathLike[str]) -> tuple[list[Camera], list[str]]:
    """The cameras a ``.splatv`` header carries (reads the header only) and notes on them."""
    head = read_head(path, PREAMBLE.size + MAX_JSON_BYTES)
    chunks, _ = _read_header(head, str(path))
    notes: list[str] = []
    return _header_cameras(chunks, str(path), notes), notes


def _header_cameras(chunks: list[dict[str, Any]], name: str, notes: list[str]) -> list[Camera]:
    """The ``cameras`` list of the first chunk that has one (3DGS cameras.json entries); an
    unreadable list is noted and ignored: the Gaussians do not depend on it."""
    for i, chunk in enumerate(chunks):
        if "cameras" in chunk:
            try:
                return cameras_from_json(chunk["cameras"], where=f"{name}: chunk {i} cameras")
            except FormatError as exc:
                notes.append(f"ignored the file's cameras: {exc}")
                return []
    return []


def _read_header(data: bytes | memoryview, name: str) -> tuple[list[dict[str, Any]], int]:
    """The JSON chunk list and the byte offset where the first chunk body starts."""
    if len(data) < PREAMBLE.size:
        raise FormatError(f"expected at least 8 bytes, found {len(data)}", where=name)
    magic, length = PREAMBLE.unpack_from(data)
    if magic != MAGIC:
        raise FormatError(f"expected magic 0x674B, found {magic:#x}", where=name)
    if length > min(MAX_JSON_BYTES, len(data) - PREAMBLE.size):
        raise FormatError(
            f"JSON length {length} exceeds the {len(data) - PREAMBLE.size} bytes that follow "
            f"(limit {MAX_JSON_BYTES})",
            where=name,
        )
    raw = bytes(data[PREAMBLE.size : PREAMBLE.size + length])
    try:
        parsed = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # RecursionError: nesting
        raise FormatError(f"the JSON header is not valid UTF-8 JSON: {exc}", where=name) from None
    return _check_chunks(parsed, name), PREAMBLE.size + length


def _check_chunks(parsed: object, name: str) -> list[dict[str, Any]]:
    """Validate the chunk list: objects with a string ``type`` and a non-negative int ``size``."""
    if not isinstance(parsed, list):
        raise FormatError(
            f"expected a JSON list of chunks, found {type(parsed).__name__}", where=name
        )
    for i, chunk in enumerate(parsed):
        where = f"{name}: JSON chunk {i}"
        if not isinstance(chunk, dict):
            raise FormatError(f"expected an object, found {type(chunk).__name__}", where=where)
        if not isinstance(chunk.get("type"), str):
            raise FormatError("'type' must be a string", where=where)
        size = chunk.get("size")
        if not isinstance(size, int) or isinstance(size, bool) or size < 0:
            raise FormatError(f"'size' must be a non-negative integer, found {size!r}", where=where)
    return parsed


def _locate_splat(
    chunks: list[dict[str, Any]], offset: int, total: int, name: str, notes: list[str]
) -> SplatChunk:
    """Find the first ``splat`` chunk and count its whole records (the file may stop early).

    Chunks before it must lie wholly in the file (else its offset is unknown); chunks after
    it are ignored, so a splat chunk shorter than declared is fine.
    """
    found: SplatChunk | None = None
    for i, chunk in enumerate(chunks):
        size: int = chunk["size"]
        if found is None and chunk["type"] == "splat":
            found = _splat_records(offset, size, total, f"{name}: chunk {i}")
        else:
            notes.append(f"ignored chunk {i} of type {chunk['type']!r}")
            if found is None and offset + size > total:
                msg = f"chunk {i} ends at byte {offset + size}, past the end ({total})"
                raise FormatError(msg, where=name)
        offset += size
    if found is None:
        raise FormatError("no 'splat' chunk in the JSON header", where=name)
    if offset < total:
        notes.append(f"ignored {total - offset} bytes after the last chunk")
    if found.slots - found.count >= 1024:  # more than one 4096-texel texture row missing
        notes.append(f"the splat chunk declares {found.slots} slots but holds {found.count}")
    return found


def _splat_records(offset: int, size: int, total: int, where: str) -> SplatChunk:
    """Records of a splat chunk: the declared size is the padded texture; files may hold fewer."""
    if size % RECORD.itemsize:
        raise FormatError(f"size {size} is not a multiple of {RECORD.itemsize}", where=where)
    present = min(size, total - offset)
    if present % RECORD.itemsize:
        raise FormatError(
            f"the file ends inside a record: {present} bytes are not a multiple of "
            f"{RECORD.itemsize} (truncated?)",
            where=where,
        )
    return SplatChunk(offset, present // RECORD.itemsize, size // RECORD.itemsize)


def _keep_mask(records: npt.NDArray[np.void], notes: list[str]) -> npt.NDArray[np.bool_]:
    """Gaussians worth keeping; each dropped group is counted once, first reason wins."""
    n = len(records)
    f32 = {k: records[k].astype(np.float32) for k in ("rotation", "scale", "motion", "omega")}
    scale = records["trbf_scale"].astype(np.float32)
    bad_position = ~np.isfinite(records["position"]).all(axis=1)
    bad_other = ~np.isfinite(records["trbf_center"].astype(np.float32)) | np.isnan(scale)
    for values in f32.values():
        bad_other |= ~np.isfinite(values).all(axis=1)
    reasons = (
        (bad_position, "non-finite positions"),
        (bad_other, "non-finite rotation, scale, motion or time values"),
        (~(scale > 0), "a temporal scale <= 0 (never visible)"),
    )
    dropped = np.zeros(n, bool)
    for mask, reason in reasons:
        count = int(np.count_nonzero(mask & ~dropped))
        if count:
            notes.append(f"dropped {count} of {n} Gaussians with {reason}")
        dropped |= mask
    return ~dropped


def _to_scene(records: npt.NDArray[np.void], duration: float, notes: list[str]) -> Scene:
    """Map kept records to base Gaussians, a type-2 timeline and temporal coefficients."""
    quats, omega = _rotations(records, notes)
    gaussians = Gaussians.from_arrays(
        records["position"],
        _log_scales(records, notes),
        quats,
        _logits(records["rgba"][:, 3], notes),
        (records["rgba"][:, :3].astype(np.float64) / 255.0 - 0.5) / SH_C0,
    )
    timeline = Timeline(
        TimelineType.CENTER_SCALE,
        records["trbf_center"].astype(np.float64) * duration,
        _trbf_scales(records, notes) * duration / math.sqrt(2.0),
        scene_length=duration,
    )
    motion = records["motion"].astype(np.float64).reshape(-1, 3, 3)  # (N, order, xyz)
    motion /= (duration ** np.arange(1, 4))[None, :, None]
    temporal = {"means": motion.astype(np.float32), "quats": (omega / duration)[:, None, :]}
    temporal = {k: v for k, v in temporal.items() if np.any(v)}
    return Scene(gaussians, timeline, temporal)


def _rotations(records: npt.NDArray[np.void], notes: list[str]) -> tuple[F32, F32]:
    """(w, x, y, z) base rotations and rates, with zero base rotations made representable.

    q = 0 is what training leaves when a Gaussian starts at zero: the rasteriser's rotation
    matrix is quadratic in q, so its gradient there is zero and R stays the identity. A zero
    base without a rate becomes the identity; with a rate w it becomes w, since q(t) = w dt is
    that same rotation at every t != 0.
    """
    quats = records["rotation"].astype(np.float32)
    omega = records["omega"].astype(np.float32)
    zero = ~quats.any(axis=1)
    moving = zero & omega.any(axis=1)
    quats[zero & ~moving] = (1.0, 0.0, 0.0, 0.0)
    quats[moving], omega[moving] = omega[moving], 0.0
    if still := int(np.count_nonzero(zero & ~moving)):
        notes.append(f"set {still} zero rotations to the identity (the splaTV shader divides 0/0)")
    if int(moving.sum()):
        notes.append(f"set {int(moving.sum())} zero rotations to their constant rotation rate")
    return quats, omega


def _log_scales(records: npt.NDArray[np.void], notes: list[str]) -> F64:
    """ln of the linear scales; |scale| (the covariance only sees its square), 0 -> 2^-24."""
    scales = np.abs(records["scale"].astype(np.float64))
    tiny = scales < F16_TINY
    if tiny.any():
        notes.append(f"raised {int(tiny.sum())} zero scale values to 2^-24")
    return np.log(np.maximum(scales, F16_TINY))


def _logits(alpha: npt.NDArray[np.uint8], notes: list[str]) -> F64:
    """logit(alpha / 255), alpha clamped so bytes 0 and 255 stay finite."""
    clamped = int(np.count_nonzero((alpha == 0) | (alpha == 255)))
    if clamped:
        notes.append(f"clamped {clamped} opacities of alpha byte 0 or 255 to finite logits")
    return alpha_to_logit(alpha / 255.0).astype(np.float64)


def _trbf_scales(records: npt.NDArray[np.void], notes: list[str]) -> F64:
    """The viewer's s = exp(trbf_scale); +inf (an f16 overflow) becomes the largest f16."""
    scales = records["trbf_scale"].astype(np.float64)
    inf = np.isinf(scales)
    if inf.any():
        notes.append(f"replaced {int(inf.sum())} infinite temporal scales by {F16_MAX:g}")
    return np.where(inf, F16_MAX, scales)


__all__ = ["MAGIC", "RECORD", "parse_splatv", "read_splatv", "sniff_splatv"]
