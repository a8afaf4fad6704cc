"""CLI commands of the streaming client: ``tsog fetch`` and ``tsog play``.

Thin: parse arguments, call :mod:`tsog_stream.client`, print results; no logic of its own.
``tsog fetch`` is ``tsog frame`` on a stream with the bytes on the wire always reported.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..client import LiveStats, PlayStats, open_stream
from ..errors import InputError
from ..server.link import LinkShape, parse_bandwidth, parse_latency
from .common import (
    Subparsers,
    add_common,
    add_frame_output,
    add_timeout,
    check_file_output,
    note,
)
from .progress import Progress
from .stream_commands import STREAM_HELP, stream_frame

if TYPE_CHECKING:
    from ..throttled_play import LinkPlayReport


def add_client_commands(sub: Subparsers) -> None:
    """Register ``fetch`` and ``play`` on the main parser."""
    p = sub.add_parser("fetch", help="fetch the frame at time T of a served container")
    p.add_argument("url", help=STREAM_HELP)
    add_frame_output(p)
    add_timeout(p)
    add_common(p)

    p = sub.add_parser(
        "play",
        help="simulate playing a served container; report stalls",
        description="Play a stream as a viewer would and report what it cost. With --realtime "
        "or --bandwidth, a layered stream (tsog segment --layers) plays adaptively: the base "
        "layer is drawn as soon as it arrives (the first picture), playback waits a little "
        "for the layers the measured throughput keeps up with, then plays, dropping layers "
        "when the link slows and taking them back when it recovers.",
        epilog="A stall is a frame whose chunks had not arrived by the time it was due (1/fps "
        "after the one before; adaptive: whose base layer had not): a viewer would see the "
        "picture freeze. Startup latency is the wait for the first played frame. Example: "
        "tsog play clip.tsogs --start 3 --duration 5 --bandwidth 1Mbit --latency 50ms",
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
    p.add_argument(
        "--bandwidth",
        metavar="RATE",
        help="play in real time over a shaped loopback link of this rate (20Mbit, 500kbit, "
        "2MB/s) in front of the origin (a local file or folder is served on loopback first); "
        "also reports the PSNR of sampled shown frames against full quality",
    )
    p.add_argument(
        "--latency",
        metavar="DELAY",
        help="with --bandwidth: round trip added to every request (50ms, 0.2s; default 0)",
    )
    p.add_argument(
        "--full-quality",
        action="store_true",
        help="wait for every layer of each frame (no adaptation): the comparison",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="follow a live stream (tsog live) in real time from just behind its live edge "
        "until it ends or --duration passes; the report adds the latency from each frame's "
        "arrival in the source to its showing (p50/p95)",
    )
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="a progress line per frame and the whole report (startup, cache, layers shown)",
    )
    add_timeout(p)
    add_common(p)


def cmd_fetch(args: argparse.Namespace, progress: Progress) -> int:
    """tsog fetch: one frame, reading only the chunks it needs."""
    check_file_output(args.output, overwrite=args.force, file_suffix=".ply")
    stats = stream_frame(args.url, args.t, args.output, progress, timeout=args.timeout)
    print(f"{stats.requests} requests, {stats.bytes} bytes")
    return 0


def cmd_play(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog play: a simulated playback with startup latency, stalls and throughput."""
    if args.json and args.bandwidth is not None:
        raise InputError("prints the report of a playback without --bandwidth", where="--json")
    if args.live:
        return _play_live(args, progress)
    if args.bandwidth is not None:
        return _play_shaped(args, progress)
    if args.latency is not None:
        raise InputError("a latency needs a link: give --bandwidth too", where="--latency")
    progress(f"opening {args.url}")
    with open_stream(args.url, timeout=args.timeout) as client:
        playback = client.client.play(
            args.start,
            speed=args.speed,
            fps=args.fps,
            duration=args.duration,
            realtime=args.realtime,
            adaptive=args.realtime and not args.full_quality,
        )
        # keep nothing: each frame is dropped once reported (memory stays bounded by the cache)
        client.drain_playback(
            playback, lambda f: _on_frame(progress, _line(f.t, playback.stats), args.verbose)
        )
    _end_live_line(progress)
    if args.json:
        print(json.dumps(_report_json(playback.stats)))
    else:
        print(_report(playback.stats, EVERY if args.verbose else SHORT))
    return 0


def _report_json(stats: PlayStats) -> dict[str, object]:
    """A playback's report as ``tsog play --json`` prints it."""
    fields = ("frames", "first_picture_s", "startup_s", "stalls", "stall_s", "requests", "bytes")
    return {name: getattr(stats, name) for name in fields} | {"hit_rate": stats.hit_rate}


