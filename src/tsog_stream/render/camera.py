"""Pinhole cameras for the CPU renderer: capture cameras (3DGS ``cameras.json``, COLMAP,
``.splatv``) and generated orbits.

Convention (the 3DGS / COLMAP / OpenCV one): camera x right, y down, z forward;
``world_to_camera`` maps world points to that frame. ``cx``/``cy`` are measured with the image
spanning [0, width] x [0, height] (pixel i covers [i, i + 1)), so a centred camera has
``cx = width / 2``; the rasterizer evaluates pixel *indices* (see docs/design/renderer.md).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..framing import look_at, world_to_camera
from ..io.cameras import read_cameras
from ..model import Gaussians
from ..schemas.cameras import CaptureCamera

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


def load_cameras_json(
    path: str | os.PathLike[str], width: int | None = None, height: int | None = None
) -> list[Camera]:
    """The cameras of a camera file (3DGS ``cameras.json``, COLMAP model, ``.splatv``: see
    :func:`tsog_stream.io.cameras.read_cameras`), scaled to ``width`` x ``height``.

    When only one of them is given the other keeps each camera's aspect ratio; when neither is,
    the file's own sizes are used. Intrinsics scale per axis, as 3DGS's evaluation does.
    """
    for label, value in (("width", width), ("height", height)):
        if value is not None and value <= 0:
            raise InputError(f"{label} must be positive, got {value}")
    return [stretched(c, width, height) for c in read_cameras(path).cameras]


def _size(capture: CaptureCamera, width: int | None, height: int | None) -> tuple[int, int]:
    """The requested size, a missing side following the capture's aspect ratio."""
    if width is None and height is None:
        return capture.width, capture.height
    if width is None:
        assert height is not None
        return max(1, round(capture.width * height / capture.height)), height
    if height is None:
        return width, max(1, round(capture.height * width / capture.width))
    return width, height


def from_capture(capture: CaptureCamera, width: int | None, height: int | None = None) -> Camera:
    """A capture camera drawing ``width`` x ``height`` pixels as a player's window shows it:
    the vertical field of view kept, square pixels, the principal point moved with the centre
    (a window wider than the capture sees more at the sides). A side left None follows the
    capture's aspect ratio (both None: the capture's size)."""
    w, h = _size(capture, width, height)
    scale = h / capture.height
    cx, cy = capture.principal_point
    return Camera(
        w,
        h,
        capture.fx * scale,
        capture.fy * scale,
        w / 2 + (cx - capture.width / 2) * scale,
        h / 2 + (cy - capture.height / 2) * scale,
        world_to_camera(capture),
        capture.name,
    )


def stretched(capture: CaptureCamera, width: int | None, height: int | None) -> Camera:
    """A capture camera scaled per axis to ``width`` x ``height`` (3DGS evaluation style)."""
    w, h = _size(capture, width, height)
    sx, sy = w / capture.width, h / capture.height
    cx, cy = capture.principal_point
    w2c = world_to_camera(capture)
    return Camera(w, h, capture.fx * sx, capture.fy * sy, cx * sx, cy * sy, w2c, capture.name)
