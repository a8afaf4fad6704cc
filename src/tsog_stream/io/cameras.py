"""Capture cameras from the files trainers leave: 3DGS ``cameras.json`` and COLMAP models.

A COLMAP model is ``cameras`` (intrinsics) plus ``images`` (one pose per registered image),
both ``.txt`` or both ``.bin``, usually in ``sparse/0``. Each COLMAP camera is read as a
:class:`~tsog_stream.schemas.cameras.Camera` standing at the origin; each pose
(world-to-camera quaternion w, x, y, z and translation) places its camera (camera centre and
camera-to-world rotation), in image-name order as 3DGS orders them. Lens distortion is not
kept (the renderers are pinhole). Every count and length is checked against the bytes left
before anything is allocated; the 2D points of ``images`` are skipped, never held.

:func:`find_cameras` looks where trainers put them, beside an input: its folder, its
``sparse/0``, and for a 3DGS output PLY (``<model>/point_cloud/iteration_N/point_cloud.ply``)
the model folder.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Final

import numpy as np

from ..constants import MAX_CAMERA_FILE_BYTES, MAX_CAMERA_SIDE, MAX_CAMERAS
from ..errors import FormatError, InputError, SourceError
from ..schemas.cameras import Camera, HeaderCamera, cameras_from_json
from .files import open_regular, read_head
from .splatv import read_splatv_cameras

COLMAP_MODELS: Final[dict[int, tuple[str, int]]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
"""COLMAP camera model id -> (name, parameter count); the first parameters are f, cx, cy
(one focal length) or fx, fy, cx, cy."""
ONE_FOCAL: Final = frozenset(
    {"SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"}
)
MAX_IMAGES: Final = 1_000_000
"""Most registered images a COLMAP model may declare (the largest public ones hold ~100k)."""
MAX_NAME_BYTES: Final = 4096
MAX_LINE_BYTES: Final = 1 << 20
"""A text line longer than this (a 2D-points line of a huge image) is skipped in pieces."""
MAX_JSON_BYTES_PER_CAMERA: Final = 4096
"""Most bytes one camera of a 3DGS ``cameras.json`` takes: its eight keys and twelve numbers
take 300-600 bytes, pretty-printed about 900."""
MAX_CAMERAS_JSON_BYTES: Final = MAX_CAMERAS * MAX_JSON_BYTES_PER_CAMERA
"""Largest ``cameras.json`` read (16 MiB, checked before reading): the most cameras a scene
carries at the most bytes each. JSON parses to at most ~25x its bytes."""
_JSON_SPACE: Final = re.compile(r"[ \t\n\r]*")
CAMERA_RECORD: Final = struct.Struct("<iiQQ")
IMAGE_RECORD: Final = struct.Struct("<i7di")
POINT2D_BYTES: Final = 24
COUNT: Final = struct.Struct("<Q")
AT_ORIGIN: Final = ((0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))
"""(position, rotation) of a COLMAP camera before an image places it."""


@dataclass(frozen=True)
class FoundCameras:
    """Cameras read from a file, where they came from, and what was left out."""

    cameras: list[Camera]
    source: str
    notes: list[str]


def read_cameras(path: str | os.PathLike[str]) -> FoundCameras:
    """The cameras of a ``cameras.json``, a COLMAP model (its folder, a folder holding
    ``sparse/0``, or its ``cameras``/``images`` file) or a ``.splatv``."""
    p = Path(path)
    if p.is_dir():
        model = _colmap_folder(p)
        if model is None:
            raise InputError(
                "expected cameras.json, or COLMAP cameras and images (.txt or .bin) here or in "
                "sparse/0",
                where=str(p),
            )
        return model
    if p.suffix.lower() in (".bin", ".txt") and p.stem in ("cameras", "images"):
        model = _colmap_folder(p.parent)
        if model is None:
            raise InputError(f"found no matching COLMAP cameras/images beside {p.name}")
        return model
    if p.suffix.lower() == ".splatv":
        return _splatv_cameras(p)
    data = _read_limited(p, MAX_CAMERAS_JSON_BYTES)
    return FoundCameras(parse_cameras_json(data, where=str(p)), str(p), [])


def find_cameras(input_path: str | os.PathLike[str]) -> FoundCameras | None:
    """The capture cameras beside an input, or None (see the module docstring for where)."""
    p = Path(input_path)
    if "*" in str(p) or "?" in str(p):
        p = p.parent
    folders = [p] if p.is_dir() else [p.parent]
    if not p.is_dir() and p.parent.name.startswith("iteration_"):
        folders.append(p.parent.parent.parent)  # <model>/point_cloud/iteration_N/x.ply
    for folder in folders:
        json_path = folder / "cameras.json"
        if json_path.is_file():
            return read_cameras(json_path)
        model = _colmap_folder(folder)
        if model is not None:
            return model
    return None


def parse_cameras_json(data: bytes, *, where: str) -> list[Camera]:
    """The cameras of a 3DGS ``cameras.json`` held in memory: a JSON list parsed an entry at
    a time, refused at its MAX_CAMERAS + 1st entry (parsed whole, a few MB of ``{}`` entries
    take gigabytes first)."""
    try:
        entries = _json_list(data.decode("utf-8"), MAX_CAMERAS, where)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise FormatError(f"not valid UTF-8 JSON: {exc}", where=where) from None
    return cameras_from_json(entries, where=where)


def _json_list(text: str, most: int, where: str) -> Any:
    """The JSON value of ``text``; a top-level list is parsed an entry at a time and refused
    past ``most`` entries, before the rest is parsed (ValueError where it is not JSON)."""
    decoder = json.JSONDecoder()
    at = _skip_space(text, 0)
    if not text.startswith("[", at):
        value, end = decoder.raw_decode(text, at)
        if _skip_space(text, end) != len(text):
            raise ValueError(f"extra data at character {end}")
        return value
    entries: list[Any] = []
    at = _skip_space(text, at + 1)
    while not text.startswith("]", at):
        if len(entries) == most:
            raise FormatError(f"more than the {most} cameras a scene may carry", where=where)
        entry, at = decoder.raw_decode(text, at)
        entries.append(entry)
        at = _skip_space(text, at)
        if text.startswith(",", at):
            at = _skip_space(text, at + 1)
            if text.startswith("]", at):
                raise ValueError(f"expected a value after ',' at character {at}")
        elif not text.startswith("]", at):
            raise ValueError(f"expected ',' or ']' at character {at}")
    if _skip_space(text, at + 1) != len(text):
        raise ValueError(f"extra data at character {at + 1}")
    return entries


def _skip_space(text: str, at: int) -> int:
    """The index of the first character at or after ``at`` that is not JSON whitespace."""
    space = _JSON_SPACE.match(text, at)
    return space.end() if space is not None else at


def _read_limited(path: Path, limit: int = MAX_CAMERA_FILE_BYTES) -> bytes:
    """A camera file's bytes, refused before reading when over ``limit`` (and read at most
    ``limit + 1`` bytes, should it grow meanwhile)."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise SourceError(f"cannot read the cameras: {exc.strerror}", where=str(path)) from None
    data = b"" if size > limit else read_head(path, size + 1)
    if size > limit or len(data) > limit:
        raise FormatError(
            f"{max(size, len(data))} bytes, more than the {limit} a camera file may hold",
            where=str(path),
        )
    return data


