"""Any input to a streamable ``.tsogs``: all that ``tsog segment`` does, as one library call.

:func:`segment_input` reads the input, finds its cameras, merges a frame sequence over time
where that pays, segments, checks a few merged frames and draws the thumbnail; it returns an
:class:`InputReport` the CLI prints, and a :class:`Listener` hears the phases as they happen.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

from .client import open_stream
from .constants import thumbnail_path
from .errors import InputError, TsogError
from .inputs import thumbnail_png
from .io.cameras import cameras_for_input
from .io.files import atomic_write_bytes, check_output, remove_stale_temp_files
from .io.objects import ObjectPath, is_object_url
from .io.readers import LoadedScene, ReadOptions, detect_format, load_scene
from .io.sequence import DEFAULT_FPS, FrameSequence, open_sequence
from .io.splatv import ASSUMED_DURATION
from .merge import TemporalMode, Tolerance, merge_sequence
from .merge.check import frame_errors
from .merge.sequence import MAX_HELD
from .model import Scene
from .schemas.cameras import Camera
from .segment import SegmentOptions, SegmentReport, merge_or_frames, segment_scene, segment_sequence
from .segment.engines import engine
from .segment.layout import Choice
from .segment.sequence import spread

SEQUENCE_KINDS = ("ply-sequence", "sog-sequence")
"""Input formats read window by window (never whole)."""
ONE_PER_FRAME = "stored one per frame (type 0)"
FRAME_CHECKS = 5
"""Frames of a merged sequence decoded after writing and compared with their source."""


class Listener(Protocol):
    """Told what segmenting an input does while it does it (``cli.progress.Progress`` plus a
    note and a warning line): the report says the rest once it is done."""

    def __call__(self, stage: str) -> None:
        """A phase that can take a while begins."""

    def bar(self, stage: str, fraction: float) -> None:
        """A phase is this far along (0..1)."""

    def done(self) -> None:
        """The phase under way has ended."""

    def note(self, text: str) -> None:
        """Something read, dropped or repaired that the result does not show."""

    def warn(self, text: str) -> None:
        """An assumption that changes the result (a ``.splatv`` read without its length)."""


class Silent:
    """A :class:`Listener` that ignores everything (the default)."""

    def __call__(self, stage: str) -> None: ...
    def bar(self, stage: str, fraction: float) -> None: ...
    def done(self) -> None: ...
    def note(self, text: str) -> None: ...
    def warn(self, text: str) -> None: ...


@dataclass(frozen=True)
class InputOptions:
    """How to read the input and what surrounds the segmenter (:class:`SegmentOptions`)."""

    format: str | None = None
    """The input's format (None: detected from its content)."""
    reading: ReadOptions = field(default_factory=ReadOptions)
    """Per-format reading options (a frame sequence's fps, a ``.splatv``'s length...)."""
    cameras: str | os.PathLike[str] | None = None
    """Capture cameras (None: those the input carries or has beside it)."""
    window_frames: float | None = None
    """A window in frames, made seconds by the input's frame rate (replaces ``window_s``)."""
    temporal: TemporalMode = "fit"
    """Frame sequences: each frame (off), unchanged Gaussians once (merge), or also smooth
    motion (fit); kept only where it pays."""
    tolerance: Tolerance | None = None
    """How far a merged Gaussian may be from the frames it stands for (None: the defaults)."""
    overwrite: bool = False
    """Replace the output if it exists."""
    thumbnail: bool = True
    """Draw the scene list's picture beside the container."""


@dataclass(frozen=True)
class TemporalOutcome:
    """What merging a frame sequence over time gave."""

    mode: TemporalMode
    merged: bool
    """A merge was made (``stats`` and ``seconds`` describe it)."""
    gaussians_in: int = 0
    gaussians_out: int = 0
    moving_out: int = 0
    frames: int = 0
    seconds: float = 0.0
    note: str = ""
    """What the merge said of itself (kept or not)."""
    worst: dict[str, float] = field(default_factory=dict)
    """The largest change from a source frame before encoding, per attribute."""
    declined: str | None = None
    """Why the frames were stored one per frame after all (None: the merge was stored)."""


