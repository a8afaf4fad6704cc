"""CLI commands on segmented streams: segment, verify, extract, pack, unpack, info, frame.

Every command that reads a stream opens it with :func:`tsog_stream.client.open_stream`, so a
path, a ``file://`` URL or an http(s) URL of a ``.tsogs`` file or an unpacked folder all work.
"""

from __future__ import annotations

import argparse
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..client import Stream, open_stream
from ..codec.chunk import encode_chunk
from ..codec.precision import DEFAULT_QUALITY
from ..container.sources import ReadStats
from ..errors import InputError
from ..io.chunks import write_chunk_files
from ..io.files import atomic_write_bytes, check_output
from ..io.objects import is_object_url
from ..io.ply import write_ply
from ..merge import TEMPORAL_MODES, Tolerance
from ..model import Gaussians, Scene
from ..pipeline import InputOptions, segment_input
from ..schemas.manifest import Layer
from ..segment import SegmentOptions
from ..segment.engines import WORKER_MEMORY, check_cluster, default_workers
from ..segment.layers import AUTO_LAYERS, LAYER_TARGETS_DB, LAYERED_MIN_GAUSSIANS, MAX_LAYERS
from ..segment.plan import POLICIES
from ..summary import cameras_summary
from .common import (
    Integer,
    Subparsers,
    Told,
    add_cameras,
    add_chunk_options,
    add_common,
    add_input,
    add_timeout,
    check_time,
    read_options,
    scene_duration,
)
from .progress import Progress
from .segment_report import print_segment_report

DEFAULT_TEMPORAL = InputOptions().temporal
STREAM_HELP = (
    "a .tsogs container or unpacked folder: path, file:// URL or http(s):// URL "
    "(a folder URL ends with / or /manifest.json)"
)
AUTO = "auto"
_WINDOW = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*(s|f)?\s*$")


def check_segment_args(args: argparse.Namespace) -> None:
    """Refuse bad options and an unwritable output before the (possibly long) input read."""
    check_output(args.output, overwrite=args.force)
    parse_window(args.window)
    if args.cluster is not None:
        check_cluster(args.cluster)
    tolerance_option(args)


def parse_window(text: str) -> tuple[float | None, float | None]:
    """'1s', '0.5' -> (seconds, None); '30f' -> (None, frames); 'auto' -> (None, None)."""
    if text == AUTO:
        return None, None
    m = _WINDOW.match(text)
    if not m:
        raise InputError(
            f"expected seconds like 1s or frames like 30f, got {text!r}", where="--window"
        )
    value = float(m.group(1))
    if value <= 0:
        raise InputError("must be positive", where="--window")
    return (None, value) if m.group(2) == "f" else (value, None)


def add_stream_commands(sub: Subparsers) -> None:
    """Register the stream subcommands on the main parser."""
    p = sub.add_parser(
        "segment",
        help="segment a scene into a streamable .tsogs container (a static one: one moment)",
    )
    _add_segment_layout(p)
    _add_segment_encoding(p)
    p.add_argument("-f", "--force", action="store_true", help="replace OUTPUT if it exists")
    add_common(p)
    p = sub.add_parser("verify", help="check a container: hashes, decoding, pixel budget, index")
    p.add_argument("input", help=STREAM_HELP)
    add_timeout(p)
    add_common(p)
    p = _copying(sub, "extract", "copy one chunk of a container out as a standalone .sog")
    p.add_argument("chunk", type=Integer(0, 2**31 - 1), help="chunk id (see tsog info)")
    _copying(sub, "unpack", "container -> folder with manifest.json and chunks/*.sog")
    _copying(sub, "pack", "unpacked folder -> container (the exact bytes unpack started from)")


COPY_HELP = {
    "extract": (STREAM_HELP, "the .sog to write (path or storage URL)"),
    "unpack": (
        STREAM_HELP,
        "the folder to write, or a storage prefix for a CDN (s3://bucket/scene/): chunks "
        "first, manifest.json last",
    ),
    "pack": (
        "the unpacked folder (path or URL; any stream works)",
        "the container to write (path or storage URL)",
    ),
}
"""INPUT and OUTPUT of the commands that copy a stream's bytes."""


def _copying(sub: Subparsers, name: str, about: str) -> argparse.ArgumentParser:
    """A command copying a stream's bytes from INPUT to -o OUTPUT."""
    p = sub.add_parser(name, help=about)
    p.add_argument("input", help=COPY_HELP[name][0])
    p.add_argument("-o", "--output", required=True, help=COPY_HELP[name][1])
    p.add_argument("-f", "--force", action="store_true", help="replace OUTPUT if it exists")
    add_common(p)
    return p


