"""Lossless WebP planes: exact RGBA in, exact RGBA out, encoded and decoded in parallel threads.

Pillow releases the GIL while libwebp encodes, so a thread pool uses both cores.
``exact=True`` keeps the RGB of texels whose alpha is 0 (sh0 opacity byte 0, padding).
"""

from __future__ import annotations

import io
import os
import struct
import threading
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
from PIL import Image

from ..constants import MAX_IMAGE_PIXELS
from ..errors import SogError
from ..machine import usable_cores
from .webp_header import Size, webp_size

_pillow_webp: Any
try:  # the libwebp decoder Pillow's WebP plugin reads through (see _libwebp_rgba)
    from PIL import _webp as _pillow_webp
except ImportError:  # pragma: no cover - a Pillow built without WebP fails on any WebP
    _pillow_webp = None

U8 = npt.NDArray[np.uint8]
T = TypeVar("T")

WEBP_METHOD = 3
"""libwebp method 0-6 (effort)."""
WEBP_QUALITY = 50
"""For lossless WebP 'quality' is the compression effort too: 50 with method 3 is within
about 1 % of the size of 100 / 4, and much faster (docs/design/chunk-codec.md)."""
Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS  # Pillow warns above this and refuses above twice it
PILLOW_ERRORS = (
    OSError,
    ValueError,
    SyntaxError,
    EOFError,
    RuntimeError,
    TypeError,
    struct.error,
    Image.DecompressionBombError,
    Image.DecompressionBombWarning,
)
"""What Pillow and its libwebp decoder raise on a damaged or hostile image: each becomes a
SogError naming the image."""


def encode_webp(image: U8) -> bytes:
    """Encode an (H, W, 4) uint8 image as lossless, exact WebP."""
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGBA").save(
        out, "WEBP", lossless=True, exact=True, quality=WEBP_QUALITY, method=WEBP_METHOD
    )
    return out.getvalue()


def decode_webp(data: bytes, *, where: str, expected: Size | None = None) -> U8:
    """Decode WebP bytes to an (H, W, 4) uint8 array without colour management or premultiply.

    The size is read from the header and checked (against ``expected`` too, when given)
    before any pixel is decoded; Pillow's decompression-bomb signals become SogError.
    """
    width, height = webp_size(data, where=where)
    if expected is not None and (width, height) != expected:
        found = f"{width}x{height}"
        raise SogError(f"expected a {expected[0]}x{expected[1]} image, found {found}", where=where)
    try:
        direct = _libwebp_rgba(data, (width, height))
        if direct is not None:
            return direct
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data), formats=["WEBP"])
        with img:
            if img.size != (width, height):
                raise SogError(f"header says {width}x{height}, image is {img.size}", where=where)
            rgba = img if img.mode == "RGBA" else img.convert("RGBA")
            arr = np.asarray(rgba, dtype=np.uint8)
    except SogError:
        raise
    except PILLOW_ERRORS as exc:
        raise SogError(f"corrupt WebP image: {exc}", where=where) from exc
    return arr.reshape(height, width, 4)


def _libwebp_rgba(data: bytes, size: Size) -> U8 | None:
    """The image's RGBA bytes as libwebp decodes them, through the decoder Pillow's WebP
    plugin opens every WebP with, without the three copies Pillow's public path makes (its
    image memory, the RGBA conversion of an image without alpha, the array). None where this
    Pillow's decoder answers otherwise than expected (the public path then decodes it);
    corrupt data raises what Pillow raises. The array is read-only: decoders read their
    planes, never write them."""
    decoder_type = getattr(_pillow_webp, "WebPAnimDecoder", None)
    if decoder_type is None:
        return None
    try:
        decoder = decoder_type(data)
    except TypeError:  # another signature: not the decoder expected
        return None
    info = decoder.get_info()
    if not (isinstance(info, tuple) and len(info) == 5 and info[0] == size):
        return None
    if info[4] not in ("RGBA", "RGBX"):  # RGBX: no alpha in the file, libwebp writes 255
        return None
    frame = decoder.get_next()
    if frame is None:
        raise EOFError("libwebp decoded no frame")
    pixels = frame[0]
    width, height = size
    if not isinstance(pixels, bytes) or len(pixels) != width * height * 4:
        return None
    return np.frombuffer(pixels, np.uint8).reshape(height, width, 4)


MAX_DECODE_THREADS = 8
"""Images decoded at once on a machine of up to 4 cores (a chunk has 5-15), twice the cores
above that. More threads than cores measured faster: a thread waiting on fresh pages leaves
its core to another (docs/design/chunk-codec.md)."""


@dataclass(frozen=True)
class _Pools:
    """The process's thread pools: WebP decodes, work on decoded images, WebP encodes, and
    the helper a piece of work splits onto (:func:`in_two`)."""

    decoding: ThreadPoolExecutor
    working: ThreadPoolExecutor
    encoding: ThreadPoolExecutor
    helping: ThreadPoolExecutor


