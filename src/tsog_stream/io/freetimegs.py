"""FreeTimeGS inputs (extended 3DGS PLY, FreeTimeGsVanilla ``.npz``) -> a type-2 :class:`Scene`.

FreeTimeGS (Wang et al., CVPR 2025) gives each Gaussian a centre time mu_t, a temporal sigma and
a velocity v on time normalised to [0, 1]: position(t) = mean + v (t - mu_t), alpha(t) =
sigmoid(opacity) exp(-1/2 ((t - mu_t) / sigma)^2), which is TSOG timeline type 2 with order-1
temporal means. One normalised unit becomes ``scene_length_s`` seconds (assumed 1 s: neither
source stores a frame rate). Spellings, header comments and what is dropped: docs/inputs.md,
"FreeTimeGS".
"""

from __future__ import annotations

import io
import math
import zipfile
from collections.abc import Collection, Mapping
from typing import BinaryIO, Final, Literal, cast

import numpy as np
import numpy.typing as npt

from ..codec.bundle import MAX_ENTRIES, ZIP_ERRORS, ZIP_MAGIC, check_member
from ..errors import FormatError, InputError, UnsupportedError
from ..model import Gaussians, Scene, Timeline, TimelineType
from .loaded import Loaded4D, length_s
from .ply import parse_ply
from .ply_columns import PlyContents
from .ply_header import PlyHeader

TIME_NAMES: Final = ("time", "t")
DURATION_NAMES: Final = ("log_duration", "duration", "t_scale")
VELOCITY_NAMES: Final = (
    ("velocity_0", "velocity_1", "velocity_2"),
    ("velocity_x", "velocity_y", "velocity_z"),
    ("vx", "vy", "vz"),
    ("motion_0", "motion_1", "motion_2"),
)
MIN_DURATION: Final = 0.02
"""FreeTimeGsVanilla's floor on sigma (normalised time), applied to checkpoints on load."""
NPZ_REQUIRED: Final = (
    "means",
    "scales",
    "quats",
    "opacities",
    "sh0",
    "times",
    "durations",
    "velocities",
)
NPZ_TAILS: Final[Mapping[str, tuple[tuple[int, ...], ...]]] = {
    "means": ((3,),),
    "scales": ((3,),),
    "quats": ((4,),),
    "opacities": ((), (1,)),
    "sh0": ((1, 3), (3,)),
    "times": ((1,), ()),
    "durations": ((1,), ()),
    "velocities": ((3,),),
}
"""Accepted per-row shapes of each checkpoint array (shN is (K, 3), checked by Gaussians)."""
NPZ_OPTIONAL: Final = ("shN", "use_velocity")
ASSUMED_SCENE_LENGTH: Final = (
    "FreeTimeGS time is normalised to [0, 1] and the file does not say how long the scene is: "
    "1 unit read as 1.0 s (pass --scene-length-s)"
)
"""The note on a scene read without scene_length_s (``Loaded4D.duration_assumed`` says it too)."""
_EXTRAS_NOTE: Final = "unknown properties kept as extras"

DurationMode = Literal["log", "linear"]
F64 = npt.NDArray[np.float64]
Floats = npt.NDArray[np.float32] | npt.NDArray[np.float64]


# --- PLY -------------------------------------------------------------------------------------


def is_freetimegs_ply(contents_or_header: PlyContents | PlyHeader) -> bool:
    """True when the vertex element has a time and a duration property (any known spelling)."""
    header = (
        contents_or_header.header
        if isinstance(contents_or_header, PlyContents)
        else contents_or_header
    )
    vertex = header.element("vertex")
    names = set(vertex.names) if vertex is not None else set()
    return bool(names & set(TIME_NAMES)) and bool(names & set(DURATION_NAMES))


