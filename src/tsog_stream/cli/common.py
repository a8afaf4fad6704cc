"""What every ``tsog`` command shares: argument types, the INPUT argument with its reading
options, output checks, and the library's listener printing on stderr."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

from ..client.http_options import DEFAULT_DEADLINE_S
from ..codec.precision import DEFAULT_QUALITY
from ..constants import DEFAULT_MAX_PIXELS, MAX_IMAGE_PIXELS
from ..errors import InputError, printable
from ..io.chunks import chunk_folder
from ..io.files import check_output, local_path
from ..io.readers import FORMATS, LoadedScene, ReadOptions, detect_format
from ..io.sequence import DEFAULT_FPS
from ..io.splatv import ASSUMED_DURATION, ASSUMED_DURATION_S
from ..pipeline import load_told
from ..schemas.manifest import SceneInfo
from ..summary import duration_text
from .progress import Progress

if TYPE_CHECKING:
    Subparsers: TypeAlias = argparse._SubParsersAction[argparse.ArgumentParser]
else:
    Subparsers: TypeAlias = argparse._SubParsersAction


class Integer:
    """An argparse type of an integer in a declared range: outside it, a usage error naming the
    range, never a value that overflows or loops for ever later."""

    def __init__(self, low: int, high: int) -> None:
        self.low, self.high = low, high
        self.__name__ = f"integer from {low} to {high}"  # argparse names the type in errors

    def __call__(self, text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not self.low <= value <= self.high:
            raise argparse.ArgumentTypeError(
                f"expected an integer from {self.low} to {self.high}, got {text}"
            )
        return value


class Seconds:
    """An argparse type of a finite number of seconds in (0, ``high``]."""

    def __init__(self, high: float = math.inf) -> None:
        self.high = high
        self.__name__ = "seconds"

    def __call__(self, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
        if not (math.isfinite(value) and 0 < value <= self.high):
            within = "> 0" if math.isinf(self.high) else f"in (0, {self.high:g}]"
            raise argparse.ArgumentTypeError(
                f"expected a finite number of seconds {within}, got {text}"
            )
        return value


SEED = Integer(0, 2**32 - 1)
QUALITY = Integer(0, 100)
QUALITY_HELP = (
    "0..100: how precisely to keep positions, rotations, scales, colours, SH bands, opacity, "
    "lifespans and motion (default 90: within 0.6 dB of 100 on every real scene measured, "
    "5-51 %% smaller; 100 keeps every 16-bit code and every Gaussian). Lower keeps only what "
    "fits an error budget per Gaussian: at 50, an opaque Gaussian moves by at most 1/1935 of "
    "the radius of the chunk's dense core (about a quarter pixel of a 1080p view of it; a "
    "faint one 1/alpha times that, as a root mean square over its lifespan when it moves), a "
    "lifespan by 1/40 of its temporal scale, and Gaussians of alpha 0.05 or less are left "
    "out (0.2 (1 - q/100)^2; docs/spec.md 5.1)"
)
CAMERAS_HELP = (
    "capture cameras: a 3DGS cameras.json, a COLMAP model (its folder, the folder holding "
    "sparse/0, or its cameras/images .txt/.bin) or a .splatv (default: those the input "
    "carries, or a cameras.json / COLMAP model beside it)"
)


def local_file(text: str) -> Path:
    """An argparse type of a local path or ``file://`` URL (``Path`` alone would make
    ``file:///a/b`` the relative ``file:/a/b``)."""
    return local_path(text)


def add_common(p: argparse.ArgumentParser) -> None:
    """Options every subcommand has."""
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output on stderr")


def add_chunk_options(p: argparse.ArgumentParser) -> None:
    """How chunks are encoded (``tsog segment``, ``tsog live``): pixel budget, seed, quality."""
    p.add_argument(
        "--max-pixels",
        type=Integer(1, MAX_IMAGE_PIXELS),
        default=DEFAULT_MAX_PIXELS,
        help="pixel budget per image (default 4096x4096)",
    )
    p.add_argument("--seed", type=SEED, default=0, help="seed of the SH palette fits")
    p.add_argument("--quality", type=QUALITY, default=DEFAULT_QUALITY, help=QUALITY_HELP)


def add_force(p: argparse.ArgumentParser, what: str = "OUTPUT") -> None:
    """-f/--force: replace an output that exists."""
    p.add_argument("-f", "--force", action="store_true", help=f"replace {what} if it exists")


def add_timeout(p: argparse.ArgumentParser) -> None:
    """``--timeout``: the deadline of one read of a stream over HTTP (client.HttpOptions)."""
    p.add_argument(
        "--timeout",
        type=Seconds(),
        default=DEFAULT_DEADLINE_S,
        metavar="SECONDS",
        help="give up on one read of a stream over HTTP (the opening request, a chunk) after "
        f"this long, retries included (default {DEFAULT_DEADLINE_S:g})",
    )


