"""Render a reference and a candidate at the same times and cameras; compare with PSNR/SSIM.

A :class:`Source` is a scene at time t (:func:`scene_source`, or any input through
:func:`tsog_stream.inputs.open_source`); cameras orbit the reference or come from a cameras.json.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from ..constants import EVAL_MAX_TIMES, RENDER_MAX_SIDE, RENDER_MAX_VIEWS
from ..errors import InputError
from ..framing import default_view
from ..model import Gaussians, Scene
from ..schemas.cameras import Camera
from ..temporal import time_range
from . import render, to_uint8
from .camera import (
    DEFAULT_PIXELS,
    RENDER_MAX_PIXELS,
    check_image_size,
    from_capture,
    load_cameras_json,
    scene_orbit,
)
from .metrics import mse, psnr_from_mse, ssim

Span = tuple[float, float]
DEFAULT_WIDTH = 640
StepCallback = Callable[[int, int], None]
"""Called with (steps done, steps in all) while an evaluation runs."""


@dataclass
class Source:
    """A scene that can be shown at any time: ``at(t)`` gives its static Gaussians."""

    name: str
    kind: str
    span: Span | None
    """(first, last) second of a 4D scene; None for a static one (shown at t = 0)."""
    frame: Callable[[float], Gaussians]
    closer: Callable[[], None] = lambda: None
    notes: list[str] = field(default_factory=list)
    fps: float | None = None
    """Frame rate of a frame-based scene (timeline types 0 and 1 with ``fps``), else None."""
    cameras: list[Camera] = field(default_factory=list)
    """Capture cameras the input carries, sits beside, or its container stores."""
    opening: Callable[[], Camera | None] = lambda: None
    """Where a viewer opens the scene (framing.default_view), computed when asked."""
    pieces: Callable[[float], Iterator[Scene]] | None = None
    """The scenes of the chunks that show t, one at a time (a container); None: ``frame``."""

    def at(self, t: float) -> Gaussians:
        """The Gaussians visible at ``t`` seconds."""
        return self.frame(t)

    def scenes_at(self, t: float) -> Iterator[Scene]:
        """Scenes whose Gaussians visible at ``t`` together are :meth:`at`'s."""
        if self.pieces is None:
            yield Scene(self.frame(t))
        else:
            yield from self.pieces(t)

    def close(self) -> None:
        """Release the reader behind the source (files, event loop, HTTP session)."""
        self.closer()

    def __enter__(self) -> Source:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def scene_source(scene: Scene, name: str = "scene", cameras: Sequence[Camera] = ()) -> Source:
    """An in-memory scene as a :class:`Source` (for scripts, tests and benchmarks)."""
    timeline = scene.timeline
    span = time_range(timeline) if timeline is not None else None
    fps = timeline.fps if timeline is not None else None
    return Source(
        name,
        "scene",
        span,
        scene.at,
        fps=fps,
        cameras=list(cameras),
        opening=lambda: default_view(scene.gaussians, cameras),
    )


def sample_times(span: Span | None, count: int, fps: float | None = None) -> list[float]:
    """``count`` times at the centres of equal slices of ``span`` (a lifespan's end is
    exclusive); [0.0] for a static scene. With ``fps`` each moves back to its frame's start,
    so frames are compared with frames, not with a fitted motion between them."""
    if not 1 <= count <= EVAL_MAX_TIMES:
        raise InputError(f"expected 1-{EVAL_MAX_TIMES} times, got {count}", where="--times")
    if span is None:
        return [0.0]
    start, end = span
    if not end > start:
        return [start]
    step = (end - start) / count
    times = [start + (i + 0.5) * step for i in range(count)]
    if fps:
        times = [math.floor(t * fps + 1e-9) / fps for t in times]
    return times


def pick_evenly(items: Sequence[Camera], count: int | None) -> list[Camera]:
    """``count`` items spread evenly over ``items`` (all when ``count`` is None)."""
    if count is None or count >= len(items):
        return list(items)
    if count < 1:
        raise InputError(f"expected at least 1 view, got {count}", where="--views")
    picks = np.linspace(0, len(items) - 1, count).round().astype(int)
    return [items[i] for i in picks]