def _splatv_cameras(path: Path) -> FoundCameras:
    """The cameras a .splatv header carries."""
    cameras, notes = read_splatv_cameras(path)
    if not cameras:
        raise InputError("the .splatv file carries no cameras", where=str(path))
    return FoundCameras(cameras, str(path), notes)


def _colmap_folder(folder: Path) -> FoundCameras | None:
    """The COLMAP model in ``folder`` or ``folder/sparse/0`` (binary preferred), or None."""
    for base in (folder, folder / "sparse" / "0"):
        for ext in (".bin", ".txt"):
            cams, imgs = base / f"cameras{ext}", base / f"images{ext}"
            if cams.is_file() and imgs.is_file():
                return read_colmap(cams, imgs)
    return None


def read_colmap(cameras_path: Path, images_path: Path) -> FoundCameras:
    """A COLMAP model's registered images as capture cameras, in image-name order; a model of
    more than MAX_CAMERAS images keeps that many, evenly spread."""
    binary = cameras_path.suffix.lower() == ".bin"
    if binary:
        with open_regular(cameras_path) as f:
            intrinsics = parse_colmap_cameras_bin(f, where=str(cameras_path))
        with open_regular(images_path) as f:
            poses = list(parse_colmap_images_bin(f, where=str(images_path)))
    else:
        text = _read_limited(cameras_path).decode("utf-8", errors="replace")
        intrinsics = parse_colmap_cameras_text(text, where=str(cameras_path))
        with open_regular(images_path) as f:
            poses = list(parse_colmap_images_text(f, where=str(images_path)))
    notes = []
    poses.sort(key=lambda pose: pose.name)
    if len(poses) > MAX_CAMERAS:
        picks = np.linspace(0, len(poses) - 1, MAX_CAMERAS).round().astype(int)
        notes.append(f"{len(poses)} images: kept {MAX_CAMERAS} cameras, evenly spread")
        poses = [poses[i] for i in picks]
    cameras = [pose.camera(intrinsics, where=str(images_path)) for pose in poses]
    if not cameras:
        raise FormatError("the COLMAP model has no registered images", where=str(images_path))
    return FoundCameras(cameras, str(cameras_path.parent), notes)


