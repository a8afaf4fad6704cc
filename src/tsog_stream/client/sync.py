"""``Stream``: the thin synchronous facade over :class:`StreamClient` (for scripts and the CLI).

It owns one event loop (``asyncio.Runner``) and forwards every call to the async core; no
logic of its own. Made where an event loop already runs (a Jupyter cell, async code), its loop
runs on a thread of its own and each call blocks until it is done there (async code should
await :class:`StreamClient` instead).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import threading
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, TypeVar

from ..container.sources import ReadStats
from ..container.stream_index import StreamIndex
from ..model import Gaussians, Scene
from .costs import SeekCost
from .http_options import HttpOptions
from .live import LiveStats, follow_live
from .playback import Playback, PlayedFrame, PlayStats
from .stream import MiB, StreamClient
from .verify import VerifyReport

T = TypeVar("T")


class Stream:
    """An opened container (any origin) driven from synchronous code; see :class:`StreamClient`."""

    def __init__(
        self,
        target: str | os.PathLike[str],
        *,
        cache_bytes: int = 256 * MiB,
        concurrency: int = 4,
        coalesce_gap: int | None = 64 * 1024,
        http: HttpOptions | None = None,
        timeout: float | None = None,
    ) -> None:
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            self._runner: asyncio.Runner | _LoopThread = asyncio.Runner()
        else:  # a Jupyter cell, async code: this thread cannot run a loop of its own
            self._runner = _LoopThread()
        opening = StreamClient.open(
            target,
            cache_bytes=cache_bytes,
            concurrency=concurrency,
            coalesce_gap=coalesce_gap,
            http=http,
            timeout=timeout,
        )
        try:
            self.client: StreamClient = self._run(opening)
        except BaseException:
            self._runner.close()
            raise

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self._runner.run(coro)

    @property
    def index(self) -> StreamIndex:
        """The container's header and index: scene range, chunks, ``chunks_for(t)``."""
        return self.client.index

    @property
    def stats(self) -> ReadStats:
        """Requests made and bytes received so far."""
        return self.client.source.stats

    def frame_at(self, t: float, layers: int | None = None) -> Gaussians:
        """The Gaussians visible at ``t`` seconds with the first ``layers`` quality layers
        (None: all), fetching only the chunks that needs."""
        return self._run(self.client.frame_at(t, layers))

    def prefetch(self, t: float, horizon: float) -> int:
        """Fetch the chunks of [t, t + horizon]; returns how many were fetched."""
        return self._run(self.client.prefetch(t, horizon))

    def chunk_bytes(self, chunk_id: int) -> bytes:
        """The verified bytes of one chunk (a standalone ``.sog``)."""
        return self._run(self.client.chunk_bytes(chunk_id))

    def chunk_scene(self, chunk_id: int) -> Scene:
        """One chunk, decoded."""
        return self._run(self.client.chunk_scene(chunk_id))

    def seek_cost(self, t: float) -> SeekCost:
        """What showing ``t`` costs against what is visible."""
        return self._run(self.client.seek_cost(t))

    def verify(self) -> VerifyReport:
        """Check every chunk (hash, decode, pixel budget, agreement with the index)."""
        return self._run(self.client.verify())

    @property
    def is_live(self) -> bool:
        """See :attr:`StreamClient.is_live`."""
        return self.client.is_live

    def refresh(self) -> bool:
        """See :meth:`StreamClient.refresh`."""
        return self._run(self.client.refresh())

    def follow_live(
        self,
        *,
        fps: float = 30.0,
        duration_s: float | None = None,
        behind_s: float | None = None,
        on_frame: Callable[[float, LiveStats], None] | None = None,
    ) -> LiveStats:
        """See :func:`.live.follow_live`."""
        return self._run(
            follow_live(
                self.client, fps=fps, duration_s=duration_s, behind_s=behind_s, on_frame=on_frame
            )
        )

    def unpack(self, folder: str | os.PathLike[str], *, overwrite: bool = False) -> int:
        """Write the unpacked layout into ``folder``; returns the number of chunks."""
        return self._run(self.client.unpack(folder, overwrite=overwrite))

    def pack(self, path: str | os.PathLike[str]) -> int:
        """Write the container as one ``.tsogs`` file; returns its size in bytes."""
        return self._run(self.client.pack(path))

    def play(
        self,
        start: float = 0.0,
        *,
        speed: float = 1.0,
        fps: float = 30.0,
        duration: float | None = None,
        horizon_s: float = 1.0,
        realtime: bool = False,
        adaptive: bool = False,
    ) -> tuple[list[PlayedFrame], PlayStats]:
        """Every frame of a simulated playback (see :meth:`StreamClient.play`) and its stats."""
        playback = self.client.play(
            start,
            speed=speed,
            fps=fps,
            duration=duration,
            horizon_s=horizon_s,
            realtime=realtime,
            adaptive=adaptive,
        )
        return self.run_playback(playback), playback.stats

    def run_playback(
        self, playback: Playback, on_frame: Callable[[PlayedFrame], None] | None = None
    ) -> list[PlayedFrame]:
        """Run a playback to its end, calling ``on_frame`` after each frame; returns them all."""
        frames: list[PlayedFrame] = []

        def keep(frame: PlayedFrame) -> None:
            frames.append(frame)
            if on_frame is not None:
                on_frame(frame)

        self._run(_drain(playback, keep))
        return frames

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

    def __enter__(self) -> Stream:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class _LoopThread:
    """An event loop on a thread of its own, driven like ``asyncio.Runner`` (``run``, ``close``):
    the facade's loop where the caller's thread already runs one, which cannot run another."""

    def __init__(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self._loop.run_forever, name="tsog-stream-loop", daemon=True
        )
        self._thread.start()

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        """Run ``coro`` on the loop's thread and wait for it; an interrupt cancels it there."""
        future = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return future.result()
        except BaseException:
            future.cancel()
            raise

    def close(self) -> None:
        """Cancel the loop's tasks left, finish its async generators and executor (as
        ``asyncio.Runner.close`` does), stop it and join its thread."""
        if self._loop.is_closed():
            return
        try:
            self.run(_cancel_the_rest())
            self.run(self._loop.shutdown_asyncgens())
            self.run(self._loop.shutdown_default_executor())
        except (RuntimeError, concurrent.futures.CancelledError):
            pass  # a loop already stopping: nothing left to finish
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
            self._loop.close()


async def _cancel_the_rest() -> None:
    """Cancel every other task of the running loop and wait for them to end."""
    tasks = [task for task in asyncio.all_tasks() if task is not asyncio.current_task()]
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


async def _drain(playback: Playback, on_frame: Callable[[PlayedFrame], None] | None) -> int:
    """Iterate a playback, dropping each frame after ``on_frame``; returns how many there were."""
    count = 0
    async for frame in playback:
        count += 1
        if on_frame is not None:
            on_frame(frame)
    return count


open_stream = Stream
"""Open a container synchronously: a path or ``file://`` URL of a ``.tsogs`` file or of an
unpacked folder, or an http(s) URL of either (a folder URL ends with ``/`` or
``/manifest.json``). ``timeout``: seconds one read over HTTP may take, retries included
(default 60). Use it as a context manager, or call ``close()``."""
