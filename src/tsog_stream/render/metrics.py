"""Image metrics on 8-bit RGB renders: PSNR and SSIM in the 3DGS evaluation's conventions.

Both take uint8 images of the same shape, (H, W) or (H, W, C), and compare them as floats in
[0, 1] (value / 255), so a render is judged after the rounding a viewer's 8-bit display applies.

- PSNR: ``10 log10(1 / MSE)`` with the MSE over all pixels and channels; ``inf`` when the images
  are identical.
- SSIM: Wang et al. 2004 as computed by the 3DGS evaluation (``utils/loss_utils.py``): an 11x11
  Gaussian window (sigma 1.5) applied per channel as a zero-padded "same" convolution (what
  ``F.conv2d(..., padding=5)`` does), C1 = 0.01^2, C2 = 0.03^2, and the mean of the whole map
  over all pixels and channels (borders included, where the zero padding lowers the local means).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..errors import InputError

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]

WINDOW_SIZE = 11
"""Side of the SSIM window in pixels."""
WINDOW_SIGMA = 1.5
"""Standard deviation of the SSIM window in pixels."""
C1 = 0.01**2
"""SSIM stabiliser of the luminance term (K1 = 0.01, dynamic range 1)."""
C2 = 0.03**2
"""SSIM stabiliser of the contrast-structure term (K2 = 0.03, dynamic range 1)."""


def gaussian_window(size: int = WINDOW_SIZE, sigma: float = WINDOW_SIGMA) -> F64:
    """The normalised 1D Gaussian whose outer product with itself is the 2D SSIM window."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g: F64 = np.exp(-(x**2) / (2.0 * sigma**2))
    window: F64 = g / float(g.sum())
    return window


def _as_unit(image: npt.ArrayLike, name: str) -> F64:
    """A uint8 image as float64 in [0, 1], always (H, W, C)."""
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        raise InputError(f"expected a uint8 image, got dtype {arr.dtype}", where=name)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0 or arr.shape[2] == 0:
        raise InputError(f"expected an (H, W) or (H, W, C) image, got {arr.shape}", where=name)
    return arr.astype(np.float64) / 255.0


def _pair(a: npt.ArrayLike, b: npt.ArrayLike) -> tuple[F64, F64]:
    """Both images as floats in [0, 1], refusing different shapes."""
    x, y = _as_unit(a, "image a"), _as_unit(b, "image b")
    if x.shape != y.shape:
        raise InputError(f"images differ in shape: {x.shape} vs {y.shape}")
    return x, y


def mse(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean squared error over all pixels and channels, images scaled to [0, 1]."""
    x, y = _pair(a, b)
    return float(np.mean((x - y) ** 2))


def psnr_from_mse(value: float) -> float:
    """PSNR in dB of images in [0, 1] with mean squared error ``value`` (inf for 0)."""
    if value < 0 or not math.isfinite(value):
        raise InputError(f"an MSE must be finite and >= 0, got {value}")
    return math.inf if value == 0 else -10.0 * math.log10(value)


def psnr(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Peak signal-to-noise ratio in dB of two uint8 images (peak 1 after scaling by 1/255)."""
    return psnr_from_mse(mse(a, b))


def _filter_axis(x: F64, window: F64, axis: int) -> F64:
    """Correlate ``x`` with ``window`` along ``axis``, zero-padded, output the same size."""
    half = len(window) // 2
    pad = [(0, 0)] * x.ndim
    pad[axis] = (half, half)
    padded = np.pad(x, pad)
    n = x.shape[axis]
    out = np.zeros_like(x)
    for k, w in enumerate(window):  # 11 shifted slices: vectorised over the whole image
        out += w * np.take(padded, np.arange(k, k + n), axis=axis)
    return out


def gaussian_filter(x: F64, window: F64 | None = None) -> F64:
    """The separable 2D window over the first two axes of (H, W, C), zero-padded 'same'.

    With zero padding the separable form equals the full 2D convolution exactly, since the
    2D window is the outer product of the 1D one and padding commutes with each 1D pass.
    """
    w = gaussian_window() if window is None else window
    return _filter_axis(_filter_axis(x, w, 0), w, 1)


def ssim_map(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """The per-pixel, per-channel SSIM map (H, W, C) of two uint8 images."""
    x, y = _pair(a, b)
    mu_x, mu_y = gaussian_filter(x), gaussian_filter(y)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    var_x = gaussian_filter(x * x) - mu_xx
    var_y = gaussian_filter(y * y) - mu_yy
    cov = gaussian_filter(x * y) - mu_xy
    num = (2.0 * mu_xy + C1) * (2.0 * cov + C2)
    den = (mu_xx + mu_yy + C1) * (var_x + var_y + C2)
    result: F64 = num / den
    return result


def ssim(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean SSIM of two uint8 images over all pixels and channels (1.0 when identical)."""
    return float(np.mean(ssim_map(a, b)))
