"""A thin synchronous facade over :class:`StreamClient` (for the CLI and scripts).

It owns one event loop (``asyncio.Runner``) and forwards every call to the async core; no
logic of its own.
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, TypeVar

from ..model import Gaussians
from .http_source import HttpOptions
from .stream import MiB, Playback, PlayedFrame, PlayStats, StreamClient

T = TypeVar("T")


class SyncClient:
    """A :class:`StreamClient` driven from synchronous code."""

    def __init__(self, target: str | os.PathLike[str], **options: Any) -> None:
        self._runner = asyncio.Runner()
        try:
            self.client: StreamClient = self._run(StreamClient.open(target, **options))
        except BaseException:
            self._runner.close()
            raise

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self._runner.run(coro)

    def frame_at(self, t: float) -> Gaussians:
        """The Gaussians visible at ``t`` seconds."""
        return self._run(self.client.frame_at(t))

    def prefetch(self, t: float, horizon: float) -> int:
        """Fetch the chunks of [t, t + horizon]; returns how many were fetched."""
        return self._run(self.client.prefetch(t, horizon))

    def play(self, start: float = 0.0, **options: Any) -> tuple[list[PlayedFrame], PlayStats]:
        """Every frame of a simulated playback (see :meth:`StreamClient.play`) and its stats."""
        playback = self.client.play(start, **options)
        return self.run_playback(playback), playback.stats

    def run_playback(
        self, playback: Playback, on_frame: Callable[[PlayedFrame], None] | None = None
    ) -> list[PlayedFrame]:
        """Run a playback to its end, calling ``on_frame`` after each frame."""
        return self._run(_collect(playback, on_frame))

    def drain_playback(
        self, playback: Playback, on_frame: Callable[[PlayedFrame], None] | None = None
    ) -> int:
        """Run a playback to its end keeping no frame (each is dropped after ``on_frame``);
        returns the number of frames played."""
        return self._run(_drain(playback, on_frame))

    def close(self) -> None:
        """Close the connections and the event loop."""
        try:
            self._run(self.client.aclose())
        finally:
            self._runner.close()

    def __enter__(self) -> SyncClient:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


async def _collect(
    playback: Playback, on_frame: Callable[[PlayedFrame], None] | None
) -> list[PlayedFrame]:
    """All frames of a playback."""
    out = []
    async for frame in playback:
        out.append(frame)
        if on_frame is not None:
            on_frame(frame)
    return out


async def _drain(playback: Playback, on_frame: Callable[[PlayedFrame], None] | None) -> int:
    """Iterate a playback, dropping each frame; returns how many there were."""
    count = 0
    async for frame in playback:
        count += 1
        if on_frame is not None:
            on_frame(frame)
    return count


def open_url(
    target: str | os.PathLike[str],
    *,
    cache_bytes: int = 256 * MiB,
    concurrency: int = 4,
    coalesce_gap: int | None = 64 * 1024,
    http: HttpOptions | None = None,
) -> SyncClient:
    """Open a container by http(s) URL, ``file://`` URL or path, synchronously."""
    return SyncClient(
        target,
        cache_bytes=cache_bytes,
        concurrency=concurrency,
        coalesce_gap=coalesce_gap,
        http=http,
    )
