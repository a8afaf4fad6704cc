"""``tsog render`` and ``tsog eval``: draw a scene at time t; compare two scenes by PSNR/SSIM.

Thin: parse arguments, call :mod:`tsog_stream.render.evaluate`, print results. The renderer is
imported when a command runs, so other commands do not pay for loading it (and numba).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

from ..constants import EVAL_MAX_TIMES, MAX_CAMERAS, RENDER_MAX_SIDE, RENDER_MAX_VIEWS
from ..errors import InputError, printable
from ..framing import FRAMING_NAME
from ..io.files import check_output
from ..pipeline import input_bytes
from .common import (
    Integer,
    Subparsers,
    Told,
    add_cameras,
    add_common,
    add_force,
    add_input,
    add_reading_options,
    local_file,
    read_options,
)
from .progress import Progress

if TYPE_CHECKING:
    from ..render.evaluate import CameraSetup, EvalReport, RenderStyle, Source

RENDER_EPILOG = """examples:
  tsog render clip.splatv --t 0.5 -o view.png            the view the player opens on
  tsog render clip.tsogs --camera 3 --width 960 -o v.png capture camera 3, 960 wide
  tsog render scene.ply --cameras sparse/0 --camera 0 -o v.png
  tsog render clip.tsogs --t 1.5 --view 3 --views 8 -o v.png
  tsog render scene.sog --cameras cameras.json --view 12 --width 320 --height 240 -o v.png
  tsog render http://host:8080/files/clip.tsogs --t 2 --background 1,1,1 -o v.png

By default the image is what the web player shows first: the scene's first capture camera
(carried by the input, found beside it as cameras.json or a COLMAP model, stored in its
container, or given with --cameras), else a framing of its dense core that floaters do not
widen; 640 pixels wide, the camera's aspect ratio (held to 1:8..8:1) unless --height is
given, at most 1280x720's pixel count; sizes given are at most 4096x4096's. --view N picks
orbit view N of --views M around the scene at t (or, with --cameras, that file's camera N
scaled to --width/--height). Images are 8-bit RGB PNG."""

EVAL_EPILOG = """examples:
  tsog eval scene.ply scene.sog                          PSNR/SSIM of a SOG round trip
  tsog eval clip.splatv clip.tsogs --times 10 --views 6 --plot psnr.png
  tsog eval scene.ply scene.sog --cameras cameras.json --width 320 --height 240 --json

Both inputs are rendered at the same times (centres of --times equal slices of the
reference's time range; t = 0 for a static scene) from the same cameras (an orbit around the
reference at each t, or a cameras.json). PSNR is over all pixels and channels of the 8-bit
images; SSIM uses the 3DGS evaluation's 11x11 Gaussian window, zero-padded (docs/eval.md).
Local inputs' sizes are reported too (a folder: its files), so one run gives a point of the
rate-distortion trade-off: bytes against PSNR."""


def _add_views(p: argparse.ArgumentParser, views_help: str, cameras_help: str | None) -> None:
    """Camera, image-size and rasterizer options shared by render and eval."""
    p.add_argument("--views", type=Integer(1, RENDER_MAX_VIEWS), help=views_help)
    p.add_argument(
        "--width",
        type=Integer(1, RENDER_MAX_SIDE),
        help="image width in pixels (orbits: default 640)",
    )
    p.add_argument(
        "--height",
        type=Integer(1, RENDER_MAX_SIDE),
        help="image height in pixels (orbits: default 480)",
    )
    if cameras_help is not None:
        p.add_argument("--cameras", type=local_file, metavar="PATH", help=cameras_help)
    p.add_argument(
        "--background",
        default="0,0,0",
        help="background colour R,G,B in [0, 1] (default 0,0,0)",
    )
    p.add_argument(
        "--antialiased", action="store_true", help="the antialiased (Mip-Splatting) variant"
    )
    p.add_argument(
        "--up",
        default="0,0,1",
        help="up axis X,Y,Z of orbit cameras (default 0,0,1; COLMAP-style captures: 0,-1,0)",
    )


def add_render_commands(sub: Subparsers) -> None:
    """Register ``render`` and ``eval`` on the main parser."""
    p = sub.add_parser(
        "render",
        help="render a scene at time t from one camera to a PNG (CPU rasterizer)",
        epilog=RENDER_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_input(p)
    add_cameras(p)
    p.add_argument("--t", type=float, default=0.0, help="time in seconds (default 0)")
    p.add_argument(
        "--camera",
        type=Integer(0, MAX_CAMERAS - 1),
        help="capture camera N (from 0) of the input, its container or --cameras, drawn as the "
        "player shows it (default: the view the player opens on)",
    )
    p.add_argument(
        "--view",
        type=Integer(0, RENDER_MAX_VIEWS - 1),
        help="orbit view N (from 0) of --views, or with --cameras that file's camera N "
        "stretched to --width x --height",
    )
    _add_views(p, "orbit cameras around the scene (default 8); with --cameras: all", None)
    p.add_argument("-o", "--output", type=local_file, required=True, help="the PNG to write")
    add_force(p)
    add_common(p)

    p = sub.add_parser(
        "eval",
        help="render two scenes at the same times and cameras; report PSNR/SSIM",
        epilog=EVAL_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("reference", help="the reference: any input, a .tsogs, its folder or a URL")
    p.add_argument("candidate", help="the candidate, in any of the same forms")
    p.add_argument(
        "--times", type=Integer(1, EVAL_MAX_TIMES), default=5, help="times sampled (default 5)"
    )
    _add_views(
        p,
        "views per time (default 4 orbit cameras; with --cameras: all)",
        "render from these cameras instead of orbits: a 3DGS cameras.json, a COLMAP model or "
        "a .splatv's cameras",
    )
    p.add_argument("--plot", type=local_file, help="also draw PSNR over time to this PNG")
    add_force(p, "the PLOT")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    add_reading_options(p, "the inputs of the formats named")
    add_common(p)


def _triple(
    text: str, flag: str, expected: str, low: float = -math.inf, high: float = math.inf
) -> tuple[float, float, float]:
    """Three finite comma-separated numbers in [low, high], or an error naming ``flag``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) and low <= v <= high for v in values):
        raise InputError(f"expected {expected}, got {text!r}", where=flag)
    return values[0], values[1], values[2]


