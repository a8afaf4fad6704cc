"""An opened container as a pure value: which chunks a time needs and where their bytes are.

Sans-I/O: bytes a reader fetched (the prefix, the index, a chunk) in, checked values out;
:func:`.sources.read_index` reads them over any byte source, :mod:`tsog_stream.client` the rest.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from functools import cached_property

from ..errors import InputError, IntegrityError
from ..model import TIME_EPSILON
from ..schemas.manifest import ChunkEntry, Manifest, check_layout, parse_manifest
from .header import PREFIX_SIZE, Header
from .index import decode_index
from .ranges import ByteRange

WINDOW_EPSILON = 1e-9
"""Fraction of a window by which a time just before its start counts as inside, so that
t = k * window_s is in window k despite rounding: the segmenter, readers and the player's
manifest.js share this rule, so a Gaussian starting at t is found at t."""
MANIFEST = "manifest.json"
"""The index of the unpacked layout (``manifest.json`` + ``chunks/NNNNNN.sog``)."""


@dataclass(frozen=True)
class StreamIndex:
    """An opened container: its header, validated index and identity (index SHA-256, hex)."""

    header: Header
    manifest: Manifest
    name: str
    packed: bool = True
    """One ``.tsogs`` file (False: ``manifest.json`` + ``chunks/``, each chunk a file)."""

    @property
    def opening_bytes(self) -> int:
        """Bytes a reader holds after opening: a packed container's first 16 KiB (a compact
        one's first chunks begin there)."""
        return min(PREFIX_SIZE, self.size) if self.packed else 0

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

    def chunk(self, chunk_id: int) -> ChunkEntry:
        """The index entry of chunk ``chunk_id`` (InputError naming the valid ids if none)."""
        chunks = self.manifest.chunks
        if not 0 <= chunk_id < len(chunks):
            raise InputError(f"no chunk {chunk_id}; this container has chunks 0-{len(chunks) - 1}")
        return chunks[chunk_id]

    @cached_property
    def windows(self) -> int:
        """Number of windows (level-0 nodes) of the segmentation."""
        return sum(1 for n in self.manifest.nodes if n.level == 0)

    def _window(self, t: float, windows: int) -> int:
        """The window holding ``t`` (:data:`WINDOW_EPSILON`), clipped to the scene's."""
        x = (t - self.manifest.scene.start_s) / self.manifest.window_s + WINDOW_EPSILON
        return min(math.floor(min(max(x, 0.0), float(windows))), windows - 1)

    @cached_property
    def bands_of(self) -> dict[int, ChunkEntry]:
        """The SH-band chunk of each chunk whose bands are split off, by the host's id."""
        return {c.sh_of: c for c in self.manifest.chunks if c.sh_of is not None}

    @cached_property
    def layer_count(self) -> int:
        """Quality layers of the stream (1 for an index without ``layers``)."""
        return max(len(self.manifest.layers), 1)

    def chunks_for_interval(
        self, start: float, end: float, layers: int | None = None
    ) -> list[ChunkEntry]:
        """Chunks holding Gaussians visible at some time in [start, end], in file order, of
        the first ``layers`` quality layers (None: all); none outside the scene's range, but
        a static scene shows the same at every time.

        Windows are chosen by index, not by their stored float edges (which round unlike frame
        times), so each Gaussian is shown once; a chunk is kept when its own interval meets
        the query within the evaluation's tolerance.
        """
        if not (math.isfinite(start) and math.isfinite(end)):
            raise InputError(f"times must be finite numbers of seconds, got [{start}, {end}]")
        m = self.manifest
        if m.scene.timeline_type is None:
            start = end = m.scene.start_s
        fps = m.scene.fps
        slack = TIME_EPSILON * (1.0 / fps if fps else 1.0) + WINDOW_EPSILON * m.window_s
        windows = self.windows
        top = self.layer_count if layers is None else layers
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
                if c.layer < top and c.start_s <= end + slack and c.end_s >= start - slack:
                    chosen.add(cid)
        return sorted((m.chunks[i] for i in chosen), key=lambda c: c.offset)

    def chunks_for(self, t: float, layers: int | None = None) -> list[ChunkEntry]:
        """Chunks needed to show time ``t`` with the first ``layers`` quality layers (None: all;
        empty before the first or after the last Gaussian)."""
        return self.chunks_for_interval(t, t, layers)


def check_file_length(header: Header, size: int, *, where: str) -> None:
    """The header's file length must be the file's: anything else is truncation or appending."""
    if header.file_length != size:
        found = f"header says the file has {header.file_length} bytes, it has {size}"
        raise IntegrityError(f"{found} (truncated or appended to)", where=where)


def index_span(header: Header) -> ByteRange:
    """Where the compressed index is."""
    return ByteRange.sized(header.index_offset, header.index_length)


def container_index(header: Header, index_bytes: bytes, *, where: str) -> StreamIndex:
    """Decode and check the index of a container whose header was read and length checked."""
    manifest = decode_index(index_bytes, header.index_raw_length, header.index_sha256, where=where)
    check_layout(manifest, *header.payload_area(), where=where)
    return StreamIndex(header, manifest, where)


def unpacked_index(manifest_json: bytes, *, where: str) -> StreamIndex:
    """The index of an unpacked layout, with the header ``tsog pack`` would give it."""
    manifest = parse_manifest(manifest_json, where=where)
    end = max((c.offset + c.length for c in manifest.chunks), default=PREFIX_SIZE)
    index = (manifest_json, hashlib.sha256(manifest_json).digest(), len(manifest_json))
    header = Header.of_index(end, index, end + len(manifest_json))
    return StreamIndex(header, manifest, where, packed=False)


def verify_chunk(chunk: ChunkEntry, data: bytes, *, where: str) -> bytes:
    """``data`` if its SHA-256 matches the index, else IntegrityError naming the chunk."""
    if hashlib.sha256(data).hexdigest() != chunk.sha256:
        found = f"chunk {chunk.id} does not match its SHA-256 in the index"
        raise IntegrityError(found, where=where)
    return data
