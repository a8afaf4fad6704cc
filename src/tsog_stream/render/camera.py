"""Pinhole cameras for the CPU renderer: the 3DGS ``cameras.json`` and generated orbits.

Convention (the 3DGS / COLMAP / OpenCV one): camera x right, y down, z forward;
``world_to_camera`` maps world points to that frame. ``cx``/``cy`` are measured with the image
spanning [0, width] x [0, height] (pixel i covers [i, i + 1)), so a centred camera has
``cx = width / 2``; the rasterizer evaluates pixel *indices* (see docs/design/renderer.md).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import FormatError, InputError, SourceError
from ..model import Gaussians

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Camera:
    """A pinhole camera: image size, intrinsics in pixels and a (4, 4) world-to-camera matrix."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: F64
    name: str = ""

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and math.isfinite(self.fx * self.fy)):
            raise InputError(f"focal lengths must be positive, got fx={self.fx} fy={self.fy}")
        w2c = np.array(self.world_to_camera, dtype=np.float64)
        if w2c.shape != (4, 4) or not np.all(np.isfinite(w2c)):
            raise InputError(f"world_to_camera must be a finite (4, 4) matrix, got {w2c.shape}")
        if not np.array_equal(w2c[3], [0.0, 0.0, 0.0, 1.0]) or abs(np.linalg.det(w2c)) < 1e-12:
            raise InputError(
                "world_to_camera must be an invertible affine matrix (last row 0 0 0 1)"
            )
        w2c.setflags(write=False)
        object.__setattr__(self, "world_to_camera", w2c)

    def __eq__(self, other: object) -> bool:
        """Equal when every field is (the matrix compared element by element)."""
        if not isinstance(other, Camera):
            return NotImplemented
        mine = (self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.name)
        theirs = (other.width, other.height, other.fx, other.fy, other.cx, other.cy, other.name)
        return mine == theirs and np.array_equal(self.world_to_camera, other.world_to_camera)

    def __hash__(self) -> int:
        """A hash consistent with ``__eq__`` (so cameras can key caches)."""
        scalars = (self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.name)
        return hash((scalars, self.world_to_camera.tobytes()))

    @property
    def position(self) -> F64:
        """The camera centre in world coordinates (-R^-1 t; -R^T t for a rigid transform)."""
        rot = self.world_to_camera[:3, :3]
        return np.asarray(np.linalg.solve(rot, -self.world_to_camera[:3, 3]), dtype=np.float64)

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera rendering ``width`` x ``height`` pixels (intrinsics scaled per axis)."""
        sx, sy = width / self.width, height / self.height
        return Camera(
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            self.cx * sx,
            self.cy * sy,
            self.world_to_camera,
            self.name,
        )


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike) -> F64:
    """World-to-camera matrix of a camera at ``eye`` looking at ``target`` (y down, z forward)."""
    eye_v = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye_v
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise InputError("the camera position equals its target")
    forward /= norm
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise InputError("the view direction is parallel to the up vector")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([right, down, forward])
    w2c[:3, 3] = -w2c[:3, :3] @ eye_v
    return w2c


def orbit_cameras(
    center: npt.ArrayLike,
    radius: float,
    count: int,
    width: int,
    height: int,
    *,
    fov_deg: float = 50.0,
    elevation_deg: float = 20.0,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> list[Camera]:
    """``count`` cameras evenly spaced on a circle around ``center``, all looking at it.

    ``fov_deg`` is the field of view across the smaller image side (square pixels, centred
    principal point); ``elevation_deg`` lifts the circle above the plane normal to ``up``.
    """
    if count < 1:
        raise InputError(f"need at least one camera, got {count}")
    if not (radius > 0 and math.isfinite(radius)):
        raise InputError(f"orbit radius must be positive and finite, got {radius}")
    if not 0 < fov_deg < 180:
        raise InputError(f"field of view must be in (0, 180) degrees, got {fov_deg}")
    c = np.asarray(center, dtype=np.float64).reshape(3)
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    a = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    focal = 0.5 * min(width, height) / math.tan(math.radians(fov_deg) / 2)
    elev = math.radians(elevation_deg)
    cams = []
    for k in range(count):
        phi = 2 * math.pi * k / count
        offset = math.cos(elev) * (math.cos(phi) * a + math.sin(phi) * b) + math.sin(elev) * u
        w2c = look_at(c + radius * offset, c, u)
        cams.append(Camera(width, height, focal, focal, width / 2, height / 2, w2c, f"orbit{k}"))
    return cams


def scene_orbit(
    gaussians: Gaussians,
    count: int,
    width: int,
    height: int,
    *,
    fov_deg: float = 50.0,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> list[Camera]:
    """An orbit around the median of the means, close enough that the scene's bulk fills the view.

    The scene radius is the 90th percentile of the distances to the median (robust to floaters);
    the camera distance fits that sphere into ``fov_deg`` with a 10 % margin.
    """
    if len(gaussians) == 0:
        raise InputError("cannot frame an empty scene")
    means = gaussians.means.astype(np.float64)
    center = np.median(means, axis=0)
    extent = float(np.percentile(np.linalg.norm(means - center, axis=1), 90))
    extent = max(extent, 1e-6)
    distance = 1.1 * extent / math.sin(math.radians(fov_deg) / 2)
    return orbit_cameras(center, distance, count, width, height, fov_deg=fov_deg, up=up)


def _field(entry: dict[str, Any], key: str, shape: tuple[int, ...], where: str) -> F64:
    """``entry[key]`` as a finite float64 array of ``shape`` or a FormatError naming the field."""
    if key not in entry:
        raise FormatError(f"missing field '{key}'", where=where)
    try:
        value = np.array(entry[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FormatError(f"field '{key}' is not numeric", where=where) from exc
    if value.shape != shape or not np.all(np.isfinite(value)):
        raise FormatError(f"field '{key}' must be finite numbers of shape {shape}", where=where)
    return value


def _json_camera(entry: object, where: str, width: int | None, height: int | None) -> Camera:
    """One cameras.json entry, its intrinsics scaled to the requested size."""
    if not isinstance(entry, dict):
        raise FormatError("each camera must be a JSON object", where=where)
    w0, h0 = float(_field(entry, "width", (), where)), float(_field(entry, "height", (), where))
    fx, fy = float(_field(entry, "fx", (), where)), float(_field(entry, "fy", (), where))
    if w0 <= 0 or h0 <= 0 or fx <= 0 or fy <= 0:
        raise FormatError("width, height, fx and fy must be positive", where=where)
    position = _field(entry, "position", (3,), where)
    rotation = _field(entry, "rotation", (3, 3), where)  # camera-to-world
    w = width if width is not None else round(w0 * height / h0) if height is not None else int(w0)
    h = height if height is not None else round(h0 * w / w0)
    w2c = np.eye(4)
    w2c[:3, :3] = rotation.T
    w2c[:3, 3] = -rotation.T @ position
    name = str(entry.get("img_name", entry.get("id", "")))
    return Camera(w, h, fx * w / w0, fy * h / h0, w / 2, h / 2, w2c, name)


def load_cameras_json(
    path: str | os.PathLike[str], width: int | None = None, height: int | None = None
) -> list[Camera]:
    """The cameras of a 3DGS ``cameras.json``, scaled to ``width`` x ``height``.

    When only one of them is given the other keeps each camera's aspect ratio; when neither is,
    the file's own sizes are used. The principal point is the image centre, as in 3DGS.
    """
    for label, value in (("width", width), ("height", height)):
        if value is not None and value <= 0:
            raise InputError(f"{label} must be positive, got {value}")
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"cannot read the cameras file: {exc}", where=str(path)) from exc
    try:
        entries = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(f"not valid JSON: {exc}", where=str(path)) from exc
    if not isinstance(entries, list) or not entries:
        raise FormatError("expected a non-empty JSON list of cameras", where=str(path))
    return [_json_camera(e, f"{path}[{i}]", width, height) for i, e in enumerate(entries)]