def parse_up(text: str) -> tuple[float, float, float]:
    """'X,Y,Z', a non-zero direction."""
    up = _triple(text, "--up", "a direction X,Y,Z")
    if not any(up):
        raise InputError(f"expected a direction X,Y,Z, got {text!r}", where="--up")
    return up


def parse_background(text: str) -> tuple[float, float, float]:
    """'R,G,B' with each value in [0, 1]."""
    return _triple(text, "--background", "R,G,B with values in [0, 1]", 0.0, 1.0)


def _setup(args: argparse.Namespace, default_views: int) -> tuple[CameraSetup, RenderStyle]:
    """The camera setup and render style the options ask for."""
    from ..render.evaluate import CameraSetup, RenderStyle  # noqa: PLC0415 - loads the renderer

    views = args.views if args.views is not None or args.cameras else default_views
    cameras = args.cameras  # eval: always replaces the orbits; render: only with --view(s)
    if hasattr(args, "view") and args.view is None and args.views is None:
        cameras = None
    setup = CameraSetup(views, args.width, args.height, cameras, parse_up(args.up))
    setup.check()
    return setup, RenderStyle(parse_background(args.background), args.antialiased)


def cmd_render(args: argparse.Namespace, progress: Progress) -> int:
    """tsog render."""
    from ..inputs import open_source  # noqa: PLC0415
    from ..render import save_png  # noqa: PLC0415 - loads the renderer
    from ..render.evaluate import opening_camera, render_view  # noqa: PLC0415

    check_output(args.output, overwrite=args.force)
    orbit = args.view is not None or args.views is not None
    if orbit and args.camera is not None:
        raise InputError("--camera picks a capture camera; --view/--views pick orbit views")
    setup, style = _setup(args, default_views=8)
    options = read_options(args)
    progress(f"reading {args.input}")
    with open_source(
        args.input,
        format=args.format,
        options=options,
        progress=progress,
        cameras=None if orbit else args.cameras,
    ) as src:
        Told(progress, args.input).notes(src.notes)
        if orbit:
            seen, view = f"view {args.view or 0}", args.view or 0
            progress(f"rendering t = {args.t:g} s, {seen}")
            image = render_view(src, args.t, view, setup, style)
        else:
            camera = opening_camera(src, args.camera, args.width, args.height)
            seen = _camera_label(args.camera, camera.name)
            progress(f"rendering t = {args.t:g} s from {seen}")
            image = style.image(src.at(args.t), camera)
    save_png(image, args.output)
    progress.done()
    height, width = image.shape[:2]
    print(f"{args.output}: {width}x{height}, t = {args.t:g} s, {seen}")
    return 0