def _add_segment_layout(p: argparse.ArgumentParser) -> None:
    """tsog segment's input, output and layout options."""
    add_input(p)
    add_cameras(p)
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the container to write (.tsogs): a path (its folder made if missing) or a "
        "storage URL (s3://bucket/scene.tsogs)",
    )
    p.add_argument(
        "--window",
        default="auto",
        help="time window: auto (default: window, policy and time slices chosen per scene by a "
        "cost model, the smallest file whose seeks read at most 1.25x what they show where the "
        "content allows; the summary says why), 1s, 0.5, or 30f (frames)",
    )
    p.add_argument(
        "--policy",
        choices=POLICIES,
        help="how Gaussians crossing windows are stored (default: chosen with the window)",
    )
    p.add_argument(
        "--workers",
        type=Integer(1, 256),
        default=default_workers(),
        help="encoder processes, or Dask workers with --cluster local (default: one per core "
        f"this process may use, fewer when its free memory holds fewer "
        f"{WORKER_MEMORY / 2**30:g} GiB workers; %(default)s here)",
    )
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="encode on a Dask cluster: a scheduler address (tcp://host:8786) or 'local' for "
        "a LocalCluster of --workers processes (needs tsog-stream[cluster]); the container is "
        "byte-identical to a local run (default: a local process pool)",
    )


def _add_segment_encoding(p: argparse.ArgumentParser) -> None:
    """tsog segment's encoding, layer and merge-over-time options."""
    add_chunk_options(p)
    p.add_argument(
        "--layers",
        type=Integer(1, MAX_LAYERS),
        metavar="N",
        help="quality layers, each its own chunks, so a player on a slow link draws the base at "
        "once and adds the rest as it arrives (default: chosen by measuring rendered PSNR: "
        f"{AUTO_LAYERS} layers, the base reaching {LAYER_TARGETS_DB[0]:g} dB and the first two "
        f"{LAYER_TARGETS_DB[1]:g} dB against the whole, when a frame shows at least "
        f"{LAYERED_MIN_GAUSSIANS} Gaussians, else 1, and for a SOG flipbook only where its "
        "layered frames stay within the flipbook's own bytes; the base is stored with DC colour "
        "and its SH bands follow in the next layer); 1 keeps one layer",
    )
    p.add_argument(
        "--temporal",
        choices=TEMPORAL_MODES,
        default=DEFAULT_TEMPORAL,
        help="frame sequences only: off = one Gaussian per frame (type 0, as in the paper); "
        "merge = a Gaussian unchanged over frames is stored once with its lifespan; fit = a "
        f"smoothly moving one also gets polynomial motion (default {DEFAULT_TEMPORAL}); a "
        "probe of a few frames decides first whether merging can pay, and a merge whose seeks "
        "would read more than a frame's own chunk is not kept",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        metavar="UNITS",
        help="--temporal: how far (scene units) a stored position may be from any frame it "
        "stands for (default: half the per-frame SOG position step at each Gaussian)",
    )
    p.add_argument(
        "--tolerance-steps",
        type=float,
        metavar="STEPS",
        help="--temporal: the same for the other attributes, in codebook steps (default 0.5; "
        "1 for SOG frames, already rounded to their own codebooks)",
    )


def segment_options(args: argparse.Namespace) -> tuple[SegmentOptions, InputOptions]:
    """The library's options as the segment command line gives them."""
    seconds, frames = parse_window(args.window)
    options = SegmentOptions(
        window_s=seconds,
        policy=args.policy,
        max_pixels=args.max_pixels,
        workers=args.workers,
        seed=args.seed,
        quality=args.quality,
        layers=args.layers,
        cluster=args.cluster,
    )
    inputs = replace(
        reading_options(args),
        window_frames=frames,
        temporal=args.temporal,
        tolerance=tolerance_option(args),
        overwrite=args.force,
    )
    return options, inputs


def reading_options(args: argparse.Namespace) -> InputOptions:
    """How to read INPUT as its options give it; the rest as ``tsog segment``'s defaults."""
    return InputOptions(format=args.format, reading=read_options(args), cameras=args.cameras)


def default_options() -> SegmentOptions:
    """The segmenter's options of a segment command line that gives none (``tsog view``)."""
    return SegmentOptions(workers=default_workers(), quality=DEFAULT_QUALITY)


def tolerance_option(args: argparse.Namespace) -> Tolerance | None:
    """The --tolerance/--tolerance-steps pair (None: the defaults for the input kind)."""
    if args.tolerance is None and args.tolerance_steps is None:
        return None
    steps = args.tolerance_steps if args.tolerance_steps is not None else Tolerance().steps
    return Tolerance(position=args.tolerance, steps=steps)


def cmd_segment(args: argparse.Namespace, progress: Progress) -> int:
    """tsog segment: parse, segment the input (pipeline.segment_input), print the report."""
    check_segment_args(args)
    options, inputs = segment_options(args)
    made = segment_input(args.input, args.output, options, inputs, Told(progress, args.input))
    progress.done()
    print_segment_report(made, args.quality)
    return 0


