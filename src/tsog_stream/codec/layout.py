"""Image geometry shared by every per-Gaussian image: size, texel order, padding."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..constants import IMAGE_ALIGN, WEBP_MAX_SIDE
from ..errors import InputError

U8 = npt.NDArray[np.uint8]


def image_size(count: int) -> tuple[int, int]:
    """(width, height) of the per-Gaussian images for ``count`` Gaussians, as SOG v2 writes them.

    W = 4*ceil(sqrt(N)/4), H = 4*ceil(N/W/4); refuses sizes a WebP cannot hold.
    """
    if count < 0:
        raise InputError(f"count must be >= 0, got {count}")
    width = IMAGE_ALIGN * math.ceil(math.sqrt(count) / IMAGE_ALIGN)
    height = IMAGE_ALIGN * math.ceil(count / width / IMAGE_ALIGN) if width else 0
    if width > WEBP_MAX_SIDE or height > WEBP_MAX_SIDE:
        raise InputError(
            f"{count} Gaussians need a {width}x{height} image, over the WebP limit of "
            f"{WEBP_MAX_SIDE} px per side; split the scene into chunks (tsog segment)"
        )
    return width, height


def to_image(texels: U8, width: int, height: int) -> U8:
    """Lay (N, 4) texels out row-major into an (H, W, 4) image; padding texels are zero."""
    image = np.zeros((height * width, 4), np.uint8)
    image[: texels.shape[0]] = texels
    return image.reshape(height, width, 4)


def from_image(image: U8, count: int) -> U8:
    """The first ``count`` texels of an (H, W, 4) image, in texel order, as (count, 4)."""
    return image.reshape(-1, 4)[:count]


def texels(*channels: npt.ArrayLike, alpha: int | npt.ArrayLike = 255) -> U8:
    """Stack up to three (N,) byte channels (missing ones zero) and an alpha into (N, 4)."""
    cols = [np.asarray(c, dtype=np.uint8) for c in channels]
    n = cols[0].shape[0]
    out = np.zeros((n, 4), np.uint8)
    for i, c in enumerate(cols):
        out[:, i] = c
    if len(cols) < 4:
        out[:, 3] = alpha
    return out
