"""``tsog verify``: check a container end to end and say which kind of check failed."""

from __future__ import annotations

import asyncio
import hashlib
import struct
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..codec.bundle import read_bundle, unnamed_entries
from ..codec.chunk import checked_images, decode_chunk, read_meta
from ..codec.sh_bands import decode_sh_bands, read_sh_meta
from ..container.header import HEADER_SIZE
from ..container.ranges import ByteRange
from ..container.sources import ByteSource
from ..container.stream_index import StreamIndex
from ..errors import TsogError
from ..model import Gaussians, Scene
from ..schemas import ChunkMeta, ShBandsMeta
from ..schemas.manifest import ChunkEntry, Manifest
from ..temporal import lifespans
from .fetchers import ChunkFetcher, RangeFetcher

RESERVED_START = struct.calcsize("<8sHHIIIQQQQ32s")
"""Header bytes [88, 128) are reserved and written as zeros (docs/spec.md §8.1)."""
CONTAINER = -1
"""The "chunk id" of problems with the container itself (header, padding)."""
_BLOCK = 1 << 20


class Check(IntEnum):
    """Kinds of failure; the value is the exit status of ``tsog verify``."""

    HASH = 3
    DECODE = 4
    BUDGET = 5
    INDEX = 6


@dataclass
class VerifyReport:
    """Problems found, by chunk (``CONTAINER`` for the header and padding)."""

    chunks: int = 0
    problems: list[tuple[Check, int, str]] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """0 when clean, else the code of the first kind of failure (hash before decode...)."""
        return min((int(c) for c, _, _ in self.problems), default=0)


def check_chunk(
    chunk: ChunkEntry, data: bytes, max_pixels: int, where: str
) -> list[tuple[Check, str]]:
    """Every check of one chunk's bytes."""
    if hashlib.sha256(data).hexdigest() != chunk.sha256:
        return [(Check.HASH, "SHA-256 does not match the index")]
    try:
        unnamed = unnamed_entries(data, where=where)
        if unnamed:
            shown = ", ".join(unnamed[:5]) + (" ..." if len(unnamed) > 5 else "")
            return [(Check.DECODE, f"entries not named by meta.json (never read): {shown}")]
        files = read_bundle(data, where=where)
        meta: ChunkMeta | ShBandsMeta = (
            read_meta(files, where=where)
            if chunk.holds_gaussians
            else read_sh_meta(files, where=where)
        )
        _, sizes = checked_images(meta, files, where=where)
        if chunk.holds_gaussians:
            scene = decode_chunk(files, where=where)
        else:
            decode_sh_bands(files, where=where)
            scene = Scene(Gaussians.empty())  # bands only: nothing is visible in time
    except TsogError as exc:
        return [(Check.DECODE, str(exc))]
    out: list[tuple[Check, str]] = []
    for name, (width, height) in sizes.items():
        if width * height > max_pixels:
            out.append((Check.BUDGET, f"{name} is {width}x{height}, over {max_pixels} px"))
    if meta.count != chunk.count:
        out.append((Check.INDEX, f"holds {meta.count} Gaussians, the index says {chunk.count}"))
    if scene.timeline is not None and len(scene):
        start, end = lifespans(scene.timeline)
        if float(end.max()) < chunk.start_s - 1e-6 or float(start.min()) > chunk.end_s + 1e-6:
            out.append(
                (Check.INDEX, "its Gaussians are never visible in the interval the index gives")
            )
    if len(scene) and not np.all(np.isfinite(scene.gaussians.means)):
        out.append((Check.DECODE, "non-finite positions"))
    return out


def unused_ranges(index: StreamIndex) -> list[ByteRange]:
    """Bytes no field, index or chunk covers: reserved header bytes and padding, in order."""
    header = index.header
    used = [ByteRange(0, RESERVED_START), ByteRange.sized(header.index_offset, header.index_length)]
    used += [index.chunk_range(c) for c in index.manifest.chunks]
    gaps: list[ByteRange] = []
    at = 0
    for span in sorted(used, key=lambda r: r.start):
        if span.start > at:
            gaps.append(ByteRange(at, span.start))
        at = max(at, span.end)
    if at < index.size:
        gaps.append(ByteRange(at, index.size))
    return gaps


