"""What a simulated playback is asked for and what it reports: its plan (checked options),
its frames and its stats. The frames themselves are :meth:`StreamClient.play`'s."""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from ..errors import InputError
from ..model import Gaussians
from ..schemas.manifest import SceneInfo
from .adaptive import HORIZON_S

MAX_PLAY_FRAMES = 1_000_000
"""Frames one simulated playback may have (9 hours at 30 fps): a bound, so that no choice of
speed and fps makes one that never ends."""


@dataclass
class PlayStats:
    """What a playback cost: startup latency, stalls, transfer and cache behaviour; for an
    adaptive one also when the first picture came and how many layers each frame showed."""

    frames: int = 0
    startup_s: float = 0.0
    first_picture_s: float = 0.0
    """Wait for the first picture (the base layer at the start time; = startup_s when not
    adaptive)."""
    layers_shown: dict[int, int] = field(default_factory=dict)
    """Frames shown with each number of layers."""
    stalls: int = 0
    stall_s: float = 0.0
    requests: int = 0
    bytes: int = 0
    hit_rate: float = 0.0
    elapsed_s: float = 0.0


@dataclass(frozen=True)
class PlayedFrame:
    """One frame of a playback: its number, scene time, Gaussians and wait for data."""

    index: int
    t: float
    gaussians: Gaussians
    wait_s: float
    layers: int = 1
    """Quality layers drawn (all of the stream's when not adaptive)."""


@dataclass
class Playback:
    """An async iterator of played frames; ``stats`` fills in as it runs."""

    frames: AsyncIterator[PlayedFrame]
    stats: PlayStats = field(default_factory=PlayStats)

    def __aiter__(self) -> AsyncIterator[PlayedFrame]:
        return self.frames


@dataclass(frozen=True)
class PlayPlan:
    """Frame times, budget and prefetch horizon of one playback."""

    start: float
    end: float
    count: int
    step: float
    """Scene seconds between frames."""
    budget: float
    """Wall seconds per frame (1 / fps)."""
    horizon: float
    realtime: bool
    adaptive: bool
    speed: float


def plan_playback(
    scene: SceneInfo,
    start: float,
    *,
    speed: float,
    fps: float,
    duration: float | None,
    horizon_s: float,
    realtime: bool,
    adaptive: bool,
) -> PlayPlan:
    """The plan of a playback of ``scene`` (see :meth:`StreamClient.play`), or an InputError
    naming the option that is not finite, not positive where it must be, or out of range."""
    checks = {
        "--start": math.isfinite(start),
        "--speed": math.isfinite(speed) and speed > 0,
        "--fps": math.isfinite(fps) and fps > 0,
        "--duration": duration is None or (math.isfinite(duration) and duration >= 0),
        "horizon_s": math.isfinite(horizon_s) and horizon_s >= 0,
    }
    for name, ok in checks.items():
        if not ok:
            raise InputError("expected a finite number, positive for speed and fps", where=name)
    if not scene.start_s <= start <= scene.end_s:
        raise InputError(
            f"{start:g} s is outside the scene, which runs from {scene.start_s:g} to "
            f"{scene.end_s:g} s",
            where="--start",
        )
    end = start + duration * speed if duration is not None else scene.end_s
    frames = max((end - start) * fps / speed + 1e-9, 0.0) + 1
    if frames > MAX_PLAY_FRAMES:
        raise InputError(
            f"{frames:.3g} frames to play (at most {MAX_PLAY_FRAMES}): raise --speed, or "
            "lower --fps or --duration"
        )
    horizon = max(horizon_s, HORIZON_S * speed) if adaptive else horizon_s
    return PlayPlan(
        start,
        end,
        int(frames),
        speed / fps,
        1.0 / fps,
        horizon,
        realtime or adaptive,
        adaptive,
        speed,
    )
