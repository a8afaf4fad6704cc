"""Lossless WebP planes: exact RGBA in, exact RGBA out, encoded in parallel threads.

Pillow releases the GIL while libwebp encodes, so a thread pool uses both cores.
``exact=True`` keeps the RGB of texels whose alpha is 0 (sh0 opacity byte 0, padding).
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import numpy.typing as npt
from PIL import Image

from ..constants import WEBP_MAX_SIDE
from ..errors import SogError

U8 = npt.NDArray[np.uint8]

WEBP_METHOD = 3
"""libwebp method 0-6 (effort)."""
WEBP_QUALITY = 50
"""For lossless WebP 'quality' is the compression effort too. Measured on real chunks
(donut, spinach .splatv, wave flipbook): quality 50 / method 3 is within 1 % of the size of
100 / 4 and 5-15x faster (docs/design/chunk-codec.md)."""
MAX_DECODED_PIXELS = WEBP_MAX_SIDE * WEBP_MAX_SIDE
"""Our own decompression-bomb limit: no WebP can legally hold more."""


def encode_webp(image: U8) -> bytes:
    """Encode an (H, W, 4) uint8 image as lossless, exact WebP."""
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGBA").save(
        out, "WEBP", lossless=True, exact=True, quality=WEBP_QUALITY, method=WEBP_METHOD
    )
    return out.getvalue()


def encode_many(images: Mapping[str, U8], workers: int | None = None) -> dict[str, bytes]:
    """Encode several images concurrently; returns name -> WebP bytes in the input order."""
    workers = workers or min(len(images), os.cpu_count() or 1) or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {name: pool.submit(encode_webp, img) for name, img in images.items()}
        return {name: fut.result() for name, fut in futures.items()}


def decode_webp(data: bytes, *, where: str) -> U8:
    """Decode WebP bytes to an (H, W, 4) uint8 array without colour management or premultiply."""
    if data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise SogError("not a WebP image (no RIFF/WEBP signature)", where=where)
    try:
        with warnings.catch_warnings():
            # Our own limit (MAX_DECODED_PIXELS) is checked below, before any pixel is decoded.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data), formats=["WEBP"])
        with img:
            width, height = img.size
            if (
                width > WEBP_MAX_SIDE
                or height > WEBP_MAX_SIDE
                or width * height > MAX_DECODED_PIXELS
            ):
                raise SogError(f"image of {width}x{height} exceeds the WebP limits", where=where)
            rgba = img.convert("RGBA")
            arr = np.asarray(rgba, dtype=np.uint8)
    except SogError:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise SogError(f"corrupt WebP image: {exc}", where=where) from exc
    return arr.reshape(height, width, 4)


def decode_many(
    files: Mapping[str, bytes], *, where: str, workers: int | None = None
) -> dict[str, U8]:
    """Decode several WebP images concurrently; errors name the file."""
    workers = workers or min(len(files), os.cpu_count() or 1) or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {n: pool.submit(decode_webp, b, where=f"{where}/{n}") for n, b in files.items()}
        return {name: fut.result() for name, fut in futures.items()}
