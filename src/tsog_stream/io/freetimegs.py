"""FreeTimeGS inputs (extended 3DGS PLY, FreeTimeGsVanilla ``.npz``) -> a type-2 :class:`Scene`.

FreeTimeGS (Wang et al., CVPR 2025) gives each Gaussian a canonical time mu_t, a temporal
standard deviation sigma and a velocity v, all on a timeline normalised to [0, 1]:

    position(t) = mean + v (t - mu_t),  alpha(t) = sigmoid(opacity) exp(-1/2 ((t - mu_t) / sigma)^2)

which is exactly TSOG timeline type 2 (centre mu_t, scale sigma) with order-1 temporal means
and t_ref = centre (``mean`` is the position *at* mu_t). Decisions (see
docs/inputs.md, "FreeTimeGS"):

* **Time unit.** Normalised time becomes seconds through ``scene_length_s`` (default 1.0 s,
  since neither source stores a frame rate): centre and sigma are multiplied by it and
  velocities divided by it. It is also the scene length.
* **Durations are log sigma by default**, as FreeTimeGsVanilla stores them (``log_duration``
  in its ``.ftgs.ply``, ``durations`` in its checkpoint, both with ``exp`` activation and the
  training floor sigma >= ``min_duration`` = 0.02) and like 3DGS scales; ``duration="linear"``
  reads a property called ``duration`` or ``t_scale`` as sigma itself.
* PLY spellings: time ``time``/``t``; duration ``log_duration``/``duration``/``t_scale``;
  velocity ``velocity_0..2``/``velocity_x..z``/``vx vy vz``/``motion_0..2``. Header comments of
  the ``.ftgs.ply`` layout are honoured: ``use_velocity 0`` (static positions),
  ``min_duration`` (sigma floor), ``time_units`` (must be ``normalized``).
* Rows with a non-finite time, duration or velocity, or sigma <= 0, are dropped with a note.
"""

from __future__ import annotations

import io
import math
import os
import struct
import zipfile
import zlib
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import IO, Any, BinaryIO, Final, Literal, cast

import numpy as np
import numpy.typing as npt

from ..errors import FormatError, InputError, UnsupportedError
from ..model import Gaussians, Scene, Timeline, TimelineType
from .loaded import Loaded4D
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
    _scene_length(scene_length_s)  # reject a bad option before reading anything
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
    """True for a zip holding ``means.npy``, ``times.npy`` and ``durations.npy`` (the whole
    file, or an open one: the zip directory is at its end, read without the rest)."""
    if isinstance(data, bytes | memoryview) and bytes(data[:4]) != b"PK\x03\x04":
        return False
    return is_freetimegs_npz(zip_members(data) or set())


def is_freetimegs_npz(members: Collection[str]) -> bool:
    """Whether a zip's member names are a FreeTimeGS checkpoint's."""
    return {"means.npy", "times.npy", "durations.npy"} <= set(members)


