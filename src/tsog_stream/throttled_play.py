"""Play a stream over a shaped link and measure what a viewer sees (``tsog play --bandwidth``).

The link is a :class:`~tsog_stream.server.link.ThrottledRelay` in front of the origin (a local
container or folder is served on loopback first). The report has the playback's figures and
the rendered PSNR of sampled shown frames against the same frames with every layer.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlsplit

from .client import Playback, PlayedFrame, PlayStats, StreamClient
from .errors import InputError, TsogError
from .render import from_capture, render, to_uint8
from .render.metrics import psnr
from .server import make_app, start_server
from .server.link import LinkShape, ThrottledRelay

SAMPLES = 8
"""Shown frames (evenly spread) compared with full quality."""
SAMPLE_WIDTH = 320
"""Width in pixels of the renders compared."""


@dataclass
class LinkPlayReport:
    """A playback over a shaped link: its figures and the quality of sampled shown frames."""

    shape: LinkShape
    opened_s: float
    """Wall seconds to open the stream (the 16 KiB index request) over the link."""
    stats: PlayStats
    full_bitrate_bps: float
    """The stream's size over the scene's length: the bitrate full quality needs on average."""
    quality: list[tuple[float, int, float]] = field(default_factory=list)
    """(t, layers shown, PSNR in dB against all layers; inf when identical) of sampled frames."""

    @property
    def worst_psnr(self) -> float:
        """The lowest PSNR of the sampled frames (inf when all were full quality or none)."""
        return min((db for _, _, db in self.quality), default=math.inf)


@contextlib.asynccontextmanager
async def _origin(target: str) -> AsyncIterator[tuple[str, int, str]]:
    """(host, port, path) of an http origin for ``target``: the URL's own, or the real server
    started on loopback for a local file or folder."""
    parts = urlsplit(target)
    if parts.scheme.lower() == "https":
        raise InputError("a shaped link relays plain http; give an http:// URL or a local path")
    if parts.scheme.lower() == "http":
        port = parts.port or 80
        path = parts.path + (f"?{parts.query}" if parts.query else "")
        yield parts.hostname or "127.0.0.1", port, path
        return
    local = Path(unquote(parts.path) if parts.scheme.lower() == "file" else target)
    if not local.exists():
        raise InputError("no such file or folder", where=str(local))
    root = local.parent if local.name == "manifest.json" else local
    runner, port = await start_server(make_app(root))
    try:
        yield "127.0.0.1", port, "/files/" if root.is_dir() else f"/files/{root.name}"
    finally:
        await runner.cleanup()


async def play_through_link(
    target: str | os.PathLike[str],
    shape: LinkShape,
    *,
    start: float = 0.0,
    duration: float | None = None,
    speed: float = 1.0,
    fps: float = 30.0,
    adaptive: bool = True,
    on_frame: Callable[[PlayedFrame, PlayStats], None] | None = None,
) -> LinkPlayReport:
    """Play ``target`` in real time through a link of ``shape``, sampling shown frames."""
    async with _origin(os.fspath(target)) as (host, port, path):
        async with ThrottledRelay(port, shape, host) as relay:
            relayed = relay.url(path)
            began = time.monotonic()
            try:
                async with await StreamClient.open(relayed) as client:
                    opened = time.monotonic() - began
                    playback = client.play(
                        start,
                        speed=speed,
                        fps=fps,
                        duration=duration,
                        realtime=True,
                        adaptive=adaptive,
                    )
                    samples = await _sampled(playback, fps, duration, on_frame)
            except TsogError as exc:
                raise _naming(exc, relayed, os.fspath(target)) from None
        m = client.index.manifest
        length = m.scene.end_s - m.scene.start_s
        bitrate = client.index.size * 8 / length if length > 0 else math.inf
        report = LinkPlayReport(shape, opened, playback.stats, bitrate)
        async with await StreamClient.open(f"http://{host}:{port}{path}") as direct:
            report.quality = await _compare(direct, samples)
    return report


def _naming(exc: TsogError, relayed: str, target: str) -> TsogError:
    """``exc`` naming the target the user gave rather than the relay URL it was read through."""
    if exc.where is not None and exc.where.startswith(relayed):
        exc.where = target + exc.where[len(relayed) :]
        exc.args = (f"{exc.where}: {exc.message}",)
    return exc


async def _sampled(
    playback: Playback,
    fps: float,
    duration: float | None,
    on_frame: Callable[[PlayedFrame, PlayStats], None] | None,
) -> list[PlayedFrame]:
    """Run the playback, keeping about SAMPLES frames spread over it (every ``every``-th)."""
    every = max(1, round(fps * duration / SAMPLES)) if duration else max(1, round(fps))
    kept: list[PlayedFrame] = []
    async for frame in playback:
        if frame.index % every == 0:
            kept.append(frame)
        if on_frame is not None:
            on_frame(frame, playback.stats)
    step = max(1, len(kept) // SAMPLES)
    return kept[::step][:SAMPLES]


async def _compare(
    direct: StreamClient, samples: list[PlayedFrame]
) -> list[tuple[float, int, float]]:
    """PSNR of each sampled frame against the frame at the same time with every layer."""
    view = direct.index.manifest.view
    if view is None or not samples:
        return []
    camera = from_capture(view, SAMPLE_WIDTH)
    out = []
    for frame in samples:
        if frame.layers >= direct.index.layer_count:
            out.append((frame.t, frame.layers, math.inf))  # every layer: the full frame itself
            continue
        full = await direct.frame_at(frame.t)
        drawn = [to_uint8(render(g, camera)) for g in (frame.gaussians, full)]
        out.append((frame.t, frame.layers, psnr(*drawn)))
    return out
