"""Following a live stream in real time: start behind the live edge, keep the index fresh,
catch up a little when behind, and measure what a viewer gets (first picture, stalls, and
the latency from a frame's arrival in the source to its showing). See docs/client.md."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..errors import InputError, TsogError
from ..schemas.manifest import Manifest
from .playback import MAX_PLAY_FRAMES

if TYPE_CHECKING:
    from .stream import StreamClient

MARGIN_S = 0.5
"""How far behind the start of the newest window a viewer joins (room for the next window's
encoding and publishing)."""
CATCH_UP = 1.1
"""The fastest a follower plays to get back to its target distance from the edge."""
TIME_EPSILON = 1e-6
"""Scene seconds by which a time summed frame by frame may miss the edge it reached."""
WAIT_BOUND_S = 30.0
"""The longest a follower waits at the edge for a publication before it gives up."""


@dataclass
class LiveStats:
    """What following a live stream gave: ``latencies_s`` from each shown frame's arrival in
    the source (the index's window arrival, advanced at the frame rate), ``publish_s`` from its
    window's publication."""

    first_picture_s: float = 0.0
    frames: int = 0
    stalls: int = 0
    stall_s: float = 0.0
    joined_behind_s: float = 0.0
    """How far behind the live edge the first frame was."""
    ended: bool = False
    latencies_s: list[float] = field(default_factory=list, repr=False)
    publish_s: list[float] = field(default_factory=list, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """The report ``tsog play --live --json`` prints."""
        return {
            "first_picture_s": round(self.first_picture_s, 4),
            "frames": self.frames,
            "stalls": self.stalls,
            "stall_s": round(self.stall_s, 4),
            "joined_behind_s": round(self.joined_behind_s, 4),
            "ended": self.ended,
            "latency_p50_s": _percentile(self.latencies_s, 50),
            "latency_p95_s": _percentile(self.latencies_s, 95),
            "publish_latency_p50_s": _percentile(self.publish_s, 50),
            "publish_latency_p95_s": _percentile(self.publish_s, 95),
        }


def _percentile(values: list[float], q: float) -> float | None:
    """The ``q``-th percentile (nearest rank), rounded to 0.1 ms; None without values."""
    if not values:
        return None
    ordered = sorted(values)
    return round(ordered[min(len(ordered) - 1, math.ceil(q / 100 * len(ordered)) - 1)], 4)


def arrival_of(manifest: Manifest, t: float) -> tuple[float, float] | None:
    """When the frame at ``t`` arrived in the source and when its window was published (Unix
    seconds), from the live index; None for a recorded one."""
    live = manifest.live
    if live is None or not live.windows:
        return None
    start, window = manifest.scene.start_s, manifest.window_s
    w = min(max(0, int((t - start) / window + 1e-9)), len(live.windows) - 1)
    entry = live.windows[w]
    return entry.arrived_s + (t - start - w * window), entry.published_s


async def follow_live(
    client: StreamClient,
    *,
    fps: float = 30.0,
    duration_s: float | None = None,
    behind_s: float | None = None,
    on_frame: Callable[[float, LiveStats], None] | None = None,
) -> LiveStats:
    """Play ``client``'s stream in real time from ``behind_s`` (default: a window and
    MARGIN_S) behind its live edge until it ends or ``duration_s`` wall seconds pass, the
    index refreshed meanwhile; ``on_frame(t, stats)`` after each frame shown."""
    if not (fps > 0 and math.isfinite(fps)):
        raise InputError(f"expected a positive frame rate, got {fps}", where="fps")
    manifest = client.index.manifest
    behind = manifest.window_s + MARGIN_S if behind_s is None else behind_s
    t = max(manifest.scene.start_s, client.live_edge_s - behind)
    stats = LiveStats(joined_behind_s=client.live_edge_s - t)
    follower = _Follower(client, behind, 1 / fps, stats, asyncio.Event(), on_frame)
    refresher = asyncio.create_task(_keep_fresh(client, follower.fresh))
    try:
        await follower.play(t, duration_s)
    finally:
        refresher.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await refresher
    return stats


async def _keep_fresh(client: StreamClient, fresh: asyncio.Event) -> None:
    """Refresh the index while the stream is live (blocking where the origin can, else every
    half window), setting ``fresh`` at each new publication."""
    while client.is_live:
        try:
            changed = await client.refresh()
        except TsogError:
            changed = False
        if changed:
            fresh.set()
        else:
            await asyncio.sleep(client.index.manifest.window_s / 2)
    fresh.set()


@dataclass
class _Follower:
    """One follow of a live stream: its target distance from the edge, frame interval,
    stats, the event a new publication sets, and who hears of each frame."""

    client: StreamClient
    behind: float
    frame_s: float
    stats: LiveStats
    fresh: asyncio.Event
    on_frame: Callable[[float, LiveStats], None] | None

    async def play(self, t: float, duration_s: float | None) -> None:
        """Show frames from ``t`` at the frame rate (up to CATCH_UP when more than a frame
        behind the target), waiting at the edge for the next publication."""
        client, frame_s = self.client, self.frame_s
        began = due = time.monotonic()
        while self.stats.frames < MAX_PLAY_FRAMES:
            if duration_s is not None and time.monotonic() - began >= duration_s:
                return
            if not await self._published_past(t):
                self.stats.ended = True
                return
            await client.prefetch(t, client.index.manifest.window_s, wait=False)
            await client.frame_at(t)
            now = time.monotonic()
            self._count(t, now - due, now - began)
            if self.on_frame is not None:
                self.on_frame(t, self.stats)
            due = max(due + frame_s, now)  # after a stall, play on from where it is
            late = client.live_edge_s - t - self.behind
            t += frame_s * (CATCH_UP if late > frame_s else 1.0)
            await asyncio.sleep(max(0.0, due - time.monotonic()))

    async def _published_past(self, t: float) -> bool:
        """Wait until the frame at ``t`` is published; False when the stream ended first."""
        deadline = time.monotonic() + WAIT_BOUND_S
        while True:
            self.fresh.clear()  # before looking: a publication after the look wakes the wait
            if t < self.client.live_edge_s - TIME_EPSILON:
                return True
            if not self.client.is_live:
                return False
            left = deadline - time.monotonic()
            if left <= 0:
                raise TsogError(f"no publication for {WAIT_BOUND_S:g} s at the live edge")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.fresh.wait(), left)

    def _count(self, t: float, late_s: float, since_start_s: float) -> None:
        """Count a frame shown ``late_s`` after it was due: the first picture, a stall when
        more than a frame late, its latencies."""
        stats = self.stats
        if stats.frames == 0:
            stats.first_picture_s = since_start_s
        elif late_s > self.frame_s:
            stats.stalls += 1
            stats.stall_s += late_s
        stats.frames += 1
        times = arrival_of(self.client.index.manifest, t)
        if times is not None:
            wall = time.time()
            stats.latencies_s.append(wall - times[0])
            stats.publish_s.append(wall - times[1])
