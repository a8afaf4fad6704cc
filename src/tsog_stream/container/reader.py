"""Opening a container and reading what time t needs, over any :class:`ByteSource`.

Opening costs one request of at most 16 KiB (header + index) unless the index is larger, in
which case a second request fetches it. ``StreamIndex`` is pure: it answers which chunks a
time or an interval needs and where their bytes are; the async functions do the reading.
"""

from __future__ import annotations

import asyncio
import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import zstandard

from ..codec.bundle import read_bundle
from ..codec.chunk import decode_chunk
from ..errors import FormatError, InputError, IntegrityError
from ..model import Gaussians, Scene
from ..schemas.manifest import ChunkEntry, Manifest, check_layout
from ..segment.plan import WINDOW_EPSILON
from ..temporal import TIME_EPSILON
from .header import PREFIX_SIZE, Header
from .index import decode_index
from .ranges import ByteRange
from .sources import ByteSource


@dataclass(frozen=True)
class StreamIndex:
    """An opened container: its header, validated index and identity (index SHA-256, hex)."""

    header: Header
    manifest: Manifest
    name: str

    @property
    def identity(self) -> str:
        """Content identity of the whole container (the SHA-256 of its index JSON)."""
        return self.header.index_sha256.hex()

    @property
    def size(self) -> int:
        """Length of the container file."""
        return self.header.file_length

    def chunk_range(self, chunk: ChunkEntry) -> ByteRange:
        """Where a chunk's bytes are."""
        return ByteRange.sized(chunk.offset, chunk.length)

    @cached_property
    def windows(self) -> int:
        """Number of windows (level-0 nodes) of the segmentation."""
        return sum(1 for n in self.manifest.nodes if n.level == 0)

    def _window(self, t: float, windows: int) -> int:
        """The window holding ``t``, by the segmenter's rule (float rounding snapped forward,
        so t = k * window_s is in window k), clipped to the scene's windows."""
        x = (t - self.manifest.scene.start_s) / self.manifest.window_s + WINDOW_EPSILON
        return min(math.floor(min(max(x, 0.0), float(windows))), windows - 1)

    def chunks_for_interval(self, start: float, end: float) -> list[ChunkEntry]:
        """Chunks holding Gaussians visible at some time in [start, end], in file order.

        Windows are chosen by index (not by comparing with their stored float edges, which
        round differently from frame times), so a time is in exactly one window and each
        Gaussian is shown once; a chunk is kept when its own visible interval meets the query
        within the evaluation's time tolerance. Nothing is chosen outside the scene's range.
        """
        if not (math.isfinite(start) and math.isfinite(end)):
            raise InputError(f"times must be finite numbers of seconds, got [{start}, {end}]")
        m = self.manifest
        fps = m.scene.fps
        slack = TIME_EPSILON * (1.0 / fps if fps else 1.0) + WINDOW_EPSILON * m.window_s
        windows = self.windows
        if windows == 0 or end < m.scene.start_s - slack or start > m.scene.end_s + slack:
            return []
        first, last = self._window(start, windows), self._window(end, windows)
        chosen: set[int] = set()
        for node in m.nodes:
            level = min(node.level, 62)  # level 62 already spans more windows than exist
            if node.index << level > last or (node.index + 1) << level <= first:
                continue
            for cid in node.chunks:
                c = m.chunks[cid]
                if c.start_s <= end + slack and c.end_s >= start - slack:
                    chosen.add(cid)
        return sorted((m.chunks[i] for i in chosen), key=lambda c: c.offset)

    def chunks_for(self, t: float) -> list[ChunkEntry]:
        """Chunks needed to show time ``t`` (empty before the first or after the last Gaussian)."""
        return self.chunks_for_interval(t, t)


async def open_stream(source: ByteSource) -> StreamIndex:
    """Read and check the header and index of the container behind ``source``."""
    size = await source.size()
    first = await source.read(ByteRange(0, min(size, PREFIX_SIZE)))
    header = Header.unpack(first, where=source.name)
    if header.file_length != size:
        raise IntegrityError(
            f"header says the file has {header.file_length} bytes, it has {size} (truncated or "
            "appended to)",
            where=source.name,
        )
    span = ByteRange.sized(header.index_offset, header.index_length)
    data = first[span.start : span.end] if span.end <= len(first) else await source.read(span)
    manifest = decode_index(data, header.index_raw_length, header.index_sha256, where=source.name)
    if zstd_frame_length(data, where=source.name) != len(data):
        raise FormatError(
            f"the index's zstd frame does not fill the {len(data)} bytes the header gives it",
            where=source.name,
        )
    payload_end = header.index_offset if header.index_offset >= PREFIX_SIZE else size
    check_layout(manifest, PREFIX_SIZE, payload_end, where=source.name)
    return StreamIndex(header, manifest, source.name)


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


def verify_chunk(chunk: ChunkEntry, data: bytes, *, where: str) -> bytes:
    """``data`` if its SHA-256 matches the index, else IntegrityError naming the chunk."""
    if hashlib.sha256(data).hexdigest() != chunk.sha256:
        raise IntegrityError(
            f"chunk {chunk.id} does not match its SHA-256 in the index", where=where
        )
    return data


async def read_chunk_bytes(source: ByteSource, index: StreamIndex, chunk: ChunkEntry) -> bytes:
    """The verified bytes (a standalone .sog) of one chunk."""
    data = await source.read(index.chunk_range(chunk))
    return verify_chunk(chunk, data, where=f"{source.name} chunk {chunk.id}")


def decode_chunk_bytes(data: bytes, *, where: str) -> Scene:
    """Decode one chunk's .sog bytes (CPU work: run it in a thread from async code)."""
    return decode_chunk(read_bundle(data, where=where), where=where)


async def read_scene_chunk(source: ByteSource, index: StreamIndex, chunk: ChunkEntry) -> Scene:
    """Fetch, verify and decode one chunk."""
    data = await read_chunk_bytes(source, index, chunk)
    return await asyncio.to_thread(
        decode_chunk_bytes, data, where=f"{source.name} chunk {chunk.id}"
    )


def frame_from_chunks(scenes: Sequence[Scene], t: float, sh_bands: int) -> Gaussians:
    """The Gaussians visible at ``t`` across decoded chunks, concatenated in chunk order."""
    return Gaussians.concat([s.at(t) for s in scenes], sh_bands=sh_bands)


async def frame_at(source: ByteSource, index: StreamIndex, t: float) -> Gaussians:
    """The scene at ``t``, reading only the chunks ``t`` needs."""
    chunks = index.chunks_for(t)
    scenes = await asyncio.gather(*(read_scene_chunk(source, index, c) for c in chunks))
    return frame_from_chunks(scenes, t, index.manifest.scene.sh_bands)
