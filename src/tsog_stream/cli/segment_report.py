"""What ``tsog segment`` (and ``tsog view -v``) prints of a :class:`pipeline.InputReport`."""

from __future__ import annotations

from ..errors import printable
from ..pipeline import FrameCheck, InputReport, TemporalOutcome
from ..schemas.cameras import Camera
from ..segment import SegmentReport
from ..segment.layout import OVERFETCH_WARNING, SEEK_TARGET, Choice
from ..summary import duration_text
from .common import warn


def print_segment_report(made: InputReport, quality: int) -> None:
    """What segmenting made, as ``tsog segment`` says it."""
    if made.temporal is not None:
        _print_temporal(made.temporal)
    if made.frame_check is not None:
        _print_frame_check(made.frame_check)
    report = made.segment
    print(f"{report.path}: {report.bytes} bytes, {_size_change(report.bytes, made.input_bytes)}")
    print(f"  {_duration_line(report)}")
    if report.layout is not None:
        _print_layout(report.layout, made.fps)
    print(f"  {report.windows} windows, {report.chunks} chunks")
    faint = f" ({report.faint} too faint at quality {quality} left out)" if report.faint else ""
    print(f"  {report.gaussians} Gaussians, {report.stored} stored copies{faint}")
    if not report.static:
        print(f"  {report.dropped} Gaussians never visible inside the scene's time range")
    print(f"  {_cameras_line(made.cameras, made.cameras_source, report)}")
    sizes = ", ".join(f"{layer.bytes}" for layer in report.layers)
    layers = f"{report.layers_why}; bytes per layer: {sizes}" if report.layers else None
    print(f"  {layers or report.layers_why or 'one layer'}")
    if made.thumbnail is not None:
        print(f"  thumbnail: {made.thumbnail}")
    for level, size in sorted(report.bytes_per_level.items()):
        print(f"  level {level}: {size} bytes")
    shown = ", ".join(str(b) for b in report.bytes_per_window[:12])
    more = " ..." if len(report.bytes_per_window) > 12 else ""
    print(f"  bytes per window (level 0): {shown}{more}")


def _print_temporal(outcome: TemporalOutcome) -> None:
    """What merging the frames over time gave, and whether it was stored."""
    if outcome.merged:
        if outcome.note:
            print(f"temporal: {outcome.note}")
        share = 100.0 * outcome.gaussians_out / max(1, outcome.gaussians_in)
        print(
            f"temporal {outcome.mode}: {outcome.gaussians_in} Gaussians in {outcome.frames} "
            f"frames -> {outcome.gaussians_out} ({share:.1f}%), {outcome.moving_out} with "
            f"motion, {outcome.seconds:.1f} s"
        )
        worst = ", ".join(f"{k} {v:.3g}" for k, v in sorted(outcome.worst.items()))
        print(f"  largest change from a source frame before encoding: {worst}")
    if outcome.declined is not None:
        print(f"temporal: {outcome.declined}")


def _print_frame_check(check: FrameCheck) -> None:
    """The worst error per attribute of a few decoded frames of a merged container."""
    for frame, unpaired in check.unpaired:
        print(f"  frame {frame}: {unpaired} Gaussians could not be paired with the source")
    shown = ", ".join(f"{k} {v:.3g}" for k, v in sorted(check.worst.items()))
    frames = ", ".join(map(str, check.frames))
    print(f"  worst error after encoding (frames {frames}): {shown}")


def _duration_line(report: SegmentReport) -> str:
    """The stream's length (said to be assumed when it was), or that it is static."""
    if report.static:
        return "a static scene: a stream of one moment (0 s), shown the same at any time"
    assumed = report.duration_assumed
    return f"duration {duration_text(report.start_s, report.end_s, static=False, assumed=assumed)}"


def _cameras_line(cameras: list[Camera], source: str, report: SegmentReport) -> str:
    """Where the player and tsog render open the scene, and why."""
    if not cameras:
        return (
            "no capture cameras (none in the input or beside it; --cameras PATH gives them): "
            "opens on a framing of the dense core"
        )
    many = "camera" if len(cameras) == 1 else "cameras"
    found = f"{len(cameras)} capture {many} from {printable(source)}"
    if report.view is not None and report.view == cameras[0]:
        name = printable(cameras[0].name) or "0"
        return f"{found}: opens from the first ({name}; {report.view_why})"
    return f"{found}: opens on a framing of the dense core ({report.view_why})"


def _size_change(size: int, input_size: int) -> str:
    """'12 % smaller than the input' or '9 % larger than the input', said plainly."""
    if not input_size:
        return "input size unknown"
    change = 100.0 * (size - input_size) / input_size
    if abs(change) < 0.05:
        return "the size of the input"
    return f"{abs(change):.1f} % {'larger' if change > 0 else 'smaller'} than the input"


def _print_layout(choice: Choice, fps: float | None) -> None:
    """The layout used and why; a warning when a layout given explicitly over-fetches."""
    chosen = choice.chosen
    how = "as given" if choice.explicit else "chosen"
    print(f"  layout ({how}): {chosen.layout.describe(fps)}: {choice.reason}")
    print(
        f"  a seek at a random t: about {chosen.seek_mean / 1e3:.0f} kB in {chosen.requests:.1f} "
        f"requests, opening included, to show {chosen.shown_mean / 1e3:.0f} kB"
    )
    if choice.explicit and chosen.overfetch > OVERFETCH_WARNING:
        warn(
            f"this layout makes a seek fetch about {chosen.overfetch:.1f}x what it "
            "shows; --window auto (the default) chooses one that fetches at most "
            f"{SEEK_TARGET:g}x where the content allows"
        )