@dataclass(frozen=True)
class FrameCheck:
    """A few frames of a merged container decoded and compared with their source."""

    frames: list[int]
    worst: dict[str, float]
    """The worst error per attribute over those frames."""
    unpaired: list[tuple[int, int]] = field(default_factory=list)
    """(frame, Gaussians of the source that no decoded one pairs with), where any."""


@dataclass(frozen=True)
class InputReport:
    """What :func:`segment_input` made, and what it found on the way."""

    segment: SegmentReport
    input_bytes: int
    """The input's size (0 when unknown: a pattern)."""
    fps: float | None
    """The input's frame rate (None: it has none)."""
    cameras: list[Camera]
    cameras_source: str
    """Where the cameras were read ("" without them)."""
    temporal: TemporalOutcome | None = None
    """A frame sequence's merge over time (None: not tried)."""
    frame_check: FrameCheck | None = None
    """The merged container checked against its source (None: no merge stored)."""
    thumbnail: str | None = None
    """The picture drawn beside the container (None: none; the listener was told why)."""


@dataclass
class _Held:
    """The input being segmented, dropped once the container is written (before the thumbnail
    decodes the scene again)."""

    source: Scene | FrameSequence | None
    duration_assumed: bool = False


def segment_input(
    source: str | os.PathLike[str],
    output: str | os.PathLike[str],
    options: SegmentOptions | None = None,
    inputs: InputOptions | None = None,
    listener: Listener | None = None,
) -> InputReport:
    """Segment any input (a file, folder, frame pattern or storage URL) into the container
    ``output`` (a path or storage URL), as ``tsog segment`` does; :class:`TsogError` on a bad
    input or an output that cannot be written (checked before the read)."""
    options = options or SegmentOptions()
    inputs = inputs or InputOptions()
    told: Listener = listener or Silent()
    target, path = str(output), str(source)
    check_output(target, overwrite=inputs.overwrite)
    kind = inputs.format or detect_format(path)
    if kind in SEQUENCE_KINDS:
        held, cameras, cameras_source = _opened(path, kind, inputs, told)
    else:
        held, cameras, cameras_source = _loaded(path, kind, inputs, told)
    return _segment(
        held,
        target,
        options=options,
        inputs=inputs,
        told=told,
        input_size=input_bytes(path),
        capture=(cameras, cameras_source),
    )


def _opened(
    path: str, kind: str, inputs: InputOptions, told: Listener
) -> tuple[_Held, list[Camera], str]:
    """A frame sequence opened (read window by window later) and its capture cameras."""
    fps = inputs.reading.fps if inputs.reading.fps is not None else DEFAULT_FPS
    seq = open_sequence(path, fps=fps, kind=kind.partition("-")[0])
    for text in seq.notes():
        told.note(text)
    found = cameras_for_input(path, explicit=inputs.cameras)
    for text in found.notes if found is not None else []:
        told.note(text)
    cameras = found.cameras if found is not None else []
    return _Held(seq), cameras, (found.source if found is not None and found.cameras else "")


def _loaded(
    path: str, kind: str, inputs: InputOptions, told: Listener
) -> tuple[_Held, list[Camera], str]:
    """Any other input read whole (:func:`load_told`)."""
    loaded = load_told(path, kind, inputs.reading, told, cameras=inputs.cameras)
    held = _Held(loaded.scene, duration_assumed=loaded.duration_assumed)
    return held, loaded.cameras, loaded.cameras_source


def load_told(
    path: str,
    kind: str,
    reading: ReadOptions,
    told: Listener,
    *,
    cameras: str | os.PathLike[str] | None = None,
) -> LoadedScene:
    """Read an input whole, its notes told; an assumed length (a ``.splatv``) first, before the
    read, as it changes everything shown of it."""
    said = kind == "splatv" and reading.duration_s is None
    if said:
        told.warn(ASSUMED_DURATION)
    told(f"reading {path}")
    loaded = load_scene(path, format=kind, options=reading, progress=told, cameras=cameras)
    for text in loaded.notes:  # what the read assumed is said once, first
        if text == ASSUMED_DURATION and not said:
            told.warn(text)
    for text in loaded.notes:
        if text != ASSUMED_DURATION:
            told.note(text)
    return loaded


