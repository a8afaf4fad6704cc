"""The container index on the wire: zstd-compressed manifest JSON with a SHA-256 of the JSON."""

from __future__ import annotations

import hashlib

import zstandard

from ..constants import MAX_INDEX_RATIO
from ..errors import FormatError, InputError, IntegrityError
from ..schemas.manifest import Manifest, dump_manifest, parse_manifest

MAX_INDEX_BYTES = 64 << 20
"""Largest index JSON written or read, packed or as an unpacked ``manifest.json`` (about 180k
chunks): opening one costs up to ten times its size in memory, so a bigger claim is refused."""
ZSTD_LEVEL = 19
INDEX_SLACK = 64 * 1024
"""Raw bytes any index may declare regardless of its compressed size."""


def encode_index(manifest: Manifest) -> tuple[bytes, bytes, int]:
    """(compressed index, SHA-256 of the raw JSON, raw length)."""
    raw = dump_manifest(manifest)
    if len(raw) > MAX_INDEX_BYTES:
        raise InputError(
            f"the index of {len(manifest.chunks)} chunks takes {len(raw)} bytes, over the "
            f"{MAX_INDEX_BYTES} readers accept: use longer windows or split the scene"
        )
    compressed = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True).compress(raw)
    return compressed, hashlib.sha256(raw).digest(), len(raw)


def decode_index(data: bytes, raw_length: int, sha256: bytes, *, where: str) -> Manifest:
    """Decompress, check length and hash, and validate the index."""
    cap = min(MAX_INDEX_BYTES, INDEX_SLACK + MAX_INDEX_RATIO * len(data))
    if raw_length > cap:
        raise FormatError(
            f"index claims {raw_length} bytes from {len(data)} compressed bytes, over the "
            f"limit of {cap} ({MAX_INDEX_BYTES} at most, {MAX_INDEX_RATIO}:1 beyond 64 KiB)",
            where=where,
        )
    try:
        declared = zstandard.frame_content_size(data)
        if declared != raw_length:
            raise IntegrityError(
                f"index frame holds {declared} bytes, header says {raw_length}", where=where
            )
        raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=raw_length)
    except zstandard.ZstdError as exc:
        raise FormatError(f"index is not a valid zstd frame: {exc}", where=where) from exc
    if len(raw) != raw_length:
        raise IntegrityError(
            f"index decompressed to {len(raw)} bytes, header says {raw_length}", where=where
        )
    if hashlib.sha256(raw).digest() != sha256:
        raise IntegrityError("index SHA-256 does not match the header", where=where)
    if zstd_frame_length(data, where=where) != len(data):
        raise FormatError(
            f"the index's zstd frame does not fill the {len(data)} bytes the header gives it",
            where=where,
        )
    return parse_manifest(raw, where=f"{where} (index)")


def zstd_frame_length(data: bytes, *, where: str) -> int:
    """Bytes taken by the zstd frame at the start of ``data``, by walking its block headers
    (RFC 8878 §3.1.1): ``decompress`` ignores trailing bytes, the index must not have any."""
    try:
        pos = zstandard.frame_header_size(data)
        checksum = zstandard.get_frame_parameters(data).has_checksum
    except zstandard.ZstdError as exc:
        raise FormatError(f"index is not a valid zstd frame: {exc}", where=where) from exc
    while pos + 3 <= len(data):
        block = int.from_bytes(data[pos : pos + 3], "little")
        kind, size = (block >> 1) & 3, block >> 3
        pos += 3 + (1 if kind == 1 else size)  # an RLE block stores one byte
        if block & 1:
            return pos + (4 if checksum else 0)
    raise FormatError("the index's zstd frame has no last block", where=where)
