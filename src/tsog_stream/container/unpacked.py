"""The unpacked layout: ``manifest.json`` + ``chunks/NNNNNN.sog``, servable by any static server.

``unpack`` and ``pack`` convert losslessly: packing an unpacked container gives back the same
bytes (same chunk order, offsets and index), checked chunk by chunk against the manifest.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import IntegrityError, SourceError
from ..io.files import atomic_write_folder, read_bytes
from ..schemas.manifest import dump_manifest, parse_manifest
from .reader import StreamIndex, read_chunk_bytes, verify_chunk
from .sources import ByteSource
from .writer import ContainerFile

MANIFEST = "manifest.json"


async def unpack(
    source: ByteSource, index: StreamIndex, folder: str | os.PathLike[str], *, overwrite: bool
) -> int:
    """Write the unpacked layout of an opened container; returns the number of chunks."""
    files = {MANIFEST: dump_manifest(index.manifest)}
    for chunk in index.manifest.chunks:
        files[chunk.file] = await read_chunk_bytes(source, index, chunk)
    atomic_write_folder(folder, files, overwrite=overwrite)
    return len(index.manifest.chunks)


def pack(folder: str | os.PathLike[str], path: str | os.PathLike[str]) -> int:
    """Build the container ``path`` from an unpacked folder; returns its size in bytes."""
    root = Path(folder)
    if not (root / MANIFEST).is_file():
        raise SourceError(f"no {MANIFEST} here", where=str(root))
    manifest = parse_manifest(read_bytes(root / MANIFEST), where=str(root / MANIFEST))
    with ContainerFile(path) as out:
        for chunk in sorted(manifest.chunks, key=lambda c: c.offset):
            data = verify_chunk(chunk, read_bytes(root / chunk.file), where=str(root / chunk.file))
            offset, length, _ = out.add(data)
            if (offset, length) != (chunk.offset, chunk.length):
                raise IntegrityError(
                    f"chunk {chunk.id} would land at [{offset}, +{length}) but the manifest says "
                    f"[{chunk.offset}, +{chunk.length}): the manifest was edited",
                    where=str(root / MANIFEST),
                )
        return out.finish(manifest)