def _segment(
    held: _Held,
    output: str,
    *,
    options: SegmentOptions,
    inputs: InputOptions,
    told: Listener,
    input_size: int,
    capture: tuple[list[Camera], str],
) -> InputReport:
    """Segment an opened or loaded input (merged first where that pays), check it, draw it."""
    source = held.source
    if source is None:
        raise InputError("nothing to segment")
    fps = _fps(source)
    options = _with_window(options, inputs.window_frames, fps)
    del source
    for stale in remove_stale_temp_files(output):
        told.note(f"removed {stale}, left by an interrupted run")
    separate = inputs.thumbnail and options.workers > 1
    with _thumbnail_drawer(separate=separate) as draw:
        report, temporal, check = _written(
            held, output, options=options, inputs=inputs, told=told, cameras=capture[0]
        )
        told.done()
        drawn = _write_thumbnail(output, draw, told) if inputs.thumbnail else None
    return InputReport(
        segment=report,
        input_bytes=input_size,
        fps=fps,
        cameras=capture[0],
        cameras_source=capture[1],
        temporal=temporal,
        frame_check=check,
        thumbnail=drawn,
    )


def _written(
    held: _Held,
    output: str,
    *,
    options: SegmentOptions,
    inputs: InputOptions,
    told: Listener,
    cameras: list[Camera],
) -> tuple[SegmentReport, TemporalOutcome | None, FrameCheck | None]:
    """The container written (and a merged sequence's frames checked); ``held`` is emptied, so
    the thumbnail drawn after decodes the scene again without ours held beside it."""
    source = held.source
    assert source is not None  # _segment checked it

    def on_chunk(done: int, total: int, eta_s: float | None) -> None:
        left = "ETA    ?" if eta_s is None else f"ETA {eta_s:4.0f}s"
        told.bar(f"chunk {done}/{total}, {left}", done / total)

    merged, layout, temporal = _probed(source, inputs, options, told)
    what = merged if merged is not None else source
    held.source = None
    if isinstance(what, FrameSequence):
        report = segment_sequence(
            what, output, options, layout=layout, cameras=cameras, on_chunk=on_chunk,
            on_stage=told,
        )  # fmt: skip
    else:
        report = segment_scene(
            what, output, options, layout=layout, cameras=cameras, on_chunk=on_chunk,
            on_stage=told, duration_assumed=held.duration_assumed,
        )  # fmt: skip
    check: FrameCheck | None = None
    if merged is not None and isinstance(source, FrameSequence):
        del what, merged
        told.done()
        check = frame_check(source, output)
    return report, temporal, check


def _probed(
    source: Scene | FrameSequence, inputs: InputOptions, options: SegmentOptions, told: Listener
) -> tuple[Scene | None, Choice | None, TemporalOutcome | None]:
    """A frame sequence merged where that pays: the merge (None: the frames), the layout chosen
    while deciding, and what merging gave."""
    if not isinstance(source, FrameSequence) or inputs.temporal == "off":
        return None, None, None
    merged, temporal = _merged(source, inputs, told)
    if merged is None:
        return None, None, temporal
    why, layout = merge_or_frames(source, merged, options)
    if why is not None:
        return None, layout, replace(temporal, declined=f"{why}; {ONE_PER_FRAME}")
    return merged, layout, temporal


def _fps(source: Scene | FrameSequence) -> float | None:
    """The input's frame rate (None: a scene without a timeline)."""
    if isinstance(source, FrameSequence):
        return source.fps
    return source.timeline.fps if source.timeline is not None else None


def _with_window(
    options: SegmentOptions, frames: float | None, fps: float | None
) -> SegmentOptions:
    """The options with a window given in frames made seconds."""
    if frames is None:
        return options
    if not fps:
        raise InputError(
            "a window in frames needs a frame rate (the input has none)", where="--window"
        )
    return replace(options, window_s=frames / fps)