def parse_freetimegs_ply(
    data: bytes | memoryview,
    *,
    name: str = "<bytes>",
    scene_length_s: float | None = None,
    duration: DurationMode = "log",
) -> Loaded4D:
    """Decode a FreeTimeGS-style PLY; one normalised time unit = ``scene_length_s`` seconds."""
    length_s(scene_length_s, "scene_length_s")  # a bad option refused before any reading
    if duration not in ("log", "linear"):
        raise InputError(f"must be 'log' or 'linear', got {duration!r}", where="duration")
    contents = parse_ply(data, name=name)
    comments = _comments(contents.header)
    if comments.get("time_units", "normalized") != "normalized":
        raise UnsupportedError(f"time_units {comments['time_units']!r}", where=name)
    extra = dict(contents.extra)
    if duration == "linear" and "log_duration" in extra:
        raise InputError("'log_duration' holds log sigma: duration='linear' contradicts it")
    times = _pop_one(extra, TIME_NAMES, name)
    sigma = _pop_one(extra, DURATION_NAMES, name)
    if times is None or sigma is None:
        raise FormatError("not a FreeTimeGS PLY: needs a time and a duration property", where=name)
    if duration == "log":
        sigma = _exp(sigma)
    velocity = _velocity(extra, name)
    notes = [n for n in contents.notes if not n.startswith(_EXTRAS_NOTE)]
    if extra:
        notes.append(f"{_EXTRAS_NOTE}: {', '.join(extra)} (not part of the 4D model)")
    if comments.get("use_velocity") == "0" and velocity is not None:
        notes.append("use_velocity 0: velocities ignored, positions are static")
        velocity = None
    floor = _float_comment(comments, "min_duration", name)
    if floor is not None:
        sigma = np.maximum(sigma, floor)
    if scene_length_s is None and "n_frames" in comments:
        frames = comments["n_frames"]
        notes.append(f"n_frames {frames}: scene_length_s = ({frames} - 1) / fps gives real time")
    if "opacity_floor" in comments:
        notes.append(f"opacity_floor {comments['opacity_floor']} not represented")
    return _build(
        contents.gaussians, times, sigma, velocity, scene_length_s=scene_length_s, notes=notes
    )


def _comments(header: PlyHeader) -> dict[str, str]:
    """``comment <key> <value>`` lines as a dict (the .ftgs.ply metadata)."""
    pairs = (c.split(maxsplit=1) for c in header.comments)
    return {p[0]: p[1].strip() for p in pairs if len(p) == 2}


def _float_comment(comments: Mapping[str, str], key: str, name: str) -> float | None:
    """A positive numeric comment value, or None when absent."""
    if key not in comments:
        return None
    try:
        value = float(comments[key])
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise FormatError(f"comment {key} must be a positive number", where=name)
    return value


def _pop_one(
    extra: dict[str, npt.NDArray[np.generic]], names: tuple[str, ...], where: str
) -> F64 | None:
    """Remove and return the one present spelling of a property (an error if several are)."""
    present = [n for n in names if n in extra]
    if len(present) > 1:
        raise FormatError(f"ambiguous: both {present[0]!r} and {present[1]!r} present", where=where)
    return extra.pop(present[0]).astype(np.float64) if present else None


def _velocity(extra: dict[str, npt.NDArray[np.generic]], where: str) -> F64 | None:
    """(N, 3) velocity from the first complete spelling, or None when there is none."""
    if "motion_3" in extra:
        msg = "motion_3.. present: a polynomial motion (Spacetime Gaussians), not a velocity"
        raise UnsupportedError(msg, where=where)
    found = [names for names in VELOCITY_NAMES if all(n in extra for n in names)]
    if len(found) > 1:
        raise FormatError(f"ambiguous velocity: {found[0][0]}.. and {found[1][0]}..", where=where)
    if not found:
        return None
    return np.stack([extra.pop(n).astype(np.float64) for n in found[0]], axis=1)


# --- npz -------------------------------------------------------------------------------------


def sniff_freetimegs_npz(data: bytes | memoryview | BinaryIO) -> bool:
    """True for a zip (bytes, or an open file: only its directory is read) holding
    ``means.npy``, ``times.npy`` and ``durations.npy``."""
    if isinstance(data, bytes | memoryview) and bytes(data[:4]) != ZIP_MAGIC:
        return False
    return is_freetimegs_npz(zip_members(data) or set())


