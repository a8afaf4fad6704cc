"""Live streams: frames in as a capture writes them, windows out as they are encoded.

:func:`run_live` watches a folder (:mod:`..io.arrivals`), cuts its frames into windows of whole
frames, encodes each window as ``tsog segment`` encodes a frame sequence's window
(:func:`.sequence.encode_window`, on the workers), and publishes the unpacked layout: a
window's chunks first (immutable), then the index, republished whole with one more
``live.sequence``, the live edge (``scene.end_s``) and each window's arrival and publish times
(docs/spec.md §8.8). A restart with the same options resumes from the published index.
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
import time
from collections import deque
from collections.abc import Sequence
from concurrent.futures import Future
from contextlib import ExitStack
from dataclasses import dataclass

from ..codec.precision import QUALITY_MAX
from ..constants import DEFAULT_MAX_PIXELS, SH_BANDS_BY_COEFFS, SH_COEFFS_BY_BANDS
from ..container.header import PREFIX_SIZE
from ..container.index import MAX_INDEX_BYTES
from ..errors import InputError, SourceError
from ..io.arrivals import Arrival, FrameArrivals
from ..io.files import atomic_write_bytes, read_head
from ..io.objects import as_location, is_object_url
from ..io.sequence import FrameWindow, frame_shape
from ..schemas.manifest import (
    ChunkEntry,
    Live,
    LiveWindow,
    Manifest,
    Policy,
    dump_manifest,
    parse_manifest,
)
from .encoding import PartInfo
from .engines import Engine, engine
from .layers import ONE_LAYER_ASKED
from .options import SegmentOptions, StageProgress, max_gaussians_per_chunk
from .plan import NodeKey, Plan
from .segmenter import views_of
from .sequence import WindowJob, encode_window
from .write import Views, entry_of, index_of

DEFAULT_WINDOW_S = 1.0
"""Window length of a live stream: a frame waits at most this long for its window, so it
bounds the latency (docs/live.md)."""
DEFAULT_IDLE_S = 30.0
"""Seconds without a new frame after which an event ends."""
MAX_FPS = 1000.0
MAX_WINDOW_S = 60.0
"""The highest frame rate and longest window taken (bounds: a window is held in memory)."""
POLL_S = 0.05
"""How often the source folder is looked at."""
LIVE_POLICY: Policy = "duplicate"
"""Every window holds its own frames (a live window never waits for a later one)."""
Results = list[tuple[PartInfo, bytes]]


@dataclass(frozen=True)
class LiveOptions:
    """How a live event is cut and encoded (the encoding options and their defaults as
    :class:`.options.SegmentOptions`')."""

    fps: float
    window_s: float = DEFAULT_WINDOW_S
    idle_s: float = DEFAULT_IDLE_S
    workers: int = 1
    seed: int = 0
    quality: int = QUALITY_MAX
    max_pixels: int = DEFAULT_MAX_PIXELS

    @property
    def per_window(self) -> int:
        """Frames per window (the window rounded to whole frames, at least one)."""
        return max(1, round(self.window_s * self.fps))


@dataclass(frozen=True)
class LiveReport:
    """What a live run published."""

    output: str
    windows: int
    frames: int
    chunks: int
    payload_bytes: int
    resumed_windows: int
    """Windows already published when this run started (a restart)."""
    ended_by: str


def run_live(
    source: str | os.PathLike[str],
    output: str,
    options: LiveOptions,
    *,
    stop: threading.Event | None = None,
    on_stage: StageProgress | None = None,
    overwrite: bool = False,
) -> LiveReport:
    """Follow the frames written into ``source`` and publish them as a live stream at
    ``output`` (a folder or a storage prefix) until the event ends: an end marker in
    ``source``, ``options.idle_s`` without a frame, or ``stop`` set (a signal). The last
    window, whole or not, is published, then the index marked ended. An unfinished stream at
    ``output`` made with the same frame rate and window is resumed; an ended one is refused
    unless ``overwrite``."""
    _check_options(options)
    told = on_stage or (lambda _: None)
    stop = stop or threading.Event()
    index = LiveIndex.resumed(output, options, overwrite=overwrite)
    arrivals = FrameArrivals(source, skip=index.frames)
    if index.windows:
        told(f"resuming after window {index.windows} ({index.frames} frames published)")
    with ExitStack() as stack:
        ended_by = _follow(arrivals, index, _Encoder(options.workers, stack), stop, told)
        if not index.windows:
            raise InputError(
                f"no frame arrived before the event ended ({ended_by})", where=str(source)
            )
        index.publish(ended=True)
    told(f"ended ({ended_by}): {index.windows} windows, {index.frames} frames")
    return LiveReport(
        output,
        index.windows,
        index.frames,
        len(index.entries),
        index.payload_bytes,
        index.resumed_windows,
        ended_by,
    )


def _check_options(options: LiveOptions) -> None:
    """Refuse a frame rate, window or idle time that is not a finite positive number within
    its bound."""
    checks = (
        ("--fps", options.fps, MAX_FPS),
        ("--window", options.window_s, MAX_WINDOW_S),
        ("--idle", options.idle_s, math.inf),
    )
    for name, value, bound in checks:
        if not (math.isfinite(value) and 0 < value <= bound):
            most = f" up to {bound:g}" if math.isfinite(bound) else ""
            raise InputError(f"must be a positive number{most}, got {value}", where=name)


class _Encoder:
    """Where windows are encoded: here (one worker), or on worker processes started when the
    first frame arrives, so they are up (imports done) by the time its window is complete."""

    def __init__(self, workers: int, stack: ExitStack) -> None:
        self.workers = workers
        self.stack = stack
        self.running: Engine | None = None

    def warm(self) -> None:
        """Start the workers (kept for the event: a window's memory is bounded, and a
        replaced worker would make some window wait for its start)."""
        if self.workers <= 1 or self.running is not None:
            return
        self.running = self.stack.enter_context(engine(self.workers, None, largest_job=None))
        for k in range(self.workers):
            self.running.submit(-1 - k, _ready)

    def start(self, job: WindowJob) -> Future[Results] | Results:
        """Encode a window job on the workers (its future), or here (its results)."""
        if self.workers <= 1:
            return encode_window(job)
        self.warm()
        assert self.running is not None
        return self.running.submit(job.index, encode_window, job)

    @property
    def slots(self) -> int:
        """Windows encoded at once."""
        return self.workers


def _ready() -> None:
    """A worker's first job: nothing, once this module (and the codec) is imported there."""


def _follow(
    arrivals: FrameArrivals,
    index: LiveIndex,
    encoder: _Encoder,
    stop: threading.Event,
    told: StageProgress,
) -> str:
    """Take frames as they arrive, encode each full window and publish windows in order,
    until the event ends; the last frames (a partial window) are published too. Returns
    what ended it."""
    frames: list[Arrival] = []
    flight: deque[tuple[list[Arrival], Future[Results] | Results]] = deque()
    last_frame = time.monotonic()
    ended_by, told_out = "", 0
    while not ended_by:
        # publish first (it may wait on the workers), then look: the idle clock and the end
        # are judged on what the folder holds now, never on a look taken before a long wait
        _publish_done(flight, index, told, wait=len(flight) > 2 * encoder.slots)
        fresh = arrivals.poll()
        if fresh:
            last_frame = time.monotonic()
            encoder.warm()
        for said in arrivals.left_out[told_out:]:
            told(said)
        told_out = len(arrivals.left_out)
        frames += fresh
        while len(frames) >= index.options.per_window:
            window, frames = frames[: index.options.per_window], frames[index.options.per_window :]
            flight.append((window, encoder.start(index.window_job(window))))
        ended_by = _ended(arrivals, stop, time.monotonic() - last_frame, index.options.idle_s)
        if not ended_by:
            stop.wait(POLL_S)
    if frames:
        flight.append((frames, encoder.start(index.window_job(frames))))
    _publish_done(flight, index, told, wait=True)
    return ended_by


def _ended(arrivals: FrameArrivals, stop: threading.Event, idle: float, idle_s: float) -> str:
    """Why the event is over ("" while it goes on): a frame still settling is not idleness."""
    if stop.is_set():
        return "stopped"
    if arrivals.ended() and not arrivals.waiting():
        return "end marker"
    if idle >= idle_s and not arrivals.waiting():
        return f"no frame for {idle_s:g} s"
    return ""


def _publish_done(
    flight: deque[tuple[list[Arrival], Future[Results] | Results]],
    index: LiveIndex,
    told: StageProgress,
    *,
    wait: bool,
) -> None:
    """Publish the windows at the head of ``flight`` that are encoded (``wait``: all of
    them, waiting for each)."""
    while flight:
        frames, job = flight[0]
        if isinstance(job, Future):
            if not (wait or job.done()):
                return
            job = job.result()
        flight.popleft()
        index.add(frames, job)
        index.publish(ended=False)
        late = time.time() - frames[0].arrived_s
        told(
            f"window {index.windows - 1} published: frames {frames[0].index + 1}-"
            f"{frames[-1].index + 1}, edge {index.edge_s:.2f} s, {late:.2f} s after its first frame"
        )


class LiveIndex:
    """A live stream's published state: its chunks, windows and index, and how to add a
    window and republish."""

    def __init__(self, output: str, options: LiveOptions, manifest: Manifest | None = None):
        self.output = output
        self.options = options
        self.entries: list[ChunkEntry] = list(manifest.chunks) if manifest else []
        self.keys = [NodeKey(c.level, c.node) for c in self.entries]
        live = manifest.live if manifest else None
        self.times: list[LiveWindow] = list(live.windows) if live else []
        self.sequence = live.sequence if live else 0
        self.frames = round(manifest.scene.end_s * options.fps) if manifest else 0
        self.resumed_windows = len(self.times)
        self.views: Views | None = None
        self.sh_coeffs: int | None = None
        if manifest is not None:
            core = manifest.scene.core
            kept = None if core is None else {"center": core.center, "radius": core.radius}
            self.views = Views(list(manifest.cameras), manifest.view, kept)
            self.sh_coeffs = SH_COEFFS_BY_BANDS[manifest.scene.sh_bands]

    @classmethod
    def resumed(cls, output: str, options: LiveOptions, *, overwrite: bool) -> LiveIndex:
        """The stream published at ``output`` to go on with, or a new one."""
        manifest = _published(output)
        if manifest is None or overwrite:
            return cls(output, options)
        if manifest.live is None or manifest.live.ended:
            what = "a recorded stream" if manifest.live is None else "an ended live stream"
            raise SourceError(f"holds {what} (pass --force to replace it)", where=output)
        window_s = options.per_window / options.fps
        if manifest.scene.fps != options.fps or abs(manifest.window_s - window_s) > 1e-9:
            raise InputError(
                f"resumes a stream of {manifest.scene.fps} fps in {manifest.window_s} s windows: "
                "give the same --fps and --window",
                where=output,
            )
        return cls(output, options, manifest)

    @property
    def windows(self) -> int:
        """Windows published."""
        return len(self.times)

    @property
    def edge_s(self) -> float:
        """The live edge: the end of the last frame published."""
        return self.frames / self.options.fps

    @property
    def payload_bytes(self) -> int:
        """Bytes of the chunks published."""
        return sum(e.length for e in self.entries)

    def window_job(self, frames: Sequence[Arrival]) -> WindowJob:
        """The window job of ``frames``; the first frame fixes the event's kind, SH
        coefficients and opening view."""
        first = frames[0].index
        w = first // self.options.per_window
        kind = frames[0].kind
        shapes = [frame_shape(kind, a.path) for a in frames]
        if self.sh_coeffs is None:
            self.sh_coeffs = shapes[0][1]
        for a, (_, coeffs) in zip(frames, shapes, strict=True):
            if coeffs > self.sh_coeffs:
                raise InputError(
                    f"has {coeffs} SH coefficients, more than the event's {self.sh_coeffs}",
                    where=str(a.path),
                )
        stop = first + len(frames)
        window = FrameWindow(
            kind, [a.path for a in frames], shapes, self.sh_coeffs, self.options.fps, first, stop
        )
        if self.views is None:  # framed on the event's first frame
            first_frame = FrameWindow(
                kind,
                window.paths[:1],
                shapes[:1],
                self.sh_coeffs,
                self.options.fps,
                first,
                first + 1,
            )
            self.views = views_of(first_frame.read().scene.gaussians, ())
        plan = Plan(0.0, stop / self.options.fps, self._window_s, w + 1, {}, 0)
        return WindowJob(
            window,
            w,
            self._max_count,
            ONE_LAYER_ASKED,
            plan,
            self.options.seed,
            self.options.quality,
        )

    @property
    def _window_s(self) -> float:
        return self.options.per_window / self.options.fps

    @property
    def _max_count(self) -> int:
        bands = SH_BANDS_BY_COEFFS[self.sh_coeffs or 0]
        return max_gaussians_per_chunk(self.options.max_pixels, bands)

    def add(self, frames: Sequence[Arrival], results: Results) -> None:
        """Write a window's chunks (each its own immutable file) and count them in."""
        offset = PREFIX_SIZE + self.payload_bytes
        for info, payload in results:
            i = len(self.entries)
            atomic_write_bytes(_at(self.output, f"chunks/{i:06d}.sog"), payload)
            digest = hashlib.sha256(payload).hexdigest()
            self.entries.append(entry_of(i, info, offset, len(payload), digest))
            self.keys.append(info.key)
            offset += len(payload)
        self.frames = frames[-1].index + 1
        self.times.append(LiveWindow(frames[0].arrived_s, 0.0))

    def publish(self, *, ended: bool) -> None:
        """Republish the index (one more sequence number; the windows added since the last
        publish are stamped with its time)."""
        now = time.time()
        self.times = [w if w.published_s else LiveWindow(w.arrived_s, now) for w in self.times]
        self.sequence += 1
        atomic_write_bytes(_at(self.output, "manifest.json"), dump_manifest(self._manifest(ended)))

    def _manifest(self, ended: bool) -> Manifest:
        """The index of what is published, as ``tsog segment`` writes a frame sequence's."""
        counted = sum(e.count for e in self.entries if e.holds_gaussians)
        fields = {
            "gaussians": counted,
            "stored": counted,
            "fps": self.options.fps,
            "timeline_type": 0,
            "temporal": {},
            "sh_bands": SH_BANDS_BY_COEFFS[self.sh_coeffs or 0],
        }
        plan = Plan(0.0, self.edge_s, self._window_s, self.windows, {}, 0)
        segment = SegmentOptions(policy=LIVE_POLICY, max_pixels=self.options.max_pixels)
        return index_of(
            self.entries,
            self.keys,
            plan=plan,
            scene_fields=fields,
            options=segment,
            views=self.views or Views([], None, None),
            layering=ONE_LAYER_ASKED,
            live=Live(sequence=self.sequence, ended=ended, windows=self.times),
        )


def _at(output: str, name: str) -> str:
    """The location of ``name`` in the layout at ``output`` (a folder or a storage prefix)."""
    if is_object_url(output):
        return f"{output.rstrip('/')}/{name}"
    return os.path.join(output, name)


def _published(output: str) -> Manifest | None:
    """The index published at ``output``, or None when there is none."""
    where = _at(output, "manifest.json")
    try:
        location = as_location(where)
        if not location.exists():
            return None
        data = read_head(location, MAX_INDEX_BYTES + 1)  # bounded before it is held whole
    except OSError as exc:
        raise SourceError(f"cannot read: {exc.strerror or exc}", where=where) from exc
    if len(data) > MAX_INDEX_BYTES:
        raise SourceError(
            f"index over {MAX_INDEX_BYTES} bytes: not a stream to resume", where=where
        )
    return parse_manifest(data, where=where)


__all__ = [
    "DEFAULT_IDLE_S",
    "DEFAULT_WINDOW_S",
    "LiveIndex",
    "LiveOptions",
    "LiveReport",
    "run_live",
]
