"""CLI commands of the streaming client: ``tsog fetch`` and ``tsog play``.

Thin: parse arguments, call :mod:`tsog_stream.client`, print results; no logic of its own.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..io.files import refuse_existing
from ..io.ply import write_ply
from .stream import PlayStats
from .sync import open_url


def add_client_commands(sub: Any, add_common: Callable[[argparse.ArgumentParser], None]) -> None:
    """Register ``fetch`` and ``play`` on the main parser."""
    p = sub.add_parser("fetch", help="fetch the frame at time T of a served container as a PLY")
    p.add_argument("url", help="http(s):// URL, file:// URL or path of a .tsogs container")
    p.add_argument("--t", type=float, required=True, help="time in seconds")
    p.add_argument("-o", "--output", type=Path, required=True, help="the PLY to write")
    p.add_argument("-f", "--force", action="store_true", help="replace OUTPUT if it exists")
    add_common(p)

    p = sub.add_parser("play", help="simulate playing a served container; report stalls")
    p.add_argument("url", help="http(s):// URL, file:// URL or path of a .tsogs container")
    p.add_argument("--start", type=float, default=0.0, help="start time in seconds (default 0)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1)")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="wall-clock seconds of playback (scene time = duration x speed; default: to the end)",
    )
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--realtime", action="store_true", help="pace frames in real time")
    add_common(p)


def cmd_fetch(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog fetch: one frame, reading only the chunks it needs."""
    refuse_existing(args.output, overwrite=args.force)
    progress(f"opening {args.url}")
    with open_url(args.url) as client:
        progress(f"fetching t = {args.t} s")
        frame = client.frame_at(args.t)
        stats = client.client.source.stats
    write_ply(args.output, frame)
    print(f"{args.output}: {len(frame)} Gaussians visible at t = {args.t} s")
    print(f"{stats.requests} requests, {stats.bytes} bytes")
    return 0


def cmd_play(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog play: a simulated playback with startup latency, stalls and throughput."""
    progress(f"opening {args.url}")
    with open_url(args.url) as client:
        playback = client.client.play(
            args.start,
            speed=args.speed,
            fps=args.fps,
            duration=args.duration,
            realtime=args.realtime,
        )
        # keep nothing: each frame is dropped once reported (memory stays bounded by the cache)
        client.drain_playback(playback, lambda f: progress(_line(f.t, playback.stats)))
    print(_report(playback.stats))
    return 0


def _line(t: float, stats: PlayStats) -> str:
    """The live progress line of a playback."""
    return (
        f"t = {t:7.3f} s, frame {stats.frames}, {stats.stalls} stalls, "
        f"{stats.bytes / 1e6:.2f} MB in {stats.requests} requests"
    )


def _report(stats: PlayStats) -> str:
    """The summary printed after a playback."""
    rate = stats.bytes / stats.elapsed_s / 1e6 if stats.elapsed_s > 0 else 0.0
    return "\n".join(
        [
            f"frames:          {stats.frames}",
            f"startup latency: {stats.startup_s * 1000:.1f} ms",
            f"stalls:          {stats.stalls} ({stats.stall_s * 1000:.1f} ms in total)",
            f"fetched:         {stats.bytes} bytes in {stats.requests} requests ({rate:.2f} MB/s)",
            f"cache hit rate:  {stats.hit_rate * 100:.1f}%",
        ]
    )