def is_freetimegs_npz(members: Collection[str]) -> bool:
    """Whether a zip's member names are a FreeTimeGS checkpoint's."""
    return {"means.npy", "times.npy", "durations.npy"} <= set(members)


def zip_members(data: bytes | memoryview | BinaryIO) -> set[str] | None:
    """The member names of a zip (bytes or an open file), None when it is no readable zip."""
    source: BinaryIO = io.BytesIO(data) if isinstance(data, bytes | memoryview) else data
    try:
        with zipfile.ZipFile(source) as zf:
            return set(zf.namelist())
    except ZIP_ERRORS:
        return None


def parse_freetimegs_npz(
    data: bytes | memoryview | BinaryIO,
    *,
    name: str = "<bytes>",
    scene_length_s: float | None = None,
) -> Loaded4D:
    """Decode a FreeTimeGsVanilla checkpoint ``.npz`` (bytes or an open file, read member by
    member); float32 arrays stay float32, so the Gaussians are held once."""
    length_s(scene_length_s, "scene_length_s")  # a bad option refused before any reading
    arrays = _load_npz(data, name)
    n = arrays["means"].shape[0] if arrays["means"].ndim else -1
    for key in NPZ_REQUIRED:
        if arrays[key].shape[:1] != (n,) or arrays[key].shape[1:] not in NPZ_TAILS[key]:
            tails = " or ".join(str((n, *t)) for t in NPZ_TAILS[key])
            msg = f"expected shape {tails}, found {arrays[key].shape}"
            raise FormatError(msg, where=f"{name}: {key}")
    try:
        gaussians = Gaussians.from_arrays(
            arrays["means"],
            arrays["scales"],
            arrays["quats"],
            arrays["opacities"].reshape(n),
            arrays["sh0"].reshape(n, 3),
            shN=arrays.get("shN", np.zeros((n, 0, 3))),
        )
    except InputError as exc:
        raise FormatError(exc.message, where=f"{name}: {exc.where}") from None
    sigma = np.maximum(_exp(_f64(arrays["durations"].reshape(n))), MIN_DURATION)
    velocity: F64 | None = _f64(arrays["velocities"])
    finite = np.ones(n, bool)
    for key in ("means", "scales", "quats", "opacities", "sh0"):
        finite &= np.isfinite(arrays[key].reshape(n, -1)).all(axis=1)
    notes = []
    if bad := int(n - np.count_nonzero(finite)):
        notes.append(f"kept {bad} Gaussians with non-finite base values as read")
    if "use_velocity" in arrays and not arrays["use_velocity"].any():
        notes.append("use_velocity 0: velocities ignored, positions are static")
        velocity = None
    times = _f64(arrays["times"].reshape(n))
    return _build(gaussians, times, sigma, velocity, scene_length_s=scene_length_s, notes=notes)


def _load_npz(data: bytes | memoryview | BinaryIO, name: str) -> dict[str, Floats]:
    """The checkpoint's arrays through zipfile and numpy: the member count, every member's
    claimed size and every ``.npy`` header's shape x dtype checked before any array is made
    (a zip bomb or a lying header is refused unread)."""
    source = cast(BinaryIO, data) if hasattr(data, "read") else io.BytesIO(cast(bytes, data))
    try:
        total = source.seek(0, io.SEEK_END)
        source.seek(0)
        zf = zipfile.ZipFile(source)
    except ZIP_ERRORS as exc:
        raise FormatError(f"not a readable npz (zip) file: {exc}", where=name) from None
    with zf:
        infos = zf.infolist()
        if len(infos) > MAX_ENTRIES:
            raise FormatError(f"{len(infos)} members, more than {MAX_ENTRIES}", where=name)
        members = {i.filename.removesuffix(".npy"): i for i in infos}
        if missing := [k for k in NPZ_REQUIRED if k not in members]:
            raise FormatError(f"missing array {', '.join(missing)}", where=name)
        wanted = [k for k in (*NPZ_REQUIRED, *NPZ_OPTIONAL) if k in members]
        for key in wanted:
            _check_npy(zf, members[key], total, f"{name}: {key}", floats=key in NPZ_REQUIRED)
        return {key: _read_npy(zf, members[key], f"{name}: {key}") for key in wanted}