@dataclass(frozen=True)
class CameraSetup:
    """Where cameras come from: an orbit of ``views`` around the scene, or a cameras.json."""

    views: int | None = 4
    width: int | None = None
    height: int | None = None
    cameras_json: str | os.PathLike[str] | None = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """The orbit's up axis (+z by default; COLMAP-style captures are usually -y up)."""

    def size(self) -> tuple[int, int]:
        """Image size of orbit cameras (640x480 unless given)."""
        return (self.width or 640, self.height or 480)

    def check(self) -> None:
        """Refuse sizes and counts that cannot make an image."""
        for name, value in (("--width", self.width), ("--height", self.height)):
            if value is not None and not 1 <= value <= RENDER_MAX_SIDE:
                raise InputError(f"expected 1-{RENDER_MAX_SIDE} pixels, got {value}", where=name)
        if self.width is not None and self.height is not None:
            check_image_size(self.width, self.height, where="--width/--height")
        if self.views is not None and not 1 <= self.views <= RENDER_MAX_VIEWS:
            raise InputError(
                f"expected 1-{RENDER_MAX_VIEWS} views, got {self.views}", where="--views"
            )

    def fixed(self) -> list[Camera] | None:
        """The cameras of the cameras.json (the same at every t), or None for orbits."""
        if self.cameras_json is None:
            return None
        cameras = load_cameras_json(self.cameras_json, self.width, self.height)
        if not cameras:
            raise InputError("holds no cameras", where=os.fspath(self.cameras_json))
        return pick_evenly(cameras, self.views)

    def around(self, frame: Gaussians, t: float) -> list[Camera]:
        """Orbit cameras around ``frame`` (the reference at ``t``)."""
        if len(frame) == 0:
            raise InputError(f"the reference shows no Gaussians at t = {t:g} s to aim cameras at")
        width, height = self.size()
        check_image_size(width, height, where="--width/--height")
        return scene_orbit(frame, self.views or 4, width, height, up=self.up)


@dataclass(frozen=True)
class RenderStyle:
    """How images are drawn: background colour (RGB in [0, 1]) and the rasterizer variant."""

    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    antialiased: bool = False

    def image(self, frame: Gaussians, camera: Camera) -> npt.NDArray[np.uint8]:
        """The 8-bit RGB image of ``frame`` seen by ``camera``."""
        drawn = render(frame, camera, background=self.background, antialiased=self.antialiased)
        return to_uint8(drawn)


def render_view(
    source: Source,
    t: float,
    view: int,
    setup: CameraSetup,
    style: RenderStyle | None = None,
) -> npt.NDArray[np.uint8]:
    """The 8-bit image of ``source`` at ``t`` from camera ``view`` (0-based) of ``setup``."""
    setup.check()
    frame = source.at(t)
    cameras = setup.fixed() or setup.around(frame, t)
    if not 0 <= view < len(cameras):
        raise InputError(f"no view {view}; there are views 0-{len(cameras) - 1}", where="--view")
    return (style or RenderStyle()).image(frame, cameras[view])


def opening_camera(
    source: Source, camera: int | None, width: int | None, height: int | None
) -> Camera:
    """Capture camera ``camera`` of the source, or (None) the view it opens from, drawn at
    ``width`` x ``height`` as a player window shows it (:func:`.camera.from_capture`); neither
    given: DEFAULT_WIDTH wide at the camera's aspect."""
    if camera is not None:
        if not source.cameras:
            raise InputError(
                "the input has no capture cameras (give them with --cameras)", where="--camera"
            )
        if not 0 <= camera < len(source.cameras):
            last = len(source.cameras) - 1
            raise InputError(f"no camera {camera}; there are cameras 0-{last}", where="--camera")
        chosen = source.cameras[camera]
    else:
        opening = source.opening()
        if opening is None:
            raise InputError("the scene shows nothing to aim a camera at")
        chosen = opening
    if width is not None and height is not None:
        check_image_size(width, height, where="--width/--height")
    if width is None and height is None:
        return from_capture(chosen, DEFAULT_WIDTH, budget=DEFAULT_PIXELS)
    return from_capture(chosen, width, height, budget=RENDER_MAX_PIXELS)


