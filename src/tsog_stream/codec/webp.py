"""Lossless WebP planes: exact RGBA in, exact RGBA out, encoded and decoded on threads.

Pillow releases the GIL inside libwebp, so the process's thread pools keep both cores busy.
``exact=True`` keeps the RGB of texels whose alpha is 0 (sh0 opacity byte 0, padding).
"""

from __future__ import annotations

import io
import os
import struct
import threading
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
from PIL import Image

from ..constants import MAX_IMAGE_PIXELS
from ..errors import SogError
from .webp_header import Size, webp_size

_pillow_webp: Any
try:  # the libwebp decoder Pillow's WebP plugin opens every WebP with (see _libwebp_rgba)
    from PIL import _webp as _pillow_webp
except ImportError:  # pragma: no cover - a Pillow built without WebP fails on any WebP
    _pillow_webp = None

U8 = npt.NDArray[np.uint8]
T = TypeVar("T")

WEBP_METHOD = 3
"""libwebp method 0-6 (effort)."""
WEBP_QUALITY = 50
"""Lossless 'quality' is effort too: within about 1 % of 100/4's size, much faster
(docs/design/chunk-codec.md)."""
Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS  # any size webp_size passes: Pillow never warns
PILLOW_ERRORS = (
    OSError,
    ValueError,
    SyntaxError,
    EOFError,
    RuntimeError,
    TypeError,
    struct.error,
    Image.DecompressionBombError,
)
"""What Pillow raises on a damaged image: each becomes a SogError naming the image."""


def encode_webp(image: U8) -> bytes:
    """Encode an (H, W, 4) uint8 image as lossless, exact WebP."""
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGBA").save(
        out, "WEBP", lossless=True, exact=True, quality=WEBP_QUALITY, method=WEBP_METHOD
    )
    return out.getvalue()


def decode_webp(data: bytes, *, where: str, expected: Size | None = None) -> U8:
    """An (H, W, 4) uint8 array (read-only) of WebP bytes, exactly as stored: no colour
    management, no premultiplying, alpha 255 where the file has none.

    The header is checked whole (and against ``expected``) before Pillow sees the bytes:
    libwebp allocates the canvas when it opens a file. Any damage raises SogError.
    """
    width, height = webp_size(data, where=where)
    if expected is not None and (width, height) != expected:
        found = f"{width}x{height}"
        raise SogError(f"expected a {expected[0]}x{expected[1]} image, found {found}", where=where)
    try:
        direct = _libwebp_rgba(data, (width, height))
        if direct is not None:
            return direct
        with Image.open(io.BytesIO(data), formats=["WEBP"]) as img:
            if img.size != (width, height):
                raise SogError(f"header says {width}x{height}, image is {img.size}", where=where)
            rgba = img if img.mode == "RGBA" else img.convert("RGBA")
            return np.asarray(rgba, np.uint8).reshape(height, width, 4)
    except PILLOW_ERRORS as exc:
        raise SogError(f"corrupt WebP image: {exc}", where=where) from exc


def _libwebp_rgba(data: bytes, size: Size) -> U8 | None:
    """The RGBA bytes libwebp decodes, read-only, from the decoder Pillow's WebP plugin opens
    every WebP with, without the copies of Pillow's public path (1.2-1.4x the CPU of a chunk's
    planes: docs/design/dependencies.md). None where this Pillow's decoder is not the one
    expected (the public path then decodes); corrupt data raises what Pillow raises."""
    decoder_type = getattr(_pillow_webp, "WebPAnimDecoder", None)
    if decoder_type is None:
        return None
    try:
        decoder = decoder_type(data)
    except TypeError:  # another signature: not the decoder expected
        return None
    info = decoder.get_info()
    # RGBX: no alpha in the file, libwebp writes 255
    if not (isinstance(info, tuple) and len(info) == 5 and info[0] == size):
        return None
    if info[4] not in ("RGBA", "RGBX"):
        return None
    frame = decoder.get_next()
    if frame is None:
        raise EOFError("libwebp decoded no frame")
    width, height = size
    if not isinstance(frame[0], bytes) or len(frame[0]) != width * height * 4:
        return None
    return np.frombuffer(frame[0], np.uint8).reshape(height, width, 4)


MAX_DECODE_THREADS = 8
"""Images decoded at once up to 4 cores, twice the cores above: a thread waiting on fresh
pages leaves its core to another (docs/design/chunk-codec.md)."""