def zip_members(data: bytes | memoryview | BinaryIO) -> set[str] | None:
    """The member names of a zip (bytes or an open file: its directory only is read); None
    when it is no readable zip."""
    source: BinaryIO = io.BytesIO(data) if isinstance(data, bytes | memoryview) else data
    try:
        with zipfile.ZipFile(source) as zf:
            return set(zf.namelist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return None


def parse_freetimegs_npz(
    data: bytes | memoryview | BinaryIO,
    *,
    name: str = "<bytes>",
    scene_length_s: float | None = None,
) -> Loaded4D:
    """Decode a FreeTimeGsVanilla checkpoint saved as ``.npz`` (splats' arrays by key), from
    bytes or from an open file: a file is read member by member, never whole, and float32
    arrays stay float32 (a 5M-Gaussian SH3 checkpoint read as bytes and float64 peaked at
    about 5x its arrays)."""
    _scene_length(scene_length_s)  # reject a bad option before reading anything
    arrays = _load_npz(data, name)
    n = arrays["means"].shape[0] if arrays["means"].ndim else -1
    for key in NPZ_REQUIRED:
        if arrays[key].shape[:1] != (n,) or arrays[key].shape[1:] not in NPZ_TAILS[key]:
            tails = " or ".join(str((n, *t)) for t in NPZ_TAILS[key])
            raise FormatError(
                f"expected shape {tails}, found {arrays[key].shape}", where=f"{name}: {key}"
            )
    shn = arrays.get("shN", np.zeros((n, 0, 3)))
    try:
        gaussians = Gaussians.from_arrays(
            arrays["means"],
            arrays["scales"],
            arrays["quats"],
            arrays["opacities"].reshape(n),
            arrays["sh0"].reshape(n, 3),
            shN=shn,
        )
    except InputError as exc:
        raise FormatError(exc.message, where=f"{name}: {exc.where}") from None
    sigma = np.maximum(_exp(arrays["durations"].reshape(n).astype(np.float64)), MIN_DURATION)
    velocity: F64 | None = arrays["velocities"].astype(np.float64)
    notes: list[str] = []
    finite = np.ones(n, bool)
    for key in ("means", "scales", "quats", "opacities", "sh0"):
        finite &= np.isfinite(arrays[key].reshape(n, -1)).all(axis=1)
    if bad := int(n - np.count_nonzero(finite)):
        notes.append(f"kept {bad} Gaussians with non-finite base values as read")
    if "use_velocity" in arrays and not arrays["use_velocity"].any():
        notes.append("use_velocity 0: velocities ignored, positions are static")
        velocity = None
    times = arrays["times"].reshape(n).astype(np.float64)
    return _build(gaussians, times, sigma, velocity, scene_length_s=scene_length_s, notes=notes)


def _load_npz(data: bytes | memoryview | BinaryIO, name: str) -> dict[str, Floats]:
    """The checkpoint's arrays (float32 kept, any other dtype as float64), read header-first
    so sizes are checked before use."""
    source = data if hasattr(data, "read") else io.BytesIO(cast("bytes", data))
    try:
        with zipfile.ZipFile(cast(BinaryIO, source)) as zf:
            members = {i.filename.removesuffix(".npy"): i for i in zf.infolist()}
            missing = [k for k in NPZ_REQUIRED if k not in members]
            if missing:
                raise FormatError(f"missing array {', '.join(missing)}", where=name)
            wanted = [k for k in (*NPZ_REQUIRED, "shN", "use_velocity") if k in members]
            fd = _file_descriptor(source)
            with ThreadPoolExecutor(READ_THREADS) as pool:
                pending = {
                    k: _read_npy(
                        zf, members[k], f"{name}: {k}", floats=k in NPZ_REQUIRED, fd=fd, pool=pool
                    )
                    for k in wanted
                }
                return {k: read() for k, read in pending.items()}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError) as exc:
        raise FormatError(f"not a readable npz (zip) file: {exc}", where=name) from None
    except RuntimeError as exc:  # encrypted members
        raise UnsupportedError(f"cannot read the zip: {exc}", where=name) from None


def _file_descriptor(source: object) -> int | None:
    """The OS file descriptor of an open local file (its stored members are then read with
    ``os.pread``, straight into their arrays, on two threads); None for bytes or a stream."""
    fileno = getattr(source, "fileno", None)
    if fileno is None:
        return None
    try:
        fd = int(fileno())
    except (OSError, ValueError, io.UnsupportedOperation):
        return None
    return fd if hasattr(os, "pread") and hasattr(os, "preadv") else None


def _read_npy(
    zf: zipfile.ZipFile,
    info: zipfile.ZipInfo,
    where: str,
    *,
    floats: bool,
    fd: int | None,
    pool: ThreadPoolExecutor,
) -> Callable[[], Floats]:
    """One ``.npy`` member: float (else any numeric) dtype, a declared size that fits it; read
    straight into its array (no second copy), float32 kept. The header is read now; the
    returned function gives the array, read on ``pool`` when the member is stored in a local
    file (``fd``)."""
    with zf.open(info) as f:
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise UnsupportedError(f"npy format version {version}", where=where)
        except ValueError as exc:
            raise FormatError(f"not a valid .npy array: {exc}", where=where) from None
        if dtype.kind not in ("f" if floats else "fiub"):
            kind = "floating-point" if floats else "numeric"
            raise FormatError(f"expected a {kind} array, found dtype {dtype}", where=where)
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > info.file_size:
            raise FormatError(
                f"shape {shape} needs {nbytes} bytes, the member has fewer", where=where
            )
        npy = _Npy(np.empty(math.prod(shape), dtype), shape, bool(fortran), where)
        start = _stored_start(fd, info)
        if fd is None or start is None:
            got = _read_into(f, npy.flat.view(np.uint8))
            return lambda: npy.array(got)
        header = f.tell()
    reading = pool.submit(_pread_member, fd, info, start, header, npy)
    return lambda: npy.array(reading.result())


