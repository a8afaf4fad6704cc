"""``tsog``: encode, decode, inspect and export TSOG/SOG scenes from the command line.

Each subcommand parses its arguments, calls the library and prints a short result. User
mistakes and bad files end in one line on stderr and exit status 1 (2 for usage errors).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._version import __version__
from ..codec.chunk import decode_chunk_timeline, encode_chunk
from ..codec.precision import DEFAULT_QUALITY, without_faint
from ..codec.webp import use_cores
from ..errors import TsogError, printable
from ..inputs import STREAM_KINDS, input_kind
from ..io.chunks import read_chunk_files, write_chunk_files
from ..io.files import check_output
from ..io.fourdgs import write_4dgs
from ..io.ply import write_ply
from ..machine import usable_cores
from ..summary import cameras_summary, chunk_summary, scene_summary, timeline_summary
from ..temporal import time_range
from . import interrupt
from .client_commands import add_client_commands, cmd_fetch, cmd_play
from .common import (
    QUALITY,
    QUALITY_HELP,
    SEED,
    Subparsers,
    add_cameras,
    add_common,
    add_force,
    add_frame_output,
    add_input,
    add_timeout,
    check_file_output,
    check_time,
    load_input,
    local_file,
    note,
)
from .live_command import add_live_command, cmd_live
from .progress import Progress
from .render_commands import add_render_commands, cmd_eval, cmd_render
from .serve_commands import add_serve_command, add_sign_command, cmd_serve, cmd_sign
from .stream_commands import (
    add_stream_commands,
    cmd_extract,
    cmd_pack,
    cmd_segment,
    cmd_unpack,
    cmd_verify,
    stream_frame,
    stream_info,
    write_frame,
)
from .view_command import add_view_command, cmd_view

EPILOG = """examples:
  tsog view clip.splatv --open                open any input in the web player
  tsog demo                                   generate, encode, decode and report
  tsog encode scene.ply scene.sog             static 3DGS PLY -> bundled SOG v2
  tsog encode chunk.sog out/                  re-encode into an unbundled folder
  tsog encode clip.splatv clip.4dgs --lossy   write .4dgs (drops motion it cannot hold)
  tsog segment frames/ --fps 30 -o c.tsogs    segment into a stream container
  tsog live capture/ --fps 30 -o live/        publish frames as they are written
  tsog frame c.tsogs --t 2 -o f.ply -v        read only the chunks t needs
  tsog decode scene.sog scene.ply             back to a float PLY (base values)
  tsog info scene.sog                         count, SH bands, timeline, sizes
  tsog frame scene.sog --t 1.5 -o f.ply       the scene at t = 1.5 s as a static file