@dataclass(frozen=True)
class Pose:
    """One registered COLMAP image: name, camera id, world-to-camera quaternion and translation."""

    name: str
    camera_id: int
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]

    def camera(self, intrinsics: dict[int, Camera], *, where: str) -> Camera:
        """``intrinsics``' camera of this image, placed where the image was taken."""
        k = intrinsics.get(self.camera_id)
        if k is None:
            raise FormatError(
                f"image {self.name!r} names unknown camera {self.camera_id}", where=where
            )
        norm = math.sqrt(sum(q * q for q in self.qvec))
        if not (math.isfinite(norm) and norm > 1e-9) or not all(map(math.isfinite, self.tvec)):
            raise FormatError(f"image {self.name!r} has a non-finite or zero pose", where=where)
        w2c = _quat_to_matrix(np.array(self.qvec) / norm)
        c2w = w2c.T
        centre = -c2w @ np.array(self.tvec)
        try:
            return Camera(
                name=self.name[:255],
                width=k.width,
                height=k.height,
                fx=k.fx,
                fy=k.fy,
                cx=k.cx,
                cy=k.cy,
                position=(float(centre[0]), float(centre[1]), float(centre[2])),
                rotation=tuple(tuple(float(v) for v in row) for row in c2w),
            )
        except ValueError as exc:
            raise FormatError(f"image {self.name!r}: {exc}", where=where) from None


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _intrinsics(model: str, width: int, height: int, params: list[float], where: str) -> Camera:
    """The pinhole part of a COLMAP camera's parameters, the camera standing at the origin."""
    if not all(map(math.isfinite, params)):
        raise FormatError(f"{model} camera has non-finite parameters", where=where)
    if model in ONE_FOCAL:
        f, cx, cy = params[:3]
        fx = fy = f
    else:
        fx, fy, cx, cy = params[:4]
    if not (0 < width <= MAX_CAMERA_SIDE and 0 < height <= MAX_CAMERA_SIDE and fx > 0 and fy > 0):
        raise FormatError(f"{model} camera has a bad size or focal length", where=where)
    position, rotation = AT_ORIGIN
    return Camera(
        width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy, position=position, rotation=rotation
    )