def _play_live(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog play --live: follow a live stream in real time; first picture, stalls, latency."""
    if args.bandwidth is not None or args.start != 0.0 or args.speed != 1.0:
        raise InputError("follows the live edge in real time", where="--live")
    began = time.monotonic()
    progress(f"opening {args.url}")
    with open_stream(args.url, timeout=args.timeout) as client:
        opened = time.monotonic() - began
        if not client.is_live:
            note("the stream is not live (recorded, or its event ended): playing it from its end")
        stats = client.follow_live(
            fps=args.fps,
            duration_s=args.duration,
            on_frame=lambda t, s: _on_frame(progress, _live_line(t, s), args.verbose),
        )
    _end_live_line(progress)
    report = stats.as_dict() | {"first_picture_s": round(opened + stats.first_picture_s, 4)}
    if args.json:
        print(json.dumps(report))
        return 0
    for name, value in report.items():
        print(f"{name.replace('_', ' ') + ':':<24}{value}")
    return 0


def _live_line(t: float, stats: LiveStats) -> str:
    """The progress line of a live follow."""
    latency = f", latency {stats.latencies_s[-1]:.2f} s" if stats.latencies_s else ""
    return f"t = {t:7.3f} s, frame {stats.frames}, {stats.stalls} stalls{latency}"


def _play_shaped(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """tsog play --bandwidth: the playback through a shaped loopback link, with quality."""
    from ..throttled_play import play_through_link  # noqa: PLC0415 - a server and the renderer

    shape = LinkShape(
        parse_bandwidth(args.bandwidth),
        parse_latency(args.latency) if args.latency is not None else 0.0,
    )
    progress(f"opening {args.url} over {shape.describe()}")
    report = asyncio.run(
        play_through_link(
            args.url,
            shape,
            start=args.start,
            duration=args.duration,
            speed=args.speed,
            fps=args.fps,
            adaptive=not args.full_quality,
            on_frame=lambda f, stats: _on_frame(
                progress, f"{_line(f.t, stats)}, {f.layers} layers", args.verbose
            ),
        )
    )
    _end_live_line(progress)
    print(
        f"link:            {shape.describe()} (full quality needs "
        f"{report.full_bitrate_bps / 1e6:.2f} Mbit/s on average)"
    )
    if args.verbose:
        print(f"opening:         {report.opened_s * 1000:.1f} ms")
    print(_report(report.stats, EVERY if args.verbose else (*SHORT, "layers shown")))
    print(_quality_line(report, every=args.verbose))
    return 0


def _on_frame(progress: Callable[[str], None], line: str, verbose: bool) -> None:
    """A played frame's progress: a line each with ``-v`` (or to a plain callable), else a
    status line redrawn on a terminal and in a log one every few seconds."""
    if isinstance(progress, Progress) and not verbose:
        progress.tick(line)
    else:
        progress(line)


def _end_live_line(progress: Callable[[str], None]) -> None:
    """End the redrawn status line before the report is printed."""
    if isinstance(progress, Progress):
        progress.done()


def _quality_line(report: LinkPlayReport, *, every: bool) -> str:
    """The sampled shown frames' worst PSNR against full quality (``every``: and each)."""
    if not report.quality:
        return "quality:         not measured (the scene has no view to render from)"

    def shown(db: float) -> str:
        return "full" if math.isinf(db) else f"{db:.1f} dB"

    each = ", ".join(f"t={t:.2f} s: {shown(db)}" for t, _, db in report.quality)
    worst = f"quality:         worst {shown(report.worst_psnr)} against full quality"
    return f"{worst} ({each})" if every else worst


def _line(t: float, stats: PlayStats) -> str:
    """The live progress line of a playback."""
    return (
        f"t = {t:7.3f} s, frame {stats.frames}, {stats.stalls} stalls, "
        f"{stats.bytes / 1e6:.2f} MB in {stats.requests} requests"
    )


SHORT = ("frames", "first picture", "stalls", "fetched")
"""The lines of a playback's report printed by default."""
EVERY = (*SHORT[:2], "startup latency", *SHORT[2:], "cache hit rate", "layers shown")
"""The lines printed with ``-v``."""


def _report(stats: PlayStats, lines: tuple[str, ...]) -> str:
    """The named lines of what a playback cost, in the order of EVERY."""
    rate = stats.bytes / stats.elapsed_s / 1e6 if stats.elapsed_s > 0 else 0.0
    values = {
        "frames": f"{stats.frames}",
        "first picture": f"{stats.first_picture_s * 1000:.1f} ms",
        "startup latency": f"{stats.startup_s * 1000:.1f} ms",
        "stalls": f"{stats.stalls} frames late, {stats.stall_s * 1000:.1f} ms in total (a stall: "
        "a frame whose chunks had not arrived when it was due, a freeze)",
        "fetched": f"{stats.bytes} bytes in {stats.requests} requests ({rate:.2f} MB/s)",
        "cache hit rate": f"{stats.hit_rate * 100:.1f}%",
        "layers shown": ", ".join(
            f"{n} frames with {k}" for k, n in sorted(stats.layers_shown.items())
        ),
    }
    return "\n".join(f"{name + ':':<17}{values[name]}" for name in EVERY if name in lines)