async def _check_unused(source: ByteSource, index: StreamIndex) -> list[str]:
    """Reserved bytes and padding carry no data; our writer zeroes them, so any other value
    is damage (harmless to readers, but reported: docs/spec.md §8.6)."""
    found = []
    for gap in unused_ranges(index):
        for start in range(gap.start, gap.end, _BLOCK):
            block = await source.read(ByteRange(start, min(gap.end, start + _BLOCK)))
            nonzero = len(block) - len(block.lstrip(b"\0"))
            if nonzero < len(block):
                where = "reserved header" if start + nonzero < HEADER_SIZE else "padding"
                found.append(f"non-zero {where} byte at offset {start + nonzero}")
                break
    return found


def layer_problems(manifest: Manifest) -> list[str]:
    """What the layer table says that its chunks do not: per layer, the Gaussians (SH-band
    chunks hold none) and bytes of its chunks, at least one chunk, and a PSNR on every layer
    but the last (the full scene: null; the schema bounds the values). A player and ``tsog
    info`` show this table, so a table that lies is an index problem though no chunk is
    damaged; entries past the layers the chunks use are one problem, not one each."""
    layers = manifest.layers
    if not layers:
        return []
    used = 1 + max((c.layer for c in manifest.chunks), default=-1)
    gaussians, sizes, chunks = [0] * len(layers), [0] * len(layers), [0] * len(layers)
    for chunk in manifest.chunks:  # the schema keeps every chunk's layer within the table
        gaussians[chunk.layer] += chunk.count if chunk.holds_gaussians else 0
        sizes[chunk.layer] += chunk.length
        chunks[chunk.layer] += 1
    problems = []
    if used < len(layers):
        problems.append(
            f"layers: the table has {len(layers)} entries, the chunks are in {used} "
            f"(layers[{used}] onward have no chunk)"
        )
    for layer in layers[:used]:
        k, name = layer.index, f"layers[{layer.index}]"
        if chunks[k] == 0:
            problems.append(f"{name}: no chunk is in this layer")
            continue
        if layer.gaussians != gaussians[k]:
            problems.append(
                f"{name}: says {layer.gaussians} Gaussians, its {chunks[k]} chunks hold "
                f"{gaussians[k]}"
            )
        if layer.bytes != sizes[k]:
            problems.append(
                f"{name}: says {layer.bytes} bytes, its {chunks[k]} chunks have {sizes[k]}"
            )
        if k == len(layers) - 1 and layer.psnr_db is not None:
            problems.append(
                f"{name}: the last layer (the full scene) has a PSNR of {layer.psnr_db:g} dB, "
                "not null"
            )
        elif k < len(layers) - 1 and layer.psnr_db is None:
            problems.append(f"{name}: no PSNR, expected the measured quality of layers 0..{k}")
    return problems


async def verify_stream(source: ChunkFetcher, index: StreamIndex) -> VerifyReport:
    """Check the layer table against the chunk entries and a container file's unused bytes
    (the unpacked layout has none), then read every chunk once, unverified, and check it."""
    report = VerifyReport(chunks=len(index.manifest.chunks))
    for msg in layer_problems(index.manifest):
        report.problems.append((Check.INDEX, CONTAINER, msg))
    if isinstance(source, RangeFetcher):
        for msg in await _check_unused(source.source, index):
            report.problems.append((Check.INDEX, CONTAINER, msg))
    for chunk in index.manifest.chunks:
        where = f"{source.name} chunk {chunk.id}"
        [data] = await source.fetch([chunk])
        found = await asyncio.to_thread(check_chunk, chunk, data, index.manifest.max_pixels, where)
        report.problems.extend((kind, chunk.id, msg) for kind, msg in found)
    return report