def seek_table(reader: Stream, samples: int = 8) -> list[dict[str, Any]]:
    """Seek costs at evenly spaced times of the scene."""
    scene = reader.index.manifest.scene
    times = np.linspace(scene.start_s, scene.end_s, samples)
    return [reader.seek_cost(round(float(t), 4)).as_dict() for t in times]


def layers_summary(layers: list[Layer]) -> dict[str, Any]:
    """The quality layers: how many, and per layer its Gaussians, bytes and measured PSNR."""
    out: dict[str, Any] = {"count": max(len(layers), 1)}
    for layer in layers:
        shows = "full" if layer.psnr_db is None else f"{layer.psnr_db:.1f} dB"
        out[f"layer {layer.index}"] = (
            f"{layer.gaussians} Gaussians, {layer.bytes} bytes; with the layers below: {shows}"
        )
    return out


def stream_info(target: str, timeout: float | None = None) -> dict[str, Any]:
    """Header, index summary and a seek-cost table of a container."""
    with open_stream(target, timeout=timeout) as reader:
        h, m = reader.index.header, reader.index.manifest
        return {
            "file": target,
            "format": "tsogs",
            "bytes": h.file_length,
            "version": f"{h.version_major}.{h.version_minor}",
            "identity": reader.index.identity,
            "index": {
                "offset": h.index_offset,
                "bytes": h.index_length,
                "json_bytes": h.index_raw_length,
            },
            "policy": m.policy,
            "window_s": m.window_s,
            "max_pixels": m.max_pixels,
            "duration": scene_duration(m.scene),
            "scene": m.scene.model_dump(),
            "nodes": len(m.nodes),
            "chunks": len(m.chunks),
            "cameras": cameras_summary(m.cameras, view=m.view),
            "layers": layers_summary(list(m.layers)),
            "seek_costs": seek_table(reader),
        }


def write_frame(output: Path, frame: Gaussians, t: float, progress: Progress) -> None:
    """Write the frame at ``t`` as a float PLY (``.ply``), else as a SOG v2 chunk; say its size."""
    if output.suffix.lower() == ".ply":
        write_ply(output, frame)
    else:
        write_chunk_files(output, encode_chunk(Scene(frame), progress=progress), overwrite=True)
    progress.done()
    print(f"{output}: {len(frame)} Gaussians visible at t = {t} s")


def stream_frame(
    target: str, t: float, output: Path, progress: Progress, *, timeout: float | None = None
) -> ReadStats:
    """tsog frame (and fetch) on a stream, reading only the chunks t needs; what it cost."""
    progress(f"opening {target}")
    with open_stream(target, timeout=timeout) as reader:
        info = reader.index.manifest.scene
        check_time(t, None if info.timeline_type is None else (info.start_s, info.end_s))
        progress(f"fetching t = {t} s")
        frame = reader.frame_at(t)
        stats = reader.stats
    write_frame(output, frame, t, progress)
    return stats


def cmd_verify(args: argparse.Namespace, progress: Progress) -> int:
    """tsog verify: exit 0 when clean, 3 hash, 4 decode, 5 budget, 6 index mismatch."""
    with open_stream(args.input, timeout=args.timeout) as reader:
        progress("verifying chunks")
        report = reader.verify()
    progress.done()
    for kind, chunk, message in report.problems:
        what = f"chunk {chunk}" if chunk >= 0 else "container"
        print(f"{what}: {kind.name.lower()}: {message}")
    status = "OK" if not report.problems else f"{len(report.problems)} problem(s)"
    print(f"{args.input}: {report.chunks} chunks checked, {status}")
    return report.exit_code


def cmd_extract(args: argparse.Namespace, progress: Progress) -> int:
    """tsog extract."""
    check_output(args.output, overwrite=args.force)
    with open_stream(args.input) as reader:
        data = reader.chunk_bytes(args.chunk)
    atomic_write_bytes(args.output, data)
    print(f"{args.output}: chunk {args.chunk}, {len(data)} bytes")
    return 0


def cmd_unpack(args: argparse.Namespace, progress: Progress) -> int:
    """tsog unpack; a storage prefix is checked by its manifest.json, the last file written."""
    if is_object_url(args.output):
        check_output(f"{args.output.rstrip('/')}/manifest.json", overwrite=args.force)
    else:
        check_output(args.output, overwrite=args.force, folder=True)
    with open_stream(args.input) as reader:
        count = reader.unpack(args.output, overwrite=args.force)
    print(f"{args.output}: manifest.json and {count} chunks")
    return 0


def cmd_pack(args: argparse.Namespace, progress: Progress) -> int:
    """tsog pack."""
    check_output(args.output, overwrite=args.force)
    with open_stream(args.input) as reader:
        size = reader.pack(args.output)
    print(f"{args.output}: {size} bytes")
    return 0
