"""A thin synchronous facade over the async container reader (for the CLI and scripts).

It owns one event loop (``asyncio.Runner``) and forwards to the async functions; no logic of
its own, so the async core stays the only implementation.
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Coroutine
from types import TracebackType
from typing import Any, TypeVar

from ..errors import InputError
from ..model import Gaussians, Scene
from .costs import SeekCost, seek_cost
from .reader import StreamIndex, frame_at, open_stream, read_chunk_bytes, read_scene_chunk
from .sources import ByteSource, FileSource
from .unpacked import unpack
from .verify import VerifyReport, verify_stream

T = TypeVar("T")


class StreamReader:
    """An opened container: ``frame_at(t)``, chunk bytes, seek costs, unpacking."""

    def __init__(self, source: ByteSource) -> None:
        self.source = source
        self._runner = asyncio.Runner()
        try:
            self.index: StreamIndex = self._run(open_stream(source))
        except BaseException:
            self._runner.close()
            raise

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> StreamReader:
        """Open a local container file."""
        return cls(FileSource(path))

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self._runner.run(coro)

    def frame_at(self, t: float) -> Gaussians:
        """The Gaussians visible at ``t`` seconds, reading only the chunks ``t`` needs."""
        return self._run(frame_at(self.source, self.index, t))

    def _chunk(self, chunk_id: int) -> Any:
        chunks = self.index.manifest.chunks
        if not 0 <= chunk_id < len(chunks):
            raise InputError(f"no chunk {chunk_id}; this container has chunks 0-{len(chunks) - 1}")
        return chunks[chunk_id]

    def chunk_bytes(self, chunk_id: int) -> bytes:
        """The verified bytes of one chunk (a standalone .sog)."""
        return self._run(read_chunk_bytes(self.source, self.index, self._chunk(chunk_id)))

    def chunk_scene(self, chunk_id: int) -> Scene:
        """One chunk, decoded."""
        return self._run(read_scene_chunk(self.source, self.index, self._chunk(chunk_id)))

    def seek_cost(self, t: float) -> SeekCost:
        """What showing ``t`` costs (see :mod:`tsog_stream.container.costs`)."""
        return self._run(seek_cost(self.source, self.index, t))

    def unpack(self, folder: str | os.PathLike[str], *, overwrite: bool = False) -> int:
        """Write the unpacked layout; returns the number of chunks."""
        return self._run(unpack(self.source, self.index, folder, overwrite=overwrite))

    def verify(self) -> VerifyReport:
        """Check every chunk (hash, decode, pixel budget, agreement with the index)."""
        return self._run(verify_stream(self.source, self.index))

    def close(self) -> None:
        """Close the event loop."""
        self._runner.close()

    def __enter__(self) -> StreamReader:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