def add_input(p: argparse.ArgumentParser) -> None:
    """The INPUT argument, --format and the per-format reading options."""
    p.add_argument(
        "input",
        help="input file, folder or frame pattern: 3DGS PLY, compressed PLY, .sog or SOG folder, "
        "folder/glob of numbered PLY or SOG frames, FreeTimeGS PLY/npz, .splatv, .4dgs",
    )
    p.add_argument(
        "--format", choices=FORMATS, help="input format (default: detected from content)"
    )
    add_reading_options(p, "the formats named")


def add_reading_options(p: argparse.ArgumentParser, applies_to: str) -> None:
    """The per-format reading options, as one group."""
    g = p.add_argument_group(f"reading options (each applies to {applies_to})")
    g.add_argument(
        "--fps", type=float, help=f"frame rate of PLY/SOG frame sequences (default {DEFAULT_FPS:g})"
    )
    g.add_argument(
        "--duration-s", type=float, help=".splatv: seconds spanned by the clip (default 1)"
    )
    g.add_argument(
        "--scene-length-s",
        type=float,
        help="FreeTimeGS: seconds spanned by normalised time (default 1)",
    )
    g.add_argument(
        "--duration-mode",
        choices=("log", "linear"),
        default="log",
        help="FreeTimeGS PLY: durations stored as log sigma (default) or sigma",
    )


def add_cameras(p: argparse.ArgumentParser) -> None:
    """--cameras PATH: where the input's capture cameras are."""
    p.add_argument("--cameras", type=local_file, metavar="PATH", help=CAMERAS_HELP)


def add_frame_output(p: argparse.ArgumentParser) -> None:
    """--t and -o/--output of the commands writing the scene at one time (frame, fetch)."""
    p.add_argument("--t", type=float, required=True, help="time in seconds")
    p.add_argument(
        "-o",
        "--output",
        type=local_file,
        required=True,
        help="frame.ply or frame.sog (or a folder)",
    )
    add_force(p)


def read_options(args: argparse.Namespace) -> ReadOptions:
    """The reading options given on the command line."""
    return ReadOptions(
        fps=args.fps,
        duration_s=args.duration_s,
        scene_length_s=args.scene_length_s,
        duration_mode=args.duration_mode,
    )


def note(message: str) -> None:
    """A reader's or writer's note, on stderr."""
    print(f"tsog: note: {message}", file=sys.stderr)


def warn(message: str) -> None:
    """Something asked for works, but worse than it could: on stderr."""
    print(f"tsog: warning: {message}", file=sys.stderr)


def assumed_duration(input_name: str) -> str:
    """The warning on a ``.splatv`` read without --duration-s, naming the file and the flag."""
    name = printable(Path(input_name).name or input_name)
    return (
        f"{name} does not say its length: read as {ASSUMED_DURATION_S:g} s; "
        "set it with --duration-s"
    )


def scene_duration(info: SceneInfo) -> str:
    """A container's length as ``tsog`` shows it (summary.duration_text)."""
    static = info.timeline_type is None
    return duration_text(info.start_s, info.end_s, static=static, assumed=info.duration_assumed)


def load_input(args: argparse.Namespace, progress: Progress) -> LoadedScene:
    """Load INPUT (and its capture cameras), told on stderr (:func:`pipeline.load_told`)."""
    kind = args.format or detect_format(args.input)
    told = Told(progress, args.input)
    cameras = getattr(args, "cameras", None)
    return load_told(args.input, kind, read_options(args), told, cameras=cameras)


def check_file_output(output: Path, *, overwrite: bool, file_suffix: str) -> None:
    """Refuse, before the input is read, a location a command writing a ``file_suffix`` or
    ``.sog`` file, else a SOG folder, could not write (io.files.check_output)."""
    is_file = output.suffix.lower() == file_suffix
    check_output(output, overwrite=overwrite, folder=not is_file and chunk_folder(output))


def check_time(t: float, span: tuple[float, float] | None) -> None:
    """Refuse a --t that is not finite or (unless the scene is static) outside its range."""
    if not math.isfinite(t):
        raise InputError(f"expected a finite number of seconds, got {t}", where="--t")
    if span is not None and not span[0] <= t <= span[1]:
        raise InputError(
            f"{t:g} s is outside the scene's time range [{span[0]:g}, {span[1]:g}] s",
            where="--t",
        )


class Told:
    """The library's listener (pipeline.Listener) on the command line: phases and bars on the
    progress line, notes and warnings on stderr (an assumed length named with its flag)."""

    def __init__(self, progress: Progress, input_name: str) -> None:
        self.progress = progress
        self.input_name = input_name

    def __call__(self, stage: str) -> None:
        self.progress(stage)

    def bar(self, stage: str, fraction: float) -> None:
        self.progress.bar(stage, fraction)

    def done(self) -> None:
        self.progress.done()

    def note(self, text: str) -> None:
        note(text)

    def warn(self, text: str) -> None:
        warn(assumed_duration(self.input_name) if text == ASSUMED_DURATION else text)

    def notes(self, notes: list[str]) -> None:
        """A reader's notes: an assumption about time first, as a warning, then the rest."""
        for text in sorted(notes, key=lambda text: text != ASSUMED_DURATION):
            (self.warn if text == ASSUMED_DURATION else self.note)(text)
