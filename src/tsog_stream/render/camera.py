"""What the renderer may draw with a :class:`~tsog_stream.schemas.cameras.Camera` (the one
camera type): cameras of a file sized for a picture and held to the rasterizer's budgets
(:func:`from_capture`, :func:`stretched`), :func:`check_drawable` for any other, and orbits.

Convention (the 3DGS / COLMAP / OpenCV one): camera x right, y down, z forward;
:func:`~tsog_stream.framing.world_to_camera` maps world points to that frame. ``cx``/``cy`` are
measured with the image spanning [0, width] x [0, height] (pixel i covers [i, i + 1)), so a
centred camera has ``cx = width / 2``; the rasterizer evaluates pixel *indices* (see
docs/design/renderer.md).
"""

from __future__ import annotations

import math
import os
from typing import Final

import numpy as np
import numpy.typing as npt

from ..constants import RENDER_MAX_SIDE
from ..errors import InputError
from ..framing import look_at, vec3
from ..io.cameras import read_cameras
from ..model import Gaussians
from ..schemas.cameras import Camera as Camera  # noqa: PLC0414 - re-exported for callers

RENDER_MAX_PIXELS: Final = 4096 * 4096
"""Most pixels one image may have (any camera; explicit sizes over it are refused, sizes
taken from a camera file shrunk to fit): the rasterizer holds about 60 bytes a pixel."""
DEFAULT_PIXELS: Final = 1280 * 720
"""Most pixels of an image whose size nobody gave (``tsog render``'s 640-wide default,
shrunk when the camera's shape would make it taller)."""
MAX_ASPECT: Final = 8.0
"""Longest image side over its shortest, at most (1:8 to 8:1): a camera file's stranger
shape is narrowed to it, its field of view kept."""
FOCAL_PER_SIDE: Final = (0.02, 50.0)
"""Focal length over the image side it spans, at least and at most: a field of view across
that side from 1.1 to 175 degrees (a camera file's focal lengths are held to it)."""


def check_drawable(camera: Camera) -> None:
    """Refuse a camera the rasterizer must not draw: its size (:func:`check_image_size`) and
    focal lengths outside :data:`FOCAL_PER_SIDE` of the sides they span. :func:`from_capture`
    and :func:`stretched` hold a camera file's values inside them; a camera made by hand is
    checked here, before any pixel is allocated."""
    check_image_size(camera.width, camera.height)
    lo, hi = FOCAL_PER_SIDE
    w, h, fx, fy = camera.width, camera.height, camera.fx, camera.fy
    if not (lo * w <= fx <= hi * w and lo * h <= fy <= hi * h):
        raise InputError(
            f"focal lengths must be {lo:g} to {hi:g} times the image side they span, got "
            f"fx={fx} fy={fy} for {w}x{h}"
        )