def _merged(
    seq: FrameSequence, inputs: InputOptions, told: Listener
) -> tuple[Scene | None, TemporalOutcome]:
    """The sequence merged (None when that saves nothing), and what merging gave."""
    started = time.monotonic()
    scene, stats = merge_sequence(seq, inputs.temporal, inputs.tolerance, progress=told)
    told.done()
    outcome = TemporalOutcome(
        mode=inputs.temporal,
        merged=scene is not None,
        gaussians_in=stats.gaussians_in,
        gaussians_out=stats.gaussians_out,
        moving_out=stats.moving_out,
        frames=stats.frames,
        seconds=time.monotonic() - started,
        note=stats.note,
        worst=dict(stats.worst),
    )
    if scene is None and stats.note:
        return None, replace(outcome, declined=f"{stats.note}; {ONE_PER_FRAME}")
    if scene is None:
        declined = (
            f"merging would hold over {MAX_HELD} Gaussians in memory after {stats.frames} "
            f"frames; {ONE_PER_FRAME}, window by window"
        )
        return None, replace(outcome, declined=declined)
    if stats.gaussians_out >= stats.gaussians_in:
        return None, replace(
            outcome, merged=False, declined=f"no Gaussian repeats across frames; {ONE_PER_FRAME}"
        )
    return scene, outcome


def frame_check(seq: FrameSequence, path: str, samples: int = FRAME_CHECKS) -> FrameCheck:
    """Decode a few frames of the written container and compare them with their source."""
    frames = spread(seq.count, samples)
    worst: dict[str, float] = {}
    unpaired: list[tuple[int, int]] = []
    with open_stream(path) as reader:
        for k in frames:
            source = seq.read(k, k + 1).scene.gaussians
            errors, missed = frame_errors(source, reader.frame_at(k / seq.fps))
            if missed:
                unpaired.append((k, missed))
            for name, value in errors.items():
                worst[name] = max(worst.get(name, 0.0), value)
    return FrameCheck(frames=frames, worst=worst, unpaired=unpaired)


@contextlib.contextmanager
def _thumbnail_drawer(*, separate: bool) -> Iterator[Callable[[str], bytes]]:
    """:func:`inputs.thumbnail_png`, run here or (``separate``) in a process of its own started
    now, so it loads the renderer while this one segments. Why: this process's heap still holds
    what segmenting freed, and the renderer loaded on top of it was the run's peak
    (docs/design/segmenter.md, "Memory by process")."""
    if not separate:
        yield thumbnail_png
        return
    with engine(1, None, largest_job=1) as drawing:
        drawing.submit(0, _load_renderer)
        yield lambda container: drawing.submit(1, thumbnail_png, container).result()


def _load_renderer() -> None:
    """Load the renderer's compiled kernel (render.warm), ignoring any failure (the drawing
    then says it)."""
    with contextlib.suppress(Exception):
        from .render import warm  # noqa: PLC0415 - numba, only when drawing

        warm()


def _write_thumbnail(container: str, draw: Callable[[str], bytes], told: Listener) -> str | None:
    """The scene list's picture beside the container, or None (told why: the container is
    whole without it)."""
    told("drawing the thumbnail")
    target = thumbnail_path(container)
    try:
        atomic_write_bytes(target, draw(container))
    except TsogError as exc:
        told.note(f"no thumbnail: {exc}")
        return None
    except BrokenProcessPool:
        told.note("no thumbnail: the process drawing it ended")
        return None
    told.done()
    return target


def input_bytes(path: str | os.PathLike[str]) -> int:
    """Size of an input file, folder or store prefix (0 for a pattern)."""
    text = str(path)
    if is_object_url(text):
        return 0 if any(c in text for c in "*?[") else ObjectPath.from_url(text).total_bytes()
    p = Path(text)
    if p.is_file():
        return p.stat().st_size
    if p.is_dir():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return 0
