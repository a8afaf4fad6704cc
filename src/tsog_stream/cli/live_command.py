"""``tsog live``: follow a folder that frames are written into and publish a live stream."""

from __future__ import annotations

import argparse
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from ..client import open_stream
from ..io.arrivals import END_MARKER, SETTLE_S
from ..io.files import check_output
from ..io.objects import is_object_url
from ..segment.engines import default_workers
from ..segment.live import (
    DEFAULT_IDLE_S,
    DEFAULT_WINDOW_S,
    MAX_WINDOW_S,
    LiveOptions,
    run_live,
)
from .common import Integer, Seconds, Subparsers, add_chunk_options, add_common
from .progress import Progress

EPILOG = f"""examples:
  tsog live capture/ -o live/ --fps 30          publish into live/, then: tsog serve live/
  tsog live capture/ -o s3://bucket/event/ --fps 30 --window 0.5

A frame is a numbered PLY or SOG file of SOURCE; it counts once unchanged for {SETTLE_S:g} s
(write it under another name, then rename it in). The event ends on a file named {END_MARKER}
in SOURCE, after --idle seconds without a frame, or on Ctrl-C / SIGTERM; the last window is
published and the index marked ended. Run again with the same arguments after a crash: it
resumes after the last published window."""


def add_live_command(sub: Subparsers) -> None:
    """Register ``live``."""
    p = sub.add_parser(
        "live",
        help="follow frames as they are written into a folder and publish a live stream",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("source", help="the folder frames are written into")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the unpacked stream to publish (manifest.json + chunks/): a folder or a storage "
        "prefix (s3://bucket/event/)",
    )
    p.add_argument("--fps", type=float, required=True, help="frames per second of SOURCE")
    p.add_argument(
        "--window",
        type=Seconds(MAX_WINDOW_S),
        default=DEFAULT_WINDOW_S,
        metavar="SECONDS",
        help="window length, rounded to whole frames: a frame waits for its window to be "
        f"complete, so latency is about this plus the encoding (default {DEFAULT_WINDOW_S:g})",
    )
    p.add_argument(
        "--idle",
        type=Seconds(),
        default=DEFAULT_IDLE_S,
        metavar="SECONDS",
        help=f"end the event after this long without a new frame (default {DEFAULT_IDLE_S:g})",
    )
    p.add_argument(
        "--workers",
        type=Integer(1, 256),
        default=default_workers(),
        help="encoder processes, one window each (default: one per usable core, %(default)s here)",
    )
    add_chunk_options(p)
    p.add_argument(
        "--pack",
        metavar="FILE",
        help="when the event ends, also write the stream as one .tsogs container (a path or "
        "storage URL), the file to keep or to hand to any static origin",
    )
    p.add_argument(
        "-f",
        "--force",
        action="store_true",
        help="replace a finished stream at OUTPUT (an unfinished one is resumed without it)",
    )
    add_common(p)


def cmd_live(args: argparse.Namespace, progress: Progress) -> int:
    """tsog live: follow SOURCE until the event ends; print what was published."""
    if is_object_url(args.output):
        check_output(f"{args.output.rstrip('/')}/chunks/000000.sog", overwrite=True)
    else:
        check_output(args.output, overwrite=True, folder=True)
    if args.pack is not None:
        check_output(args.pack, overwrite=args.force)
    options = LiveOptions(
        fps=args.fps,
        window_s=args.window,
        idle_s=args.idle,
        workers=args.workers,
        seed=args.seed,
        quality=args.quality,
        max_pixels=args.max_pixels,
    )
    with _stopped_by_signals() as stop:
        report = run_live(
            args.source, args.output, options, stop=stop, on_stage=progress, overwrite=args.force
        )
    progress.done()
    resumed = (
        f", {report.resumed_windows} of them before a restart" if report.resumed_windows else ""
    )
    print(
        f"{report.output}: {report.windows} windows{resumed}, {report.frames} frames, "
        f"{report.chunks} chunks, {report.payload_bytes} bytes (ended: {report.ended_by})"
    )
    if args.pack is not None:
        progress(f"packing {args.pack}")
        with open_stream(args.output) as stream:
            size = stream.pack(args.pack)
        progress.done()
        print(f"{args.pack}: {size} bytes")
    return 0


@contextmanager
def _stopped_by_signals() -> Iterator[threading.Event]:
    """An event set by the first SIGINT or SIGTERM (the event then ends cleanly); a second
    SIGINT interrupts at once."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