def check_image_size(width: int, height: int, *, where: str | None = None) -> None:
    """Refuse an image size the renderer must not allocate: sides 1 to RENDER_MAX_SIDE,
    at most :data:`RENDER_MAX_PIXELS` pixels, no longer than :data:`MAX_ASPECT` times wide
    or tall."""
    size = f"{width}x{height}"
    if not (1 <= width <= RENDER_MAX_SIDE and 1 <= height <= RENDER_MAX_SIDE):
        raise InputError(f"image sides must be 1-{RENDER_MAX_SIDE} pixels, got {size}", where=where)
    if width * height > RENDER_MAX_PIXELS:
        raise InputError(
            f"{size} is {width * height} pixels, more than the {RENDER_MAX_PIXELS} an image "
            "may have",
            where=where,
        )
    if max(width, height) > MAX_ASPECT * min(width, height):
        raise InputError(
            f"{size} is more than {MAX_ASPECT:g} times as wide as tall or as tall as wide",
            where=where,
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
    check_image_size(width, height)
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
        eye = c + radius * offset
        c2w = look_at(eye, c, u)[:3, :3].T
        rotation = (vec3(c2w[0]), vec3(c2w[1]), vec3(c2w[2]))
        cams.append(
            Camera(
                name=f"orbit{k}",
                width=width,
                height=height,
                fx=focal,
                fy=focal,
                position=vec3(eye),
                rotation=rotation,
            )
        )
    check_drawable(cams[0])
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
    the file's own sizes are used (either way within :data:`MAX_ASPECT` and
    :data:`RENDER_MAX_PIXELS`). Intrinsics scale per axis, as 3DGS's evaluation does.
    """
    for label, value in (("width", width), ("height", height)):
        if value is not None and value <= 0:
            raise InputError(f"{label} must be positive, got {value}")
    return [stretched(c, width, height) for c in read_cameras(path).cameras]


def _size(capture: Camera, width: int | None, height: int | None, budget: int) -> tuple[int, int]:
    """The requested size. A side left None follows the capture's aspect ratio, held within
    :data:`MAX_ASPECT`, and such a size is shrunk, its shape kept, to ``budget`` pixels
    (both None: the capture's own size, held the same way); a size given whole is the
    caller's, checked by :func:`check_drawable`."""
    for label, value in (("width", width), ("height", height)):
        if value is not None and value < 1:
            raise InputError(f"{label} must be positive, got {value}")
    if width is not None and height is not None:
        return width, height
    shape_w = min(capture.width, MAX_ASPECT * capture.height)
    shape_h = min(capture.height, MAX_ASPECT * capture.width)
    if width is not None:
        w, h = float(width), width * shape_h / shape_w
    elif height is not None:
        w, h = height * shape_w / shape_h, float(height)
    else:
        w, h = shape_w, shape_h
    scale = min(1.0, math.sqrt(budget / (w * h)))
    return _bounded(max(1, round(w * scale)), max(1, round(h * scale)), budget)


def _bounded(width: int, height: int, budget: int) -> tuple[int, int]:
    """``width`` x ``height`` with the longer side trimmed until the shape is within
    :data:`MAX_ASPECT` and the pixels within ``budget`` (rounding can leave either a pixel
    over)."""
    width = min(width, int(MAX_ASPECT * height), RENDER_MAX_SIDE)
    height = min(height, int(MAX_ASPECT * width), RENDER_MAX_SIDE)
    while width * height > budget:
        if width >= height:
            width -= 1
        else:
            height -= 1
    return width, height


def _sane(focal: float, centre: float, side: int) -> tuple[float, float]:
    """A focal length held to :data:`FOCAL_PER_SIDE` of ``side`` and a principal point held
    inside the image (a camera file's values may be anything finite)."""
    lo, hi = FOCAL_PER_SIDE
    return min(max(focal, lo * side), hi * side), min(max(centre, 0.0), float(side))


def _drawn(
    capture: Camera, w: int, h: int, x: tuple[float, float], y: tuple[float, float]
) -> Camera:
    """``capture``'s pose and name drawing ``w`` x ``h`` pixels, with the (focal length,
    principal point) ``x`` and ``y`` held to sane values (:func:`_sane`); checked drawable."""
    (fx, cx), (fy, cy) = _sane(*x, w), _sane(*y, h)
    camera = Camera(
        name=capture.name,
        width=w,
        height=h,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        position=capture.position,
        rotation=capture.rotation,
    )
    check_drawable(camera)
    return camera


def from_capture(
    capture: Camera,
    width: int | None,
    height: int | None = None,
    *,
    budget: int = RENDER_MAX_PIXELS,
) -> Camera:
    """A capture camera drawing ``width`` x ``height`` pixels as a player's window shows it:
    the vertical field of view kept, square pixels, the principal point moved with the centre
    (a window wider than the capture sees more at the sides). A side left None follows the
    capture's aspect ratio (both None: the capture's size), within :data:`MAX_ASPECT` and
    ``budget`` pixels; the intrinsics are held to sane values (:func:`_sane`)."""
    w, h = _size(capture, width, height, budget)
    scale = h / capture.height
    cx, cy = capture.principal_point
    x = capture.fx * scale, w / 2 + (cx - capture.width / 2) * scale
    y = capture.fy * scale, h / 2 + (cy - capture.height / 2) * scale
    return _drawn(capture, w, h, x, y)


def stretched(
    capture: Camera,
    width: int | None,
    height: int | None,
    *,
    budget: int = RENDER_MAX_PIXELS,
) -> Camera:
    """A capture camera scaled per axis to ``width`` x ``height`` (3DGS evaluation style;
    sizes and intrinsics bounded as :func:`from_capture` bounds them)."""
    w, h = _size(capture, width, height, budget)
    sx, sy = w / capture.width, h / capture.height
    cx, cy = capture.principal_point
    return _drawn(capture, w, h, (capture.fx * sx, cx * sx), (capture.fy * sy, cy * sy))