Times are in seconds everywhere. Inputs are recognised by content; --format overrides."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="tsog",
        description="Store and stream dynamic (4D) Gaussian Splatting scenes as TSOG.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"tsog-stream {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_file_commands(sub)
    add_stream_commands(sub)
    add_live_command(sub)
    add_client_commands(sub)
    add_serve_command(sub)
    add_sign_command(sub)
    add_render_commands(sub)
    add_view_command(sub)
    p = sub.add_parser("demo", help="generate a 4D scene, encode it to TSOG, decode it, report")
    p.add_argument(
        "--out", type=local_file, default=Path("out"), help="folder for demo.sog (default ./out)"
    )
    p.add_argument("--seed", type=SEED, default=0, help="scene and palette seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    add_common(p)
    return parser


def _add_file_commands(sub: Subparsers) -> None:
    """encode, decode, info and frame: the commands on a scene file."""
    p = sub.add_parser("encode", help="encode a scene to a SOG/TSOG chunk (.sog zip or folder)")
    add_input(p)
    p.add_argument(
        "output", type=local_file, help="OUT.sog for a bundled zip, any other path for a folder"
    )
    p.add_argument("--seed", type=SEED, default=0, help="seed of the SH palette fit (default 0)")
    p.add_argument("--quality", type=QUALITY, default=DEFAULT_QUALITY, help=QUALITY_HELP)
    p.add_argument(
        "--lossy",
        action="store_true",
        help="OUT.4dgs only: drop motion .4dgs cannot hold instead of refusing",
    )
    add_force(p)
    add_common(p)
    p = sub.add_parser("decode", help="decode a chunk to a float 3DGS PLY (base values)")
    add_input(p)
    p.add_argument("output", type=local_file, help="output .ply")
    add_common(p)
    p = sub.add_parser(
        "info", help="describe a file: count, SH bands, timeline, image sizes, bytes, cameras"
    )
    add_input(p)
    add_cameras(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    add_timeout(p)
    add_common(p)
    p = sub.add_parser("frame", help="export the scene at time t as a static PLY or SOG")
    add_input(p)
    add_frame_output(p)
    p.add_argument("-v", "--verbose", action="store_true", help="report the bytes read")
    add_timeout(p)
    add_common(p)


def cmd_encode(args: argparse.Namespace, progress: Progress) -> int:
    """tsog encode."""
    check_file_output(args.output, overwrite=args.force, file_suffix=".4dgs")
    scene = load_input(args, progress).scene
    if args.output.suffix.lower() == ".4dgs":
        for text in write_4dgs(args.output, scene, lossy=args.lossy):
            note(text)
        progress.done()
        print(f"{args.output}: {len(scene)} Gaussians, {args.output.stat().st_size} bytes")
        return 0
    stored = without_faint(scene, args.quality)
    files = encode_chunk(stored, seed=args.seed, progress=progress, quality=args.quality)
    size = write_chunk_files(args.output, files, overwrite=True)
    progress.done()
    left_out = len(scene) - len(stored)
    faint = f" ({left_out} too faint at quality {args.quality} left out)" if left_out else ""
    print(f"{args.output}: {len(stored)} Gaussians, {size} bytes{faint}")
    return 0


def cmd_decode(args: argparse.Namespace, progress: Progress) -> int:
    """tsog decode."""
    check_output(args.output, overwrite=True)  # decode replaces OUTPUT, as it always has
    scene = load_input(args, progress).scene
    write_ply(args.output, scene.gaussians)
    progress.done()
    print(f"{args.output}: {len(scene)} Gaussians")
    return 0


def _print_text(info: dict[str, Any], indent: str = "") -> None:
    """A nested summary as indented 'key: value' lines, values escaped for the terminal."""
    for key, value in info.items():
        if isinstance(value, dict):
            print(f"{indent}{key}:")
            _print_text(value, indent + "  ")
        else:
            print(f"{indent}{key}: {printable(str(value))}")


def _print_seek_table(rows: list[dict[str, Any]]) -> None:
    """The seek-cost rows of a stream as a text table."""
    head = ("t (s)", "chunks", "requests", "bytes", "% file", "visible", "vis bytes", "overfetch")
    print("seek costs:")
    print("  " + " ".join(f"{h:>10}" for h in head))
    for r in rows:
        cells = (r["t"], r["chunks"], r["requests"], r["bytes"], r["percent_of_file"])
        more = (r["visible"], r["visible_bytes"], r["overfetch"])
        print("  " + " ".join(f"{c:>10}" for c in (*cells, *more)))


def cmd_info(args: argparse.Namespace, progress: Progress) -> int:
    """tsog info."""
    kind = input_kind(args.input, args.format)
    info: dict[str, Any] = {"file": str(args.input), "format": kind}
    if kind in STREAM_KINDS:
        progress("measuring seek costs")
        info = stream_info(args.input, args.timeout)
    elif kind == "sog":
        files = read_chunk_files(Path(args.input))
        info.update(chunk_summary(files, where=str(args.input)))
        progress("decoding the timeline")
        timeline = decode_chunk_timeline(files, where=str(args.input))
        if timeline is not None:
            info["timeline"] = timeline_summary(timeline)
    else:
        loaded = load_input(args, progress)
        info.update(scene_summary(loaded.scene, duration_assumed=loaded.duration_assumed))
        info["cameras"] = cameras_summary(loaded.cameras, loaded.cameras_source)
    progress.done()
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    seek = info.pop("seek_costs", None)
    _print_text(info)
    if seek:
        _print_seek_table(seek)
    return 0


def cmd_frame(args: argparse.Namespace, progress: Progress) -> int:
    """tsog frame."""
    check_file_output(args.output, overwrite=args.force, file_suffix=".ply")
    if input_kind(args.input, args.format) in STREAM_KINDS:
        stats = stream_frame(args.input, args.t, args.output, progress, timeout=args.timeout)
        if args.verbose:
            print(f"read {stats.bytes} bytes in {stats.requests} requests", file=sys.stderr)
        return 0
    scene = load_input(args, progress).scene
    check_time(args.t, time_range(scene.timeline) if scene.timeline is not None else None)
    progress(f"evaluating t = {args.t} s")
    frame = scene.at(args.t)
    write_frame(args.output, frame, args.t, progress)
    return 0


def cmd_demo(args: argparse.Namespace, progress: Progress) -> int:
    """tsog demo."""
    from ..demo import run_demo  # noqa: PLC0415 - segmenter, server and client: the demo's own

    report = run_demo(args.out, seed=args.seed, progress=progress)
    progress.done()
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_demo(report)
    return 0


def _print_demo(report: dict[str, Any]) -> None:
    """The demo report as a short text table."""
    print(f"scene: {report['gaussians']} Gaussians, timeline type {report['timeline_type']}")
    print(f"TSOG chunk: {report['tsog_bytes']} bytes -> {report['output']}")
    saving = report["saving_percent"]
    print(f"extended PLY: {report['extended_ply_bytes']} bytes ({saving}% smaller as TSOG)")
    s = report["stream"]
    print(
        f"stream: {s['bytes']} bytes, {s['windows']} windows, {s['chunks']} chunks -> {s['output']}"
    )
    print(f"served at {s['url']} (loopback, stopped after the run)")
    print(f"  played {s['frames']} frames from t = {s['start_t']} s at 2x speed")
    print(f"  startup {s['startup_ms']} ms, {s['stalls']} stalls, {s['requests']} requests,")
    print(f"  {s['bytes_fetched']} bytes, cache hit rate {s['cache_hit_rate']:.0%}")
    print(f"  frames differing from local reads: {s['mismatches']}")
    print("errors after encode/decode (positions: scene units, rotations: degrees, opacity: alpha)")
    head = ("t (s)", "visible", "pos max", "rot max", "scale max", "alpha max", "flips")
    print(" ".join(f"{h:>9}" for h in head))
    cells = (
        "{t:9.2f} {count:9.0f} {means_max:9.5f} {rotation_deg_max:9.3f} {scales_max:9.4f} "
        "{opacity_max:9.4f} {visibility_flips:9d}"
    )
    for row in report["errors"]:
        print(cells.format(**row))
    if s["output"]:
        print(f"watch it in the web player: {_tsog_command()} view {printable(s['output'])}")


def _tsog_command() -> str:
    """How to run tsog again: its name when it is on PATH, else the path it was run by."""
    ran = Path(sys.argv[0])
    return "tsog" if shutil.which("tsog") or ran.name != "tsog" else printable(str(ran))


COMMANDS = {
    "encode": cmd_encode,
    "decode": cmd_decode,
    "info": cmd_info,
    "frame": cmd_frame,
    "demo": cmd_demo,
    "segment": cmd_segment,
    "live": cmd_live,
    "verify": cmd_verify,
    "extract": cmd_extract,
    "unpack": cmd_unpack,
    "pack": cmd_pack,
    "fetch": cmd_fetch,
    "play": cmd_play,
    "serve": cmd_serve,
    "sign": cmd_sign,
    "render": cmd_render,
    "eval": cmd_eval,
    "view": cmd_view,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tsog`` console script."""
    args = build_parser().parse_args(argv)
    progress = Progress(quiet=args.quiet)
    interrupt.quiet_resource_tracker()
    use_cores(usable_cores())  # a container's CPU quota, which the codec does not read
    try:
        with interrupt.latched():
            return COMMANDS[args.command](args, progress)
    except TsogError as exc:
        progress.done()
        print(f"tsog: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        progress.done()
        print("tsog: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of our output left (tsog info x | head): nothing more to say, and the
        # interpreter must not fail again flushing stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    finally:
        progress.close()


if __name__ == "__main__":
    sys.exit(main())