@dataclass(frozen=True)
class _Npy:
    """A member's declared array, its buffer allocated before it is read."""

    flat: npt.NDArray[Any]
    shape: tuple[int, ...]
    fortran: bool
    where: str

    def array(self, got: int) -> Floats:
        """The array once ``got`` bytes were read into it: shaped, float32 kept, any other
        dtype as float64 (a short read is a truncated file)."""
        if got != self.flat.nbytes:
            raise FormatError(f"truncated: {got} of {self.flat.nbytes} bytes", where=self.where)
        array = self.flat.reshape(self.shape, order="F" if self.fortran else "C")
        if array.dtype == np.float32:
            return cast("Floats", array)
        return array.astype(np.float64)


def _stored_start(fd: int | None, info: zipfile.ZipInfo) -> int | None:
    """Where a member's bytes start in the file, when it is stored (not compressed, not
    encrypted) in a local file; else None (read through zipfile)."""
    if fd is None or info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
        return None
    local = os.pread(fd, LOCAL_HEADER_SIZE, info.header_offset)
    if len(local) < LOCAL_HEADER_SIZE or local[:4] != LOCAL_HEADER_MAGIC:
        raise FormatError("bad local header", where=info.filename)
    name_length, extra_length = struct.unpack_from("<HH", local, 26)
    return int(info.header_offset + LOCAL_HEADER_SIZE + name_length + extra_length)


def _pread_member(fd: int, info: zipfile.ZipInfo, start: int, header: int, npy: _Npy) -> int:
    """Read a stored member's array bytes (``header`` bytes past its ``start``: the npy
    header) straight into its buffer, and check the member's CRC-32 as zipfile does; the
    count of array bytes read."""
    view = npy.flat.view(np.uint8).data
    got = 0
    while got < len(view):
        n = os.preadv(fd, [view[got:]], start + header + got)
        if n <= 0:
            break
        got += n
    crc = zlib.crc32(os.pread(fd, header, start))
    crc = zlib.crc32(view[:got], crc)
    position, end = start + header + got, start + info.file_size
    while position < end:  # bytes past the array (none in a file numpy wrote), a block at a time
        block = os.pread(fd, min(READ_BLOCK, end - position), position)
        if not block:
            break
        crc = zlib.crc32(block, crc)
        position += len(block)
    if got == len(view) and crc != info.CRC:
        raise FormatError("bad CRC-32: the file is damaged", where=npy.where)
    return got


READ_BLOCK = 1 << 20
"""Bytes of an npz member decompressed at a time into its array."""
READ_THREADS = 2
"""Stored members of a local file read at once (the copy from the page cache is bound by
fresh pages: two threads read a 1.28 GB checkpoint in about half the time of one)."""
LOCAL_HEADER_SIZE = 30
"""Bytes of a zip local file header before its name and extra field."""
LOCAL_HEADER_MAGIC = b"PK\x03\x04"


def _read_into(f: IO[bytes], out: npt.NDArray[np.uint8]) -> int:
    """Fill ``out`` from ``f`` a block at a time (a member is never held twice; ``readinto``
    writes straight into it: 900 MB 1.2-1.9 s -> 0.4-0.8 s); the count."""
    view = out.data
    got = 0
    while got < out.size:
        n = f.readinto(view[got : got + READ_BLOCK])  # type: ignore[attr-defined]
        if not n:
            break
        got += n
    return got


# --- shared ----------------------------------------------------------------------------------


def _scene_length(scene_length_s: float | None) -> float:
    """Seconds in one normalised time unit (1.0 when not given)."""
    if scene_length_s is None:
        return 1.0
    ok = isinstance(scene_length_s, int | float) and math.isfinite(scene_length_s)
    if not (ok and scene_length_s > 0):
        raise InputError(
            f"must be a positive number, got {scene_length_s!r}", where="scene_length_s"
        )
    return float(scene_length_s)


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
    length = _scene_length(scene_length_s)
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
    if scene_length_s is None:
        notes.append("time is normalised to [0, 1]: 1 unit read as 1.0 s (scene_length_s)")
    kept = gaussians if keep.all() else gaussians.subset(keep)  # no copy when all are kept
    return Loaded4D(Scene(kept, timeline, temporal), notes)


__all__ = [
    "is_freetimegs_npz",
    "is_freetimegs_ply",
    "parse_freetimegs_npz",
    "parse_freetimegs_ply",
    "sniff_freetimegs_npz",
    "zip_members",
]