def json_psnr(value: float) -> float | None:
    """A PSNR for JSON, which has no infinity: null stands for identical images."""
    return None if math.isinf(value) else value


@dataclass(frozen=True)
class EvalRow:
    """One comparison: time, view, and the metrics of the candidate against the reference."""

    t: float
    view: int
    psnr: float
    ssim: float
    mse: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: an infinite PSNR (identical images) is written as null."""
        return {**asdict(self), "psnr": json_psnr(self.psnr)}


@dataclass(frozen=True)
class TimeSummary:
    """Mean and worst metrics over the views at one time."""

    t: float
    psnr_mean: float
    psnr_worst: float
    ssim_mean: float
    ssim_worst: float


def mean_psnr(values: Sequence[float]) -> float:
    """Mean of per-image PSNRs; identical images (inf) are left out unless all are identical."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.inf


@dataclass(frozen=True)
class EvalReport:
    """Every (t, view) comparison with the size and names of what was compared."""

    reference: str
    candidate: str
    width: int
    height: int
    rows: tuple[EvalRow, ...]

    def times(self) -> list[TimeSummary]:
        """Per-time means and worst cases, in time order."""
        out = []
        for t in sorted({r.t for r in self.rows}):
            at = [r for r in self.rows if r.t == t]
            ps, ss = [r.psnr for r in at], [r.ssim for r in at]
            out.append(TimeSummary(t, mean_psnr(ps), min(ps), float(np.mean(ss)), min(ss)))
        return out

    def summary(self) -> dict[str, Any]:
        """Means over all rows, the worst rows and how many images were identical."""
        worst_p = min(self.rows, key=lambda r: r.psnr)
        worst_s = min(self.rows, key=lambda r: r.ssim)
        return {
            "images": len(self.rows),
            "identical": sum(1 for r in self.rows if r.mse == 0),
            "psnr_mean": mean_psnr([r.psnr for r in self.rows]),
            "ssim_mean": float(np.mean([r.ssim for r in self.rows])),
            "psnr_worst": {"t": worst_p.t, "view": worst_p.view, "psnr": worst_p.psnr},
            "ssim_worst": {"t": worst_s.t, "view": worst_s.view, "ssim": worst_s.ssim},
        }

    def to_dict(self) -> dict[str, Any]:
        """The whole report, JSON-safe (infinite PSNRs, from identical images, as null)."""
        summary = self.summary()
        summary["psnr_mean"] = json_psnr(summary["psnr_mean"])
        summary["psnr_worst"]["psnr"] = json_psnr(summary["psnr_worst"]["psnr"])
        return {
            "reference": self.reference,
            "candidate": self.candidate,
            "width": self.width,
            "height": self.height,
            "summary": summary,
            "rows": [r.to_dict() for r in self.rows],
        }


def evaluate(
    reference: Source,
    candidate: Source,
    *,
    times: int = 5,
    setup: CameraSetup | None = None,
    style: RenderStyle | None = None,
    on_step: StepCallback | None = None,
) -> EvalReport:
    """Render both sources at ``times`` times of the reference's range and compare each view."""
    setup = setup or CameraSetup()
    style = style or RenderStyle()
    setup.check()
    moments = sample_times(reference.span, times, reference.fps)
    fixed = setup.fixed()
    total = len(moments) * (len(fixed) if fixed is not None else setup.views or 4)
    rows: list[EvalRow] = []
    size = (0, 0)
    for t in moments:
        ref_frame, cand_frame = reference.at(t), candidate.at(t)
        cameras = fixed if fixed is not None else setup.around(ref_frame, t)
        size = (cameras[0].width, cameras[0].height)
        for view, camera in enumerate(cameras):
            a, b = style.image(ref_frame, camera), style.image(cand_frame, camera)
            err = mse(a, b)
            rows.append(EvalRow(t, view, psnr_from_mse(err), ssim(a, b), err))
            if on_step is not None:
                on_step(len(rows), total)
    return EvalReport(reference.name, candidate.name, size[0], size[1], tuple(rows))