def _check_npy(
    zf: zipfile.ZipFile, info: zipfile.ZipInfo, total: int, where: str, *, floats: bool
) -> None:
    """Refuse, before its array is made, a member that claims more than its compressed bytes
    can inflate to, or whose ``.npy`` header is not a float (else numeric) array its claimed
    size holds."""
    check_member(info, total, where, error=FormatError, unsupported=UnsupportedError)
    try:
        with zf.open(info) as f:
            version = np.lib.format.read_magic(f)
            if version not in NPY_HEADERS:
                raise UnsupportedError(f"npy format version {version}", where=where)
            shape, _, dtype = NPY_HEADERS[version](f)
            header = f.tell()
    except ZIP_ERRORS as exc:
        raise FormatError(f"not a valid .npy array: {exc}", where=where) from None
    if dtype.kind not in ("f" if floats else "fiub"):
        kind = "floating-point" if floats else "numeric"
        raise FormatError(f"expected a {kind} array, found dtype {dtype}", where=where)
    if min(shape, default=0) < 0:
        raise FormatError(f"negative dimension in shape {shape}", where=where)
    if header + math.prod(shape) * dtype.itemsize > info.file_size:
        raise FormatError(f"shape {shape} needs more bytes than the member has", where=where)


def _read_npy(zf: zipfile.ZipFile, info: zipfile.ZipInfo, where: str) -> Floats:
    """A member :func:`_check_npy` passed, as an array (float32 kept, any other dtype as
    float64), the rest of the member read too so zipfile checks its CRC-32."""
    try:
        with zf.open(info) as f:
            array = np.lib.format.read_array(f, allow_pickle=False)
            while f.read(READ_BLOCK):
                pass
    except ZIP_ERRORS as exc:
        raise FormatError(f"damaged: {exc}", where=where) from None
    return cast(Floats, array) if array.dtype == np.float32 else _f64(array)


NPY_HEADERS: Final = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
}
READ_BLOCK: Final = 1 << 20
"""Bytes of a member past its array read at a time (to reach its CRC-32)."""


# --- shared ----------------------------------------------------------------------------------


def _f64(values: npt.NDArray[np.generic]) -> F64:
    """``values`` as float64 (no copy when they are)."""
    return np.asarray(values, np.float64)


def _exp(log_sigma: F64) -> F64:
    """exp without overflow warnings (an overflow is an infinite sigma, dropped later)."""
    with np.errstate(over="ignore"):
        return np.exp(log_sigma)


def _build(
    gaussians: Gaussians,
    times: F64,
    sigma: F64,
    velocity: F64 | None,
    *,
    scene_length_s: float | None,
    notes: list[str],
) -> Loaded4D:
    """Drop unusable rows, convert normalised time to seconds and assemble the Scene."""
    length = length_s(scene_length_s, "scene_length_s")
    n = len(gaussians)
    keep = np.isfinite(times) & np.isfinite(sigma) & (sigma > 0)
    if velocity is not None:
        keep &= np.isfinite(velocity).all(axis=1)
    if dropped := int(n - keep.sum()):
        notes.append(
            f"dropped {dropped} of {n} Gaussians with a non-finite time, duration "
            "or velocity, or a duration <= 0"
        )
    timeline = Timeline(
        TimelineType.CENTER_SCALE, times[keep] * length, sigma[keep] * length, scene_length=length
    )
    temporal: dict[str, npt.NDArray[np.float32]] = {}
    if velocity is not None:
        temporal["means"] = (velocity[keep] / length)[:, None, :].astype(np.float32)
    assumed = scene_length_s is None
    if assumed:
        notes.insert(0, ASSUMED_SCENE_LENGTH)
    kept = gaussians if keep.all() else gaussians.subset(keep)  # no copy when all are kept
    return Loaded4D(Scene(kept, timeline, temporal), notes, duration_assumed=assumed)


__all__ = [
    "is_freetimegs_npz",
    "is_freetimegs_ply",
    "parse_freetimegs_npz",
    "parse_freetimegs_ply",
    "sniff_freetimegs_npz",
    "zip_members",
]
