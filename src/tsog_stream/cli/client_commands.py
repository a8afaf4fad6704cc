"""CLI commands of the streaming client: ``tsog fetch`` and ``tsog play``.

Thin: parse arguments, call :mod:`tsog_stream.client`, print results; no logic of its own.
``tsog fetch`` is ``tsog frame`` on a stream with the bytes on the wire always reported.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from ..client import PlayStats, open_stream
from ..io.files import refuse_existing
from .common import Subparsers, add_common
from .progress import Progress
from .stream_commands import STREAM_HELP, stream_frame


def add_client_commands(sub: Subparsers) -> None:
    """Register ``fetch`` and ``play`` on the main parser."""
    p = sub.add_parser("fetch", help="fetch the frame at time T of a served container")
    p.add_argument("url", help=STREAM_HELP)
    p.add_argument("--t", type=float, required=True, help="time in seconds")
    p.add_argument(
        "-o", "--output", type=Path, required=True, help="frame.ply or frame.sog (or a folder)"
    )
    p.add_argument("-f", "--force", action="store_true", help="replace OUTPUT if it exists")
    add_common(p)

    p = sub.add_parser(
        "play",
        help="simulate playing a served container; report stalls",
        epilog="A stall is a frame whose chunks had not arrived by the time it was due (1/fps "
        "after the one before): a viewer would see the picture freeze. Startup latency is the "
        "wait for the first frame (opening the index included).",
    )
    p.add_argument("url", help=STREAM_HELP)
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


def cmd_fetch(args: argparse.Namespace, progress: Progress) -> int:
    """tsog fetch: one frame, reading only the chunks it needs."""
    refuse_existing(args.output, overwrite=args.force)
    stats = stream_frame(args.url, args.t, args.output, progress)
    print(f"{stats.requests} requests, {stats.bytes} bytes")
    return 0


def cmd_play(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog play: a simulated playback with startup latency, stalls and throughput."""
    progress(f"opening {args.url}")
    with open_stream(args.url) as client:
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
            f"stalls:          {stats.stalls} frames late, {stats.stall_s * 1000:.1f} ms in "
            "total (a stall: a frame whose chunks had not arrived when it was due, a freeze)",
            f"fetched:         {stats.bytes} bytes in {stats.requests} requests ({rate:.2f} MB/s)",
            f"cache hit rate:  {stats.hit_rate * 100:.1f}%",
        ]
    )
