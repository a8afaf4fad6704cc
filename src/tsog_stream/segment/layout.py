"""The layout of a segmentation chosen per scene by a cost model (``--window auto``).

Each candidate layout (window length x policy) is estimated from the Gaussians' lifespans and
two small encoded samples (:func:`measure_costs`): the file's bytes, and the bytes and requests
a seek to a random t reads. Chosen: the smallest file whose mean seek stays within SEEK_TARGET
x the visible bytes (plus the opening), among files within FILE_SLACK of the smallest; else
the one that over-fetches least (docs/design/segmenter.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Final

import numpy as np
import numpy.typing as npt

from ..codec.bundle import bundle_bytes
from ..codec.chunk import encode_chunk
from ..container.header import HEADER_SIZE, PREFIX_SIZE, container_length
from ..errors import InputError
from ..model import Scene
from ..morton import morton_run
from ..schemas.manifest import Policy
from ..temporal import lifespans, time_range
from .plan import (
    DEFAULT_MAX_COPIES,
    POLICIES,
    stored_in_windows,
    tree_level,
    window_count,
    window_span,
)

F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]

SEEK_TARGET: Final = 1.25
"""A seek may fetch at most this many times the bytes of what it shows (plus the opening)."""
FILE_SLACK: Final = 1.15
"""A layout is considered only if its file is at most this much larger than the smallest
(playback reads the whole stream: its bitrate is the file size)."""
OVERFETCH_WARNING: Final = 2.0
"""An explicit layout whose seeks fetch more than this many times what they show is warned."""
SAMPLE_TIMES: Final = 64
"""Times at which a layout's seek is estimated (stratified over the scene)."""
MAX_ENTRIES: Final = 100_000
"""Lifespans the model looks at; more are sampled (weights scaled), so choosing stays fast."""
MAX_STORED_FACTOR: Final = 8
"""A layout storing more than this many copies per Gaussian is not worth estimating."""
MAX_WINDOWS: Final = 20_000
"""Most windows a candidate may have (each is an index node; the index stays small)."""
INDEX_BYTES_PER_CHUNK: Final = 120
"""Compressed index bytes per chunk (zstd of its JSON entry: the SHA-256 is most of it)."""
SAMPLE_GAUSSIANS: Final = 8192
"""Gaussians of the larger sample encoded to measure bytes per Gaussian."""
SLICES: Final = (2, 4, 8)
"""Time slices per window tried for hierarchy and hybrid (a node's chunks cut by start time)."""
FRAME_WINDOWS: Final = (1, 2, 3, 5, 10, 15, 30, 60, 120)
"""Candidate windows, in frames, of content with a frame rate."""
SECOND_WINDOWS: Final = (1 / 30, 1 / 15, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
"""Candidate windows, in seconds, of content without one."""
_LEVEL_SHIFT = 40
_PREFERRED: dict[str, int] = {"hybrid": 0, "hierarchy": 1, "duplicate": 2}


@dataclass(frozen=True)
class Costs:
    """What storing costs: bytes per Gaussian, fixed bytes per chunk (zip, ``meta.json``,
    codebooks, SH palette), and the Gaussians a chunk may hold under the pixel budget."""

    per_gaussian: float
    per_chunk: float
    max_count: int


@dataclass(frozen=True)
class Lifespans:
    """What the model needs of a scene: lifespans [start, end) in seconds, each with a weight
    (the Gaussians sharing it: a flipbook frame is one entry weighing its Gaussian count)."""

    start: F64
    end: F64
    weight: F64
    scene_start: float
    scene_end: float
    fps: float | None

    @classmethod
    def of_scene(cls, scene: Scene) -> Lifespans:
        """The lifespans of a 4D scene, sampled down to MAX_ENTRIES."""
        if scene.timeline is None:
            raise ValueError("a static scene has no lifespans")
        start, end = lifespans(scene.timeline)
        first, last = time_range(scene.timeline)
        weight = np.ones(start.size)
        if start.size > MAX_ENTRIES:
            pick = np.random.default_rng(0).choice(start.size, MAX_ENTRIES, replace=False)
            start, end = start[pick], end[pick]
            weight = np.full(MAX_ENTRIES, len(scene) / MAX_ENTRIES)
        return cls(start, end, weight, first, last, scene.timeline.fps)

    @classmethod
    def of_frames(cls, counts: list[int], fps: float) -> Lifespans:
        """A sequence of frames, each visible for one frame time."""
        k = np.arange(len(counts), dtype=np.float64)
        weight = np.asarray(counts, dtype=np.float64)
        return cls(k / fps, (k + 1) / fps, weight, 0.0, len(counts) / fps, fps)

    @property
    def carries_over(self) -> bool:
        """Whether any Gaussian outlives one frame (always, without a frame rate)."""
        if not self.fps:
            return True
        return bool(np.any(self.end - self.start > (1 + 1e-6) / self.fps))

    def visible(self, times: F64) -> F64:
        """Gaussians visible at each time (start <= t < end)."""
        starts, began, ends, ended = self._running_totals
        n_began = np.searchsorted(starts, times, side="right")
        n_ended = np.searchsorted(ends, times, side="right")
        return np.asarray(began[n_began] - ended[n_ended], dtype=np.float64)

    @cached_property
    def _running_totals(self) -> tuple[F64, F64, F64, F64]:
        """Starts and ends sorted, with the weight begun / ended up to each (sorted once for
        every layout estimated)."""
        by_start, by_end = np.argsort(self.start), np.argsort(self.end)
        began = np.concatenate(([0.0], np.cumsum(self.weight[by_start])))
        ended = np.concatenate(([0.0], np.cumsum(self.weight[by_end])))
        return self.start[by_start], began, self.end[by_end], ended


@dataclass(frozen=True)
class Layout:
    """How time is cut (window length), where crossing Gaussians go (policy), and whether a
    node's chunks are cut by when their Gaussians start (``slice_s``; None: Morton runs only),
    so a seek skips a chunk that shows nothing at t."""

    window_s: float
    policy: Policy
    slice_s: float | None = None

    def describe(self, fps: float | None) -> str:
        """'window 1 frame, hybrid' or 'window 0.5 s, hierarchy, slices of 0.125 s'."""
        frames = self.window_s * fps if fps else 0.0
        if fps and abs(frames - round(frames)) < 1e-6:
            n = round(frames)
            text = f"window {n} frame{'s' if n != 1 else ''} ({self.window_s:.3g} s), {self.policy}"
        else:
            text = f"window {self.window_s:.3g} s, {self.policy}"
        if self.slice_s is not None:
            text += f", chunks cut by start time in slices of {self.slice_s:.3g} s"
        return text


@dataclass(frozen=True)
class Estimate:
    """A layout's estimated file and seeks (bytes; a seek includes the opening)."""

    layout: Layout
    file_bytes: float
    chunks: int
    seek_mean: float
    seek_worst: float
    shown_mean: float
    """Bytes of a standalone chunk of the Gaussians visible at t (what a flipbook frame is)."""
    requests: float
    opening: float = PREFIX_SIZE
    """Bytes read before any chunk: the 16 KiB prefix, and the index when it does not fit."""

    @property
    def overfetch(self) -> float:
        """Mean seek bytes, the opening left out, over the bytes of what is shown."""
        return (self.seek_mean - self.opening) / max(self.shown_mean, 1.0)

    @property
    def meets_target(self) -> bool:
        """Whether a mean seek stays within SEEK_TARGET x what it shows plus the opening."""
        return self.seek_mean <= SEEK_TARGET * self.shown_mean + PREFIX_SIZE


@dataclass(frozen=True)
class Choice:
    """The layout chosen, every layout estimated, and why (one line for the summary)."""

    chosen: Estimate
    tried: tuple[Estimate, ...]
    reason: str
    explicit: bool


def measure_costs(scene: Scene, max_count: int, seed: int = 0, quality: int = 100) -> Costs:
    """Bytes per Gaussian and per chunk, from encoding two Morton-contiguous samples (like real
    chunks) of SAMPLE_GAUSSIANS and an eighth of it at ``quality``."""
    n = min(len(scene), SAMPLE_GAUSSIANS)
    if n < 16:
        return Costs(per_gaussian=32.0, per_chunk=2048.0, max_count=max_count)
    big = morton_run(scene.gaussians.means, (len(scene) - n) // 2, n)
    small = big[: n // 8]
    big_bytes = len(bundle_bytes(encode_chunk(scene.subset(big), seed=seed, quality=quality)))
    small_bytes = len(bundle_bytes(encode_chunk(scene.subset(small), seed=seed, quality=quality)))
    per_gaussian = max((big_bytes - small_bytes) / (n - small.size), 0.5)
    per_chunk = max(small_bytes - small.size * per_gaussian, 0.0)
    return Costs(per_gaussian, per_chunk, max_count)


@dataclass(frozen=True)
class _Nodes:
    """The units a layout fills, one per (node, time slice): node key (level << 40 | index),
    Gaussians, and visible interval clipped to the node."""

    key: Ints
    count: F64
    start: F64
    end: F64


def _fill(life: Lifespans, layout: Layout, windows: int) -> _Nodes | None:
    """Gaussians per unit under the layout (None when it would store too many copies)."""
    alive = (life.end > life.scene_start) & (life.start <= life.scene_end)
    start, end, weight = life.start[alive], life.end[alive], life.weight[alive]
    first, last = window_span(start, end, life.scene_start, layout.window_s, windows)
    copies = last - first + 1
    dup = stored_in_windows(copies, layout.policy, DEFAULT_MAX_COPIES)
    if int(copies[dup].sum()) > MAX_STORED_FACTOR * max(start.size, 1):
        return None
    counts = copies[dup]
    rep = np.repeat(np.flatnonzero(dup), counts)
    win = first[rep] + np.arange(rep.size) - np.repeat(np.cumsum(counts) - counts, counts)
    level = tree_level(first[~dup], last[~dup])
    members = np.concatenate([rep, np.flatnonzero(~dup)])
    keys = np.concatenate([win, (first[~dup] >> level) | (level << _LEVEL_SHIFT)])
    if keys.size == 0:
        return _Nodes(keys, np.zeros(0), np.zeros(0), np.zeros(0))
    node_lo, node_hi = _node_span(keys, life.scene_start, life.scene_end, layout.window_s)
    slices = time_slices(start[members], node_lo, layout.slice_s)
    order = np.lexsort((slices, keys))
    keys, slices, members = keys[order], slices[order], members[order]
    node_lo, node_hi = node_lo[order], node_hi[order]
    cut = np.flatnonzero((np.diff(keys) != 0) | (np.diff(slices) != 0)) + 1
    heads = np.concatenate(([0], cut))
    return _Nodes(
        keys[heads],
        np.add.reduceat(weight[members], heads),
        np.maximum(np.minimum.reduceat(start[members], heads), node_lo[heads]),
        np.minimum(np.maximum.reduceat(end[members], heads), node_hi[heads]),
    )


def time_slices(start: F64, node_start: F64, slice_s: float | None) -> Ints:
    """The time slice of each Gaussian in its node: whole slices of ``slice_s`` from the
    node's start to the Gaussian's (0 for one starting before the node, or without slices)."""
    if slice_s is None:
        return np.zeros(start.size, np.int64)
    return np.maximum(np.floor((start - node_start) / slice_s), 0).astype(np.int64)


def _node_span(key: Ints, t0: float, t1: float, window_s: float) -> tuple[F64, F64]:
    """Seconds each node covers, clipped to the scene (as Plan.node_interval)."""
    level = key >> _LEVEL_SHIFT
    index = key & ((1 << _LEVEL_SHIFT) - 1)
    span = window_s * np.exp2(level.astype(np.float64))
    lo = t0 + index * span
    return lo, np.minimum(lo + span, t1)


def sample_times(life: Lifespans) -> F64:
    """SAMPLE_TIMES times at the centres of equal slices of the scene."""
    span = max(life.scene_end - life.scene_start, 0.0)
    return life.scene_start + (np.arange(SAMPLE_TIMES) + 0.5) / SAMPLE_TIMES * span


EVEN_FROM = 1 << 16
"""Chunks of at most this many Gaussians or more are cut into an even number per group (below
it an extra chunk's fixed cost outweighs the balance)."""


def chunk_counts(counts: npt.ArrayLike, max_count: int) -> npt.NDArray[np.int64]:
    """The chunks a node of each count is cut into: at most ``max_count`` Gaussians each, and
    for big chunks (``max_count`` >= EVEN_FROM) an even number when more than two, so two
    workers finish a big node together."""
    n = np.ceil(np.asarray(counts, np.float64) / max(max_count, 1)).astype(np.int64)
    if max_count < EVEN_FROM:
        return n
    out: npt.NDArray[np.int64] = np.where(n > 2, n + n % 2, n)
    return out


def estimate(life: Lifespans, layout: Layout, costs: Costs) -> Estimate | None:
    """The layout's file and seek estimates (None when it stores too many copies)."""
    windows = window_count(life.scene_start, life.scene_end, layout.window_s)
    nodes = _fill(life, layout, windows)
    if nodes is None:
        return None
    chunks = chunk_counts(nodes.count, costs.max_count)
    node_bytes = nodes.count * costs.per_gaussian + chunks * costs.per_chunk
    index_bytes = INDEX_BYTES_PER_CHUNK * float(chunks.sum())
    opening = PREFIX_SIZE + (index_bytes if index_bytes > PREFIX_SIZE - HEADER_SIZE else 0.0)
    times = sample_times(life)
    fetched, requests = _seeks(nodes, node_bytes, times)
    shown = life.visible(times) * costs.per_gaussian + costs.per_chunk
    return Estimate(
        layout=layout,
        file_bytes=container_length(float(node_bytes.sum()), index_bytes),
        chunks=int(chunks.sum()),
        seek_mean=opening + float(fetched.mean()),
        seek_worst=opening + float(fetched.max()),
        shown_mean=float(shown.mean()),
        requests=1.0 + float(requests.mean()),
        opening=opening,
    )


def _seeks(nodes: _Nodes, node_bytes: F64, times: F64) -> tuple[F64, F64]:
    """Bytes and requests to show each time: every unit whose interval holds it; one request
    per node hit (its chunks are adjacent in the file)."""
    fetched = np.zeros(times.size)
    requests = np.zeros(times.size)
    if nodes.key.size == 0:
        return fetched, requests
    heads = np.concatenate(([0], np.flatnonzero(np.diff(nodes.key)) + 1))
    for lo in range(0, times.size, 16):  # 16 times at once bounds the units x times matrix
        t = times[lo : lo + 16]
        hit = (nodes.start[:, None] <= t) & (nodes.end[:, None] >= t)
        fetched[lo : lo + 16] = node_bytes @ hit
        requests[lo : lo + 16] = np.logical_or.reduceat(hit, heads, axis=0).sum(axis=0)
    return fetched, requests


def candidates(
    life: Lifespans, window_s: float | None, policy: Policy | None, slice_s: float | None = None
) -> list[Layout]:
    """Layouts to estimate: the given window (with ``slice_s``) and policy, or every candidate
    for those unset."""
    if policy is not None and policy not in POLICIES:
        raise InputError(
            f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)}", where="--policy"
        )
    policies: tuple[Policy, ...] = (policy,) if policy else POLICIES
    if window_s is not None:
        return [Layout(window_s, p, slice_s) for p in policies]
    span = max(life.scene_end - life.scene_start, 1e-9)
    lengths = [k / life.fps for k in FRAME_WINDOWS] if life.fps else list(SECOND_WINDOWS)
    fitting = [w for w in lengths if span / w <= MAX_WINDOWS and w < 2 * span]
    if not fitting:
        fitting = [max(lengths)] if span / max(lengths) <= MAX_WINDOWS else [span / MAX_WINDOWS]
    if not life.carries_over:
        return [Layout(w, policy or "hybrid") for w in fitting]  # every policy is the same
    sliced = [
        Layout(w, p, w / k)
        for w in fitting
        for p in policies
        if p != "duplicate"
        for k in SLICES
        if not life.fps or w / k >= 1 / life.fps - 1e-9
    ]
    return [Layout(w, p) for w in fitting for p in policies] + sliced


def choose_layout(
    life: Lifespans,
    costs: Costs,
    *,
    window_s: float | None = None,
    policy: Policy | None = None,
    slice_s: float | None = None,
) -> Choice:
    """The layout to use: the given one (estimated, for the summary and its warning), or, among
    layouts whose file is within FILE_SLACK of the smallest, the smallest file meeting the
    seek target, else the one over-fetching least (ties: see _smallest_then_simplest)."""
    layouts = candidates(life, window_s, policy, slice_s)
    tried = [e for layout in layouts if (e := estimate(life, layout, costs)) is not None]
    if not tried:  # every candidate stores too many copies: take the first anyway
        tried = [_unbounded(life, layouts[0], costs)]
    smallest = min(e.file_bytes for e in tried)
    affordable = [e for e in tried if e.file_bytes <= FILE_SLACK * smallest]
    meeting = [e for e in affordable if e.meets_target]
    if meeting:
        best = min(meeting, key=_smallest_then_simplest)
    else:
        best = min(affordable, key=lambda e: (e.overfetch, e.file_bytes))
    explicit = len(layouts) == 1 and window_s is not None
    return Choice(best, tuple(tried), _reason(life, best, meeting, len(tried), explicit), explicit)


def _smallest_then_simplest(e: Estimate) -> tuple[float, float, bool, int, float]:
    """Order of preference among layouts meeting the target: smaller file, fewer requests,
    no time slices, the policy order hybrid, hierarchy, duplicate, then longer windows."""
    sliced = e.layout.slice_s is not None
    return (e.file_bytes, e.requests, sliced, _PREFERRED[e.layout.policy], -e.layout.window_s)


def _unbounded(life: Lifespans, layout: Layout, costs: Costs) -> Estimate:
    """An estimate without the copy bound (a layout given explicitly is estimated anyway)."""
    windows = window_count(life.scene_start, life.scene_end, layout.window_s)
    copies = window_span(life.start, life.end, life.scene_start, layout.window_s, windows)
    stored = float(((copies[1] - copies[0] + 1) * life.weight).sum())
    size = stored * costs.per_gaussian
    return Estimate(layout, size, windows, size, size, costs.per_chunk, float(windows))


def _reason(
    life: Lifespans, best: Estimate, meeting: list[Estimate], tried: int, explicit: bool
) -> str:
    """Why this layout, in one line."""
    fetch = f"a seek reads {best.overfetch:.2f}x the bytes it shows, plus the opening"
    if explicit:
        return f"as asked: {fetch}"
    one_frame = life.fps is not None and abs(best.layout.window_s * life.fps - 1) < 1e-6
    if one_frame and not life.carries_over:
        return f"a window per frame: no Gaussian carries over between frames ({fetch})"
    if meeting:
        return (
            f"{fetch} (target {SEEK_TARGET:g}x) with the smallest file of the {len(meeting)} "
            f"of {tried} layouts that meet it"
        )
    return (
        f"no layout of {tried} meets the {SEEK_TARGET:g}x seek target within "
        f"{FILE_SLACK:g}x the smallest file: this one comes closest ({fetch})"
    )


def why_not_merged(per_frame: Choice, merged: Choice) -> str | None:
    """Why a frame sequence should be stored frame by frame rather than merged (None: merge):
    a merge is no smaller, or its seeks read more than SEEK_TARGET x a frame's own chunk."""
    frame, whole = per_frame.chosen, merged.chosen
    if whole.file_bytes >= frame.file_bytes:
        return "merging would make the file no smaller"
    frame_bytes = frame.shown_mean  # one frame's own chunk
    if whole.seek_mean <= SEEK_TARGET * frame_bytes + PREFIX_SIZE or not frame.meets_target:
        return None
    return (
        f"merged, the file would be {whole.file_bytes / frame.file_bytes:.2f}x but a seek "
        f"{whole.seek_mean / (frame_bytes + PREFIX_SIZE):.1f}x a frame's own chunk "
        f"(target {SEEK_TARGET:g}x)"
    )