def _camera_label(index: int | None, name: str) -> str:
    """'capture camera 2 (00003)', or what the opening view is; the name (a file's or a
    server's) escaped for the terminal."""
    name = printable(name)
    if index is not None:
        return f"capture camera {index} ({name})" if name else f"capture camera {index}"
    if name == FRAMING_NAME:
        return "the opening view (a framing of the dense core)"
    return f"the opening view (capture camera {name})" if name else "the opening view"


def _open_pair(
    args: argparse.Namespace, stack: contextlib.ExitStack, progress: Progress
) -> tuple[Source, Source]:
    """Open REFERENCE and CANDIDATE, each with the reading options that apply to it."""
    from ..inputs import OPTION_KINDS, fit_options, input_kind, open_source  # noqa: PLC0415

    options = read_options(args)
    sources = []
    for target in (args.reference, args.candidate):
        progress(f"reading {target}")
        fitted = fit_options(input_kind(target), options)
        sources.append(stack.enter_context(open_source(target, options=fitted, progress=progress)))
        Told(progress, target).notes(sources[-1].notes)
    for name, kinds in OPTION_KINDS.items():
        if getattr(options, name) is not None and not any(s.kind in kinds for s in sources):
            flag = "--" + name.replace("_", "-")
            raise InputError(f"applies to {', '.join(kinds)} inputs only", where=flag)
    return sources[0], sources[1]


def cmd_eval(args: argparse.Namespace, progress: Progress) -> int:
    """tsog eval."""
    from ..render.evaluate import evaluate  # noqa: PLC0415 - loads the renderer

    if args.plot is not None:
        check_output(args.plot, overwrite=args.force)
    setup, style = _setup(args, default_views=4)
    with contextlib.ExitStack() as stack:
        reference, candidate = _open_pair(args, stack, progress)
        report = evaluate(
            reference,
            candidate,
            times=args.times,
            setup=setup,
            style=style,
            on_step=lambda done, total: progress.bar("rendering", done / total),
        )
    if args.plot is not None:
        from ..render.plot import write_psnr_plot  # noqa: PLC0415

        write_psnr_plot(report, args.plot)
    progress.done()
    sizes = {"reference": input_bytes(args.reference), "candidate": input_bytes(args.candidate)}
    if args.json:
        out = report.to_dict()
        out["bytes"] = {name: size or None for name, size in sizes.items()}
        out["plot"] = str(args.plot) if args.plot is not None else None
        print(json.dumps(out, indent=2))
    else:
        print_report(report, args.plot)
        print(_sizes_line(sizes["reference"], sizes["candidate"]))
    return 0


def _sizes_line(reference: int, candidate: int) -> str:
    """'bytes: reference R, candidate C (0.12x the reference)'; unknown (URLs) said so."""

    def shown(size: int) -> str:
        return f"{size:,}" if size else "unknown (not a local file)"

    ratio = f" ({candidate / reference:.3g}x the reference)" if reference and candidate else ""
    return f"bytes: reference {shown(reference)}, candidate {shown(candidate)}{ratio}"


def _db(value: float) -> str:
    return "inf" if math.isinf(value) else f"{value:.2f}"


def print_report(report: EvalReport, plot: Path | None) -> None:
    """The report as a text table with means and worst cases."""
    print(f"reference: {report.reference}")
    print(f"candidate: {report.candidate}")
    print(f"images: {report.width}x{report.height}, 8-bit RGB")
    print(f"{'t (s)':>10} {'view':>5} {'PSNR (dB)':>10} {'SSIM':>8}")
    for r in report.rows:
        print(f"{r.t:>10.4g} {r.view:>5d} {_db(r.psnr):>10} {r.ssim:>8.5f}")
    s = report.summary()
    identical = f", {s['identical']} identical" if s["identical"] else ""
    print(
        f"mean: PSNR {_db(s['psnr_mean'])} dB, SSIM {s['ssim_mean']:.5f} "
        f"over {s['images']} images{identical}"
    )
    wp, ws = s["psnr_worst"], s["ssim_worst"]
    print(f"worst PSNR: {_db(wp['psnr'])} dB at t = {wp['t']:.4g} s, view {wp['view']}")
    print(f"worst SSIM: {ws['ssim']:.5f} at t = {ws['t']:.4g} s, view {ws['view']}")
    if plot is not None:
        print(f"plot: {plot}")
