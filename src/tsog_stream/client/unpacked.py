"""Between the two layouts: one ``.tsogs`` file and ``manifest.json`` + ``chunks/NNNNNN.sog``.

Both directions read the chunks through an opened client (``chunk_bytes``), so any origin
works: a file, a folder, a URL of either. They convert losslessly: packing an unpacked
container gives back the same bytes (same chunk order, offsets and index), checked chunk by
chunk against the index.
"""

from __future__ import annotations

import os
from collections.abc import Awaitable, Callable

from ..container.header import PREFIX_SIZE
from ..container.objects import container_output, put_objects
from ..container.stream_index import MANIFEST, StreamIndex
from ..container.writer import payloads_at
from ..errors import IntegrityError
from ..io.files import atomic_write_folder
from ..io.objects import is_object_url
from ..schemas.manifest import dump_manifest

ChunkBytes = Callable[[int], Awaitable[bytes]]
"""The verified bytes of a chunk by id (``StreamClient.chunk_bytes``)."""


async def unpack(
    index: StreamIndex, chunk_bytes: ChunkBytes, folder: str | os.PathLike[str], *, overwrite: bool
) -> int:
    """Write the unpacked layout of an opened container; returns the number of chunks."""
    manifest = index.manifest
    files = {MANIFEST: dump_manifest(manifest)}
    for chunk in manifest.chunks:
        files[chunk.file] = await chunk_bytes(chunk.id)
    if is_object_url(folder):
        put_objects(os.fspath(folder), files, overwrite=overwrite)
    else:
        atomic_write_folder(folder, files, overwrite=overwrite)
    return len(manifest.chunks)


async def pack(index: StreamIndex, chunk_bytes: ChunkBytes, path: str | os.PathLike[str]) -> int:
    """Write an opened container as one ``.tsogs`` file; returns its size in bytes.

    Every chunk must land where the index says: an unpacked folder whose manifest was edited
    by hand is refused rather than written with an index that lies.
    """
    manifest = payloads_at(index.manifest, PREFIX_SIZE)  # where a writer's offsets count from
    with container_output(path) as out:
        for chunk in sorted(manifest.chunks, key=lambda c: c.offset):
            offset, length, _ = out.add(await chunk_bytes(chunk.id))
            if (offset, length) != (chunk.offset, chunk.length):
                raise IntegrityError(
                    f"chunk {chunk.id} would land at [{offset}, +{length}) but the manifest says "
                    f"[{chunk.offset}, +{chunk.length}): the manifest was edited",
                    where=index.name,
                )
        return out.finish(manifest)
