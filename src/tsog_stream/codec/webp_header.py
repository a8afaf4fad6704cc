"""WebP headers read without decoding: an image's declared size, checked whole before libwebp
(which allocates the canvas on opening) sees the bytes, and the most bytes a size may take.

A RIFF file: ``RIFF``, its size, ``WEBP``, then chunks (kind, size, payload, padded to even);
a still's first chunk is ``VP8L``, ``VP8 `` or ``VP8X`` (flags, canvas, then one VP8L/VP8).
"""

from __future__ import annotations

from ..constants import WEBP_MAX_SIDE
from ..errors import SogError

Size = tuple[int, int]
VP8L_SIGNATURE = 0x2F
WEBP_BYTES_PER_TEXEL = 8
"""Most bytes a reader accepts per texel: twice lossless WebP's 4.0 for RGBA noise."""
WEBP_FIXED_BYTES = 64 << 10
"""Bytes beyond those for headers and code tables (a 4x4 image of noise takes 158)."""
RIFF_HEAD = 12  # "RIFF", the size of what follows, "WEBP"
CHUNK_HEAD = 8  # a chunk's four-letter kind and payload size
VP8X_ANIMATION = 0x02
VP8_START_CODE = b"\x9d\x01\x2a"
MIN_PAYLOAD = {b"VP8X": 10, b"VP8L": 5, b"VP8 ": 10}
"""Fewest payload bytes of each first chunk that carries a size."""


def max_webp_bytes(texels: int) -> int:
    """The most bytes a WebP of ``texels`` texels may take: more is refused unread."""
    return WEBP_BYTES_PER_TEXEL * texels + WEBP_FIXED_BYTES


def webp_size(data: bytes, *, where: str) -> Size:
    """(width, height) from a WebP's headers, nothing decoded: the RIFF size must be the
    file's, the first chunk must fit, a VP8X canvas (not animated) must be its image's size,
    and no side may pass the WebP limit."""
    if len(data) < RIFF_HEAD + CHUNK_HEAD or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise SogError("not a WebP image (no RIFF/WEBP signature)", where=where)
    riff = int.from_bytes(data[4:8], "little") + 8
    if riff != len(data):
        lie = "past its end" if riff > len(data) else f"{len(data) - riff} bytes before its end"
        raise SogError(f"RIFF size says {riff} bytes, {lie} (of {len(data)})", where=where)
    kind, payload = _chunk(data, RIFF_HEAD, where)
    if kind == b"VP8X":
        if payload[0] & VP8X_ANIMATION:
            raise SogError("animated WebP (a SOG image is a still)", where=where)
        canvas = _side_checked(
            1 + int.from_bytes(payload[4:7], "little"),
            1 + int.from_bytes(payload[7:10], "little"),
            where,
        )
        image = _image_in(data, RIFF_HEAD + CHUNK_HEAD + len(payload) + len(payload) % 2, where)
        if image != canvas:
            found = f"VP8X canvas of {canvas[0]}x{canvas[1]} holds a {image[0]}x{image[1]} image"
            raise SogError(found, where=where)
        return canvas
    return _frame_size(kind, payload, where)


def _chunk(data: bytes, at: int, where: str) -> tuple[bytes, bytes]:
    """(kind, payload) of the RIFF chunk at ``at``, which must fit, with room for any size."""
    if at + CHUNK_HEAD > len(data):
        raise SogError(f"ends at byte {len(data)}, inside a chunk header", where=where)
    kind = data[at : at + 4]
    size = int.from_bytes(data[at + 4 : at + 8], "little")
    if at + CHUNK_HEAD + size > len(data):
        raise SogError(f"chunk {kind!r} of {size} bytes ends past the file", where=where)
    payload = data[at + CHUNK_HEAD : at + CHUNK_HEAD + size]
    if size < MIN_PAYLOAD.get(kind, 0):
        raise SogError(f"chunk {kind!r} of {size} bytes is too short", where=where)
    return kind, payload


def _image_in(data: bytes, at: int, where: str) -> Size:
    """The size of the first VP8 or VP8L chunk from ``at`` on (a VP8X file's image)."""
    while at < len(data):
        kind, payload = _chunk(data, at, where)
        if kind in (b"VP8 ", b"VP8L"):
            return _frame_size(kind, payload, where)
        at += CHUNK_HEAD + len(payload) + len(payload) % 2
    raise SogError("VP8X file without a VP8 or VP8L image", where=where)


def _frame_size(kind: bytes, payload: bytes, where: str) -> Size:
    """(width, height) of a VP8L (lossless) or VP8 (lossy) bitstream's header."""
    if kind == b"VP8L":
        bits = int.from_bytes(payload[1:5], "little")
        if payload[0] != VP8L_SIGNATURE or bits >> 29:
            raise SogError("VP8L chunk without its signature or of another version", where=where)
        return _side_checked(1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF), where)
    if kind == b"VP8 ":
        if payload[3:6] != VP8_START_CODE:
            raise SogError("VP8 chunk without its start code", where=where)
        width = int.from_bytes(payload[6:8], "little") & 0x3FFF
        height = int.from_bytes(payload[8:10], "little") & 0x3FFF
        return _side_checked(width, height, where)
    raise SogError(f"unknown WebP chunk {kind!r}", where=where)


def _side_checked(width: int, height: int, where: str) -> Size:
    """(width, height), each side within 1..WEBP_MAX_SIDE."""
    if not (0 < width <= WEBP_MAX_SIDE and 0 < height <= WEBP_MAX_SIDE):
        raise SogError(
            f"image of {width}x{height} exceeds the WebP limit of {WEBP_MAX_SIDE} px per side",
            where=where,
        )
    return width, height