def parse_colmap_cameras_text(text: str, *, where: str) -> dict[int, Camera]:
    """``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`` per line, ``#`` comments."""
    by_name = {name: count for name, count in COLMAP_MODELS.values()}
    out: dict[int, Camera] = {}
    lines = io.StringIO(text, newline=None)  # a line at a time, never a list of them
    for number, line in enumerate(lines, 1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        at = f"{where}:{number}"
        if len(fields) < 4 or fields[1] not in by_name:
            raise FormatError("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...", where=at)
        model, count = fields[1], by_name[fields[1]]
        if len(fields) != 4 + count:
            raise FormatError(
                f"{model} takes {count} parameters, found {len(fields) - 4}", where=at
            )
        try:
            cid, width, height = int(fields[0]), int(fields[2]), int(fields[3])
            params = [float(v) for v in fields[4:]]
        except ValueError:
            raise FormatError("expected numbers", where=at) from None
        out[cid] = _intrinsics(model, width, height, params, at)
        if len(out) > MAX_IMAGES:
            raise FormatError(f"more than {MAX_IMAGES} cameras", where=where)
    return out


def _lines(f: BinaryIO) -> Iterator[bytes]:
    """The lines of a text file, each cut at MAX_LINE_BYTES (the rest of a longer line is read
    and dropped in pieces, so a huge 2D-points line never sits in memory)."""
    while True:
        line = f.readline(MAX_LINE_BYTES)
        if not line:
            return
        if not line.endswith(b"\n") and len(line) == MAX_LINE_BYTES:
            while (rest := f.readline(MAX_LINE_BYTES)) and not rest.endswith(b"\n"):
                pass
        yield line


def parse_colmap_images_text(f: BinaryIO, *, where: str) -> Iterator[Pose]:
    """``images.txt``: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then a 2D-points line."""
    expect_pose = True
    count = 0
    for number, raw in enumerate(_lines(f), 1):
        line = raw.decode("utf-8", errors="replace").strip()
        if line.startswith("#"):
            continue
        if not expect_pose:
            expect_pose = True
            continue
        if not line:
            continue
        fields = line.split(maxsplit=9)
        if len(fields) != 10:
            raise FormatError(
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", where=f"{where}:{number}"
            )
        try:
            q = tuple(float(v) for v in fields[1:5])
            t = tuple(float(v) for v in fields[5:8])
            camera_id = int(fields[8])
        except ValueError:
            raise FormatError("expected numbers", where=f"{where}:{number}") from None
        count += 1
        if count > MAX_IMAGES:
            raise FormatError(f"more than {MAX_IMAGES} images", where=where)
        yield Pose(fields[9], camera_id, q, t)  # type: ignore[arg-type]
        expect_pose = False


def _read_exactly(f: BinaryIO, size: int, where: str) -> bytes:
    data = f.read(size)
    if len(data) != size:
        raise FormatError(f"ends early: expected {size} more bytes, found {len(data)}", where=where)
    return data


def _remaining(f: BinaryIO) -> int:
    """Bytes left after the file position."""
    here = f.tell()
    end = f.seek(0, os.SEEK_END)
    f.seek(here)
    return end - here


def parse_colmap_cameras_bin(f: BinaryIO, *, where: str) -> dict[int, Camera]:
    """``cameras.bin``: uint64 count, then per camera int32 id, int32 model, uint64 width,
    uint64 height and the model's float64 parameters."""
    (count,) = COUNT.unpack(_read_exactly(f, COUNT.size, where))
    if count > min(MAX_IMAGES, _remaining(f) // CAMERA_RECORD.size):
        raise FormatError(f"declares {count} cameras, more than its bytes can hold", where=where)
    out: dict[int, Camera] = {}
    for _ in range(count):
        cid, model_id, width, height = CAMERA_RECORD.unpack(
            _read_exactly(f, CAMERA_RECORD.size, where)
        )
        if model_id not in COLMAP_MODELS:
            raise FormatError(f"camera {cid} has unknown model id {model_id}", where=where)
        model, params = COLMAP_MODELS[model_id]
        values = list(struct.unpack(f"<{params}d", _read_exactly(f, 8 * params, where)))
        out[cid] = _intrinsics(model, width, height, values, where)
    return out


def parse_colmap_images_bin(f: BinaryIO, *, where: str) -> Iterator[Pose]:
    """``images.bin``: uint64 count, then per image int32 id, float64 qw qx qy qz tx ty tz,
    int32 camera id, a NUL-terminated name, uint64 point count and 24 bytes per 2D point
    (skipped)."""
    (count,) = COUNT.unpack(_read_exactly(f, COUNT.size, where))
    if count > min(MAX_IMAGES, _remaining(f) // (IMAGE_RECORD.size + 1 + COUNT.size)):
        raise FormatError(f"declares {count} images, more than its bytes can hold", where=where)
    for _ in range(count):
        record = IMAGE_RECORD.unpack(_read_exactly(f, IMAGE_RECORD.size, where))
        name = _read_name(f, where)
        (points,) = COUNT.unpack(_read_exactly(f, COUNT.size, where))
        if points > _remaining(f) // POINT2D_BYTES:
            raise FormatError(f"image {name!r} declares {points} points past the end", where=where)
        f.seek(points * POINT2D_BYTES, os.SEEK_CUR)
        yield Pose(name, record[8], record[1:5], record[5:8])


def _read_name(f: BinaryIO, where: str) -> str:
    """A NUL-terminated UTF-8 name of at most MAX_NAME_BYTES."""
    out = bytearray()
    while True:
        byte = f.read(1)
        if not byte:
            raise FormatError("ends inside an image name", where=where)
        if byte == b"\0":
            return out.decode("utf-8", errors="replace")
        out += byte
        if len(out) > MAX_NAME_BYTES:
            raise FormatError(f"an image name longer than {MAX_NAME_BYTES} bytes", where=where)


def cameras_for_input(
    input_path: str | os.PathLike[str],
    *,
    explicit: str | os.PathLike[str] | None = None,
    own: list[Camera] | None = None,
) -> FoundCameras | None:
    """The cameras an input goes with: ``explicit`` (``--cameras``; its errors are the
    caller's), else those the input carries (``own``, a format's header: marked as
    :class:`HeaderCamera`), else those found beside it (one that cannot be read is noted and
    left out: the scene does not depend on it)."""
    if explicit is not None:
        return read_cameras(explicit)
    if own:
        header: list[Camera] = [HeaderCamera.of(camera) for camera in own]
        return FoundCameras(header, f"{os.fspath(input_path)} (its own)", [])
    try:
        return find_cameras(input_path)
    except (FormatError, SourceError, InputError) as exc:
        return FoundCameras([], "", [f"ignored the cameras beside the input: {exc}"])