def affinity_cores() -> int:
    """The cores this process's CPU affinity allows (the machine's count where the system
    cannot say): the pools' size unless a caller says less (:func:`use_cores`)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else os.cpu_count() or 1


class _SharedPools:
    """The process's pools (decoding, working on decoded images, encoding, and the helper of
    :func:`in_two`), made on first use and kept: starting threads per chunk cost 10-15 %.
    Sized for :func:`affinity_cores` unless :func:`use_cores` said otherwise: what a container's
    CPU quota leaves is for the caller to say (the codec reads no system file)."""

    _lock: threading.Lock
    _pools: dict[str, ThreadPoolExecutor] | None
    _cores: int | None = None

    def __init__(self) -> None:
        self.forget()

    def get(self) -> dict[str, ThreadPoolExecutor]:
        """The pools by name, made on the first call."""
        with self._lock:
            if self._pools is None:
                cores = self._cores or affinity_cores()
                sizes = {"decoding": max(MAX_DECODE_THREADS, 2 * cores), "working": cores}
                sizes |= {"encoding": cores, "helping": 1}
                self._pools = {k: ThreadPoolExecutor(n, f"tsog-{k}") for k, n in sizes.items()}
            return self._pools

    def cores(self) -> int:
        """The cores the pools are (or will be) sized for."""
        with self._lock:
            return self._cores or affinity_cores()

    def size_for(self, cores: int) -> None:
        """Pools for ``cores`` from now on (pools of another size end once idle)."""
        with self._lock:
            if cores != self._cores:
                self._cores, self._pools = cores, None

    def forget(self) -> None:
        """No pools yet (and in a forked child: the parent's threads do not exist there)."""
        self._lock, self._pools = threading.Lock(), None


_SHARED_POOLS = _SharedPools()
os.register_at_fork(after_in_child=_SHARED_POOLS.forget)


def use_cores(cores: int) -> None:
    """Size this process's codec pools for ``cores`` (the CLI and the segmenter's workers say
    what ``machine.usable_cores`` finds under a container's quota; a Dask worker, its threads)."""
    _SHARED_POOLS.size_for(max(1, cores))


def cores_in_use() -> int:
    """The cores the codec's thread pools are sized for in this process."""
    return _SHARED_POOLS.cores()


SPLIT_LEAST = 16384
"""Fewest rows :func:`in_two` splits: below, handing half over costs more than it saves."""


def in_two(count: int, part: Callable[[int, int], object], *, least: int = SPLIT_LEAST) -> None:
    """``part(start, stop)`` over rows [0, ``count``) in two halves, the first on the helper
    thread (numpy releases the GIL): for work left when the other core is idle, such as the SH
    gathers after a chunk's last plane. Under ``least`` rows, all here; either error propagates."""
    if count < least:
        part(0, count)
        return
    half = count // 2
    first = _SHARED_POOLS.get()["helping"].submit(part, 0, half)
    try:
        part(half, count)
    finally:
        first.result()


class ImageEncoder:
    """Encodes images to WebP on the process's encoding threads from the moment each is added,
    so the first are compressed while the rest are computed (encoding all at the end left the
    main thread idle for 45 % of an encode). Leaving it cancels what has not started and waits
    for the rest, so nothing runs on after an error."""

    def __init__(self) -> None:
        self._pool = _SHARED_POOLS.get()["encoding"]
        self._files: dict[str, Future[bytes]] = {}

    def __enter__(self) -> ImageEncoder:
        return self

    def __exit__(self, *exc: object) -> None:
        _cancel_and_wait(self._files.values())

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
    """Decodes WebP images on threads and runs work on each set as soon as it is decoded, so
    one attribute's arithmetic overlaps the next image's decode.

    Images are decoded in the order work asks for them (declare the costliest first); work
    waits on a pool of its own, never holding up a decode. Leaving it cancels what has not
    started and waits for the rest, so nothing runs on after an error.
    """

    def __init__(
        self, files: Mapping[str, bytes], *, where: str, sizes: Mapping[str, Size] | None = None
    ) -> None:
        self._files, self._where, self._sizes = files, where, sizes or {}
        pools = _SHARED_POOLS.get()
        self._decoding, self._working = pools["decoding"], pools["working"]
        self._images: dict[str, Future[U8]] = {}
        self._work: list[Future[Any]] = []

    def __enter__(self) -> ImageDecoder:
        return self

    def __exit__(self, *exc: object) -> None:
        _cancel_and_wait([*self._work, *self._images.values()])

    def then(self, names: Sequence[str], work: Callable[[Mapping[str, U8]], T]) -> Future[T]:
        """``work`` run on the named images once they are decoded (their errors propagate)."""
        for name in names:  # decoding starts on first request
            if name not in self._images:
                where, size = f"{self._where}/{name}", self._sizes.get(name)
                future = self._decoding.submit(
                    decode_webp, self._files[name], where=where, expected=size
                )
                self._images[name] = future
        images = {name: self._images[name] for name in names}
        done = self._working.submit(lambda: work({n: f.result() for n, f in images.items()}))
        self._work.append(done)
        return done


def _cancel_and_wait(futures: Any) -> None:
    """Cancel what has not started, wait for the rest."""
    futures = list(futures)
    for future in futures:
        future.cancel()
    wait(futures)
