"""A CPU reference rasterizer for 3D Gaussians (3DGS, Kerbl et al. 2023), numpy or numba.

``render(gaussians, camera)`` returns an (H, W, 3) float32 RGB image. The conventions (pixel
centres, camera frame, SH, low-pass, antialiasing, early termination) are in
docs/design/renderer.md.
"""

from __future__ import annotations

import io
import os
from typing import Literal

import numpy as np
import numpy.typing as npt
from PIL import Image

from ..errors import InputError
from ..framing import look_at
from ..io.files import atomic_write_bytes
from ..model import Gaussians
from ..schemas.cameras import Camera
from . import raster_numba
from .camera import from_capture, load_cameras_json, orbit_cameras, scene_orbit
from .project import Projected, project
from .raster import bin_tiles, rasterize_numpy

Backend = Literal["auto", "numpy", "numba"]
F64 = npt.NDArray[np.float64]

__all__ = [
    "Backend",
    "Camera",
    "Projected",
    "draw",
    "from_capture",
    "load_cameras_json",
    "look_at",
    "numba_available",
    "orbit_cameras",
    "png_bytes",
    "project",
    "render",
    "save_png",
    "scene_orbit",
    "to_uint8",
    "warm",
]


def numba_available() -> bool:
    """True when the numba backend can be used (the ``render`` extra is installed)."""
    return raster_numba.available()


def render(
    gaussians: Gaussians,
    camera: Camera,
    *,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    antialiased: bool = False,
    backend: Backend = "auto",
) -> npt.NDArray[np.float32]:
    """Render ``gaussians`` seen by ``camera``: (H, W, 3) float32 RGB, not clipped.

    ``backend="auto"`` uses numba when it is installed, else numpy; both give the same image
    (identical in practice, tested to 1e-5). ``antialiased`` applies Mip-Splatting's 2D
    filter opacity compensation.
    """
    _drawing_options(background, backend)  # refused before any projecting
    proj = project(gaussians, camera, antialiased=antialiased)
    return draw(proj, camera, background=background, backend=backend)


def draw(
    proj: Projected,
    camera: Camera,
    *,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    backend: Backend = "auto",
    only: npt.NDArray[np.int64] | None = None,
) -> npt.NDArray[np.float32]:
    """The picture of Gaussians already projected for ``camera`` (what :func:`render` does
    after projecting); ``only``: of those rows alone, ties in depth drawn in the order given
    (:func:`raster.bin_tiles`), so several subsets of one projection are drawn without
    projecting or copying them again."""
    bg = _drawing_options(background, backend)
    bins = bin_tiles(proj, camera.width, camera.height, only)
    use_numba = backend == "numba" or (backend == "auto" and raster_numba.available())
    composite = raster_numba.rasterize_numba if use_numba else rasterize_numpy
    return composite(proj, bins, camera.width, camera.height, bg)


def _drawing_options(background: tuple[float, float, float], backend: Backend) -> F64:
    """The background as an array; InputError for an unknown or missing backend or a
    background that is not three finite numbers."""
    if backend not in ("auto", "numpy", "numba"):
        raise InputError(f"unknown backend {backend!r} (expected auto, numpy or numba)")
    if backend == "numba" and not raster_numba.available():
        raise InputError("the numba backend needs numba: pip install 'tsog-stream[render]'")
    bg = np.asarray(background, dtype=np.float64)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise InputError(f"background must be three finite numbers, got {background!r}")
    return bg


def warm() -> None:
    """Load the numba kernel now (its import and on-disk cache: about 1 s on first use) by
    drawing one Gaussian 16 pixels wide, so a picture drawn later starts at once; nothing
    without numba."""
    if not raster_numba.available():
        return
    one = Gaussians.from_arrays(
        np.zeros((1, 3)), np.full((1, 3), -1.0), [[1.0, 0, 0, 0]], [4.0], [[0.5, 0.5, 0.5]]
    )
    ahead = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # 4 units before it, looking on
    camera = Camera(
        width=16, height=16, fx=16.0, fy=16.0, position=(0.0, 0.0, -4.0), rotation=ahead
    )
    render(one, camera, backend="numba")


def to_uint8(image: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """An 8-bit image: round(clip(x, 0, 1) * 255)."""
    arr = np.asarray(image, dtype=np.float64)
    return np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)


def png_bytes(image: npt.ArrayLike) -> bytes:
    """An (H, W, 3) float or uint8 image as 8-bit PNG bytes."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) image, got shape {arr.shape}")
    pixels = arr if arr.dtype == np.uint8 else to_uint8(arr)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def save_png(image: npt.ArrayLike, path: str | os.PathLike[str]) -> None:
    """Write an (H, W, 3) float or uint8 image as an 8-bit PNG, atomically."""
    atomic_write_bytes(path, png_bytes(image))
