"""The numba compositor: the numpy path's maths as the reference's sequential per-pixel loop.

Optional (``pip install tsog-stream[render]``): without numba, :func:`available` is False.
"""

from __future__ import annotations

import functools
import importlib
import threading
from typing import Any

import numpy as np
import numpy.typing as npt

from .project import TILE, Projected
from .raster import ALPHA_MAX, ALPHA_MIN, T_MIN, TileBins

numba: Any = None
"""The numba module once :func:`available` has imported it (lazily: importing numba is slow)."""


@functools.cache
def available() -> bool:
    """True when numba imports (the ``render`` extra); the import happens on the first call."""
    global numba  # noqa: PLW0603 - the kernel resolves numba.prange through this global
    try:
        numba = importlib.import_module("numba")
    except ImportError:  # pragma: no cover - depends on the environment
        return False
    return True


_KERNEL: Any = None
_LAUNCH = threading.Lock()


def _tiles_kernel(  # pragma: no cover - compiled by numba, checked against numpy in the tests
    packed: Any, ids: Any, starts: Any, background: Any, image: Any
) -> None:
    """Composite every tile (in parallel) into ``image`` (H, W, 3), background included.

    ``packed`` rows are x, y, conic a, b, c, opacity, r, g, b, cutoff of the projected
    Gaussians; each tile first gathers its rows into a contiguous block.
    """
    height, width = image.shape[0], image.shape[1]
    grid_x = (width + TILE - 1) // TILE
    for k in numba.prange(starts.shape[0] - 1):
        y0 = (k // grid_x) * TILE
        x0 = (k % grid_x) * TILE
        rows = packed[ids[starts[k] : starts[k + 1]]]
        for y in range(y0, min(y0 + TILE, height)):
            for x in range(x0, min(x0 + TILE, width)):
                t = 1.0
                r = 0.0
                g = 0.0
                b = 0.0
                for j in range(rows.shape[0]):
                    dx = rows[j, 0] - x
                    dy = rows[j, 1] - y
                    power = -0.5 * (rows[j, 2] * dx * dx + rows[j, 4] * dy * dy)
                    power -= rows[j, 3] * dx * dy
                    if power > 0.0 or power < rows[j, 9]:
                        continue
                    alpha = min(ALPHA_MAX, rows[j, 5] * np.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    test_t = t * (1.0 - alpha)
                    if test_t < T_MIN:
                        break
                    w = alpha * t
                    r += rows[j, 6] * w
                    g += rows[j, 7] * w
                    b += rows[j, 8] * w
                    t = test_t
                image[y, x, 0] = r + t * background[0]
                image[y, x, 1] = g + t * background[1]
                image[y, x, 2] = b + t * background[2]


def skip_below(opacity: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Per Gaussian, a power below which alpha is surely < 1/255 (less a 1e-9 margin, far above
    rounding), so exp() can be skipped without changing a decision."""
    with np.errstate(divide="ignore"):
        return np.log(ALPHA_MIN / opacity) - 1e-9


def _kernel() -> Any:
    """The compiled kernel: compiled once per process, cached on disk where that is writable."""
    global _KERNEL  # noqa: PLW0603 - lazy compile
    if _KERNEL is None:
        if not available():  # pragma: no cover - callers check first
            raise RuntimeError("numba is not installed")
        try:
            _KERNEL = numba.njit(parallel=True, cache=True)(_tiles_kernel)
        except RuntimeError:  # pragma: no cover - "cannot cache function": read-only install
            _KERNEL = numba.njit(parallel=True)(_tiles_kernel)
    return _KERNEL


def rasterize_numba(
    proj: Projected, bins: TileBins, width: int, height: int, background: npt.NDArray[np.float64]
) -> npt.NDArray[np.float32]:
    """The (H, W, 3) image composited by the numba kernel; launches are serialised (numba's
    fallback "workqueue" threading layer is not thread-safe)."""
    image = np.zeros((height, width, 3), np.float64)
    cutoff = skip_below(proj.opacity)[:, None]
    packed = np.concatenate([proj.xy, proj.conic, proj.opacity[:, None], proj.color, cutoff], 1)
    with _LAUNCH:
        _kernel()(packed, bins.ids, bins.starts, background, image)
    return image.astype(np.float32)