class _SharedPools:
    """The process's thread pools (:class:`_Pools`), made on first use and kept: a pool per
    chunk started its threads on every decode, each start waiting for the new thread to take
    the GIL from the running decodes (a 100k-Gaussian chunk decoded 10-15 % slower)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pools: _Pools | None = None
        self._cores: int | None = None

    def get(self) -> _Pools:
        """The pools, made on the first call."""
        with self._lock:
            if self._pools is None:
                cores = self._cores or usable_cores()
                self._pools = _Pools(
                    decoding=ThreadPoolExecutor(max(MAX_DECODE_THREADS, 2 * cores), "tsog-webp"),
                    working=ThreadPoolExecutor(cores, "tsog-decode"),
                    encoding=ThreadPoolExecutor(cores, "tsog-encode"),
                    helping=ThreadPoolExecutor(1, "tsog-help"),
                )
            return self._pools

    def cores(self) -> int:
        """The cores the pools are (or will be) sized for."""
        with self._lock:
            return self._cores or usable_cores()

    def size_for(self, cores: int) -> None:
        """Pools for ``cores`` from now on: pools of another size are dropped (work already
        handed to them finishes; their idle threads end with them) and made anew on next use."""
        with self._lock:
            if cores != self._cores:
                self._cores = cores
                self._pools = None

    def forget(self) -> None:
        """In a forked child: the parent's pool threads do not exist there, so make new ones."""
        self._lock = threading.Lock()
        self._pools = None


_SHARED_POOLS = _SharedPools()
os.register_at_fork(after_in_child=_SHARED_POOLS.forget)


def use_cores(cores: int) -> None:
    """Size the codec's thread pools for ``cores`` cores in this process from now on, where
    a scheduler gave it fewer than :func:`~tsog_stream.machine.usable_cores` says: a Dask
    worker declared with one thread beside others on the same machine."""
    _SHARED_POOLS.size_for(max(1, cores))


def cores_in_use() -> int:
    """The cores the codec's thread pools are sized for in this process."""
    return _SHARED_POOLS.cores()


SPLIT_LEAST = 16384
"""Fewest rows :func:`in_two` splits: below, handing half over costs more than it saves."""


def in_two(count: int, part: Callable[[int, int], object], *, least: int = SPLIT_LEAST) -> None:
    """``part(start, stop)`` over rows [0, ``count``) in two halves, the first on the process's
    helper thread and the second here (numpy releases the GIL), for work that runs when the
    other core has nothing left to do: the SH bands' gathers after the last plane of a chunk.
    Fewer than ``least`` rows are done here at once. The first half's error propagates."""
    if count < least:
        part(0, count)
        return
    half = count // 2
    first = _SHARED_POOLS.get().helping.submit(part, 0, half)
    try:
        part(half, count)
    finally:
        first.result()


class ImageEncoder:
    """Encodes images to lossless WebP on the process's encoding threads (one per core), each
    from the moment it is added: an encoder adds its images as it makes them, so the first
    ones are compressed while it computes the rest (the WebP of a chunk, encoded all at the
    end, was 45 % of a .splatv capture's encode time with the main thread idle).

    Leaving it cancels what has not started and waits for the rest, so nothing of it runs on
    after an error.
    """

    def __init__(self) -> None:
        self._pool = _SHARED_POOLS.get().encoding
        self._files: dict[str, Future[bytes]] = {}

    def __enter__(self) -> ImageEncoder:
        return self

    def __exit__(self, *exc: object) -> None:
        for future in self._files.values():
            future.cancel()
        wait(self._files.values())

    def add(self, images: Mapping[str, U8]) -> None:
        """Start encoding each image (a name added twice is refused: it would be lost)."""
        for name, image in images.items():
            if name in self._files:
                raise ValueError(f"image {name!r} added twice")
            self._files[name] = self._pool.submit(encode_webp, image)

    def files(self) -> dict[str, bytes]:
        """Every image's WebP bytes, in the order added (waits for them)."""
        return {name: future.result() for name, future in self._files.items()}


def encode_many(images: Mapping[str, U8]) -> dict[str, bytes]:
    """Encode several images concurrently; name -> WebP bytes in the input order."""
    with ImageEncoder() as encoder:
        encoder.add(images)
        return encoder.files()


class ImageDecoder:
    """Decodes WebP images on threads and runs work on them as soon as they are ready.

    Pillow and numpy release the GIL, so one attribute's arithmetic overlaps the next image's
    decode. Images are decoded in the order work asks for them (declare the heaviest work
    first); work runs on a pool of its own, so waiting for images never holds up a decode.
    Both pools are the process's (:class:`_SharedPools`); leaving the decoder cancels what of
    its own has not started and waits for the rest, so nothing of it runs on after an error.
    """

    def __init__(
        self, files: Mapping[str, bytes], *, where: str, sizes: Mapping[str, Size] | None = None
    ) -> None:
        self._files = files
        self._where = where
        self._sizes = sizes or {}
        pools = _SHARED_POOLS.get()
        self._decoding, self._working = pools.decoding, pools.working
        self._images: dict[str, Future[U8]] = {}
        self._work: list[Future[Any]] = []

    def __enter__(self) -> ImageDecoder:
        return self

    def __exit__(self, *exc: object) -> None:
        futures: list[Future[Any]] = [*self._work, *self._images.values()]
        for future in futures:
            future.cancel()
        wait(futures)

    def then(self, names: Sequence[str], work: Callable[[Mapping[str, U8]], T]) -> Future[T]:
        """``work`` run on the named images once they are decoded (their errors propagate)."""
        images = {name: self._decode(name) for name in names}
        future = self._working.submit(
            lambda: work({name: image.result() for name, image in images.items()})
        )
        self._work.append(future)
        return future

    def _decode(self, name: str) -> Future[U8]:
        """The decoding of one image, started on first request (called from one thread)."""
        if name not in self._images:
            self._images[name] = self._decoding.submit(
                decode_webp,
                self._files[name],
                where=f"{self._where}/{name}",
                expected=self._sizes.get(name),
            )
        return self._images[name]
