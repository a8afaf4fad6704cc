"""Merge a frame sequence into one scene: the ``--temporal`` modes of ``tsog segment``.

``off`` keeps one Gaussian per frame (type 0); ``merge`` turns runs of unchanged Gaussians into
lifespans (type 1); ``fit`` also gives smoothly moving ones polynomial motion.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from typing import Final, Literal

import numpy as np

from ..errors import InputError
from ..io.sequence import FrameSequence
from ..model import Gaussians, Scene
from .features import Steps, Tolerance, robust_extent
from .runs import DEFAULT_REACH, FrameMerger, MergeStats

TemporalMode = Literal["off", "merge", "fit"]
TEMPORAL_MODES: Final = ("off", "merge", "fit")
SOG_FRAME_STEPS: Final = 1.0
"""Default tolerance in steps for SOG frames (each already rounded to its own codebooks)."""
FIT_PAYS_BELOW: Final = 0.8
"""``fit`` keeps its motion only when it stores at most this share of the frames' Gaussians
(above, the coefficient images outweigh what it saves: docs/design/temporal-merge.md)."""
MAX_HELD: Final = 4_000_000
"""Gaussians a merge may hold in memory (a few GiB) before the sequence is stored per frame."""
PROBE_FRAMES: Final = 8
"""Consecutive frames of each probe: enough that a polynomial through them can fail."""
PROBE_SAMPLES: Final = 3
"""Probes, at the start, middle and end of the sequence."""
PROBE_GAUSSIANS: Final = 4096
"""About this many Gaussians of each probed frame are matched: those in a central box."""
MERGE_PAYS_BELOW: Final = 0.95
"""``merge`` runs on the whole sequence only when a probe kept at most this share."""

Progress = Callable[[str], None]


def default_tolerance(seq: FrameSequence, tolerance: Tolerance | None) -> Tolerance:
    """The tolerance to use: the caller's, else half a step (a whole step for SOG frames)."""
    if tolerance is not None:
        return tolerance
    return Tolerance(steps=SOG_FRAME_STEPS) if seq.frames.kind == "sog" else Tolerance()


def merge_frames(
    frames: Iterable[Gaussians],
    *,
    fps: float,
    sh_coeffs: int,
    mode: TemporalMode = "merge",
    tolerance: Tolerance | None = None,
    max_held: int | None = None,
) -> tuple[Scene | None, MergeStats]:
    """Frames in order (all padded to ``sh_coeffs``) as one type-1 scene, and what merging did;
    steps and reach from the first frame. None when it would hold more than ``max_held``."""
    if mode not in ("merge", "fit"):
        raise InputError(f"expected merge or fit, got {mode!r}", where="temporal")
    merger: FrameMerger | None = None
    for g in frames:
        if merger is None:
            extent = robust_extent(g.means)
            merger = FrameMerger(
                Steps.of(g),
                tolerance or Tolerance(),
                fps,
                sh_coeffs,
                fit=mode == "fit",
                reach=DEFAULT_REACH * extent,
            )
        merger.add(g)
        if max_held is not None and merger.held > max_held:
            return None, replace(merger.stats)
    if merger is None:
        raise InputError("the sequence has no frames")
    scene = merger.scene()
    return scene, replace(merger.stats)


def probe_merge(
    seq: FrameSequence, mode: TemporalMode, tolerance: Tolerance | None = None
) -> tuple[TemporalMode | None, str]:
    """The mode worth running on the whole sequence (None: store it per frame) and why, from
    merging up to PROBE_SAMPLES runs of PROBE_FRAMES frames cropped to a central box of about
    PROBE_GAUSSIANS (docs/design/segmenter.md). A run fitting paired nothing in is not merged
    again (merging looks for a part of what fitting does)."""
    if seq.count < 2:
        return None, "one frame: nothing to merge"
    tol = default_tolerance(seq, tolerance)
    modes: tuple[TemporalMode, ...] = ("fit", "merge") if mode == "fit" else (mode,)
    kept = dict.fromkeys(modes, 1.0)
    options = {"fps": seq.fps, "sh_coeffs": seq.sh_coeffs, "tolerance": tol}
    runs = 0
    for frames in _probe_runs(seq):
        runs += 1
        for m in modes:
            _, stats = merge_frames(frames, mode=m, **options)  # type: ignore[arg-type]
            kept[m] = min(kept[m], stats.gaussians_out / max(stats.gaussians_in, 1))
            if stats.pairs == 0:
                break
    if kept.get("fit", 1.0) <= FIT_PAYS_BELOW:
        return "fit", ""
    if kept["merge"] <= MERGE_PAYS_BELOW:
        if mode == "merge":
            return "merge", ""
        return "merge", (
            f"fitted motion kept {kept['fit']:.0%} of the Gaussians of a probe, too many to pay "
            "for the coefficient images: merged lifespans only"
        )
    shown = ", ".join(f"{m} {k:.0%}" for m, k in kept.items())
    return None, (
        f"merging kept {shown} of the Gaussians of {runs} probe{'s' if runs != 1 else ''} of "
        f"{min(PROBE_FRAMES, seq.count)} frames (it pays below {MERGE_PAYS_BELOW:.0%}): "
        "not merged"
    )


def _probe_runs(seq: FrameSequence) -> Iterator[list[Gaussians]]:
    """The probe runs of consecutive frames, each cropped to its first frame's central box."""
    length = min(PROBE_FRAMES, seq.count)
    count = max(1, min(PROBE_SAMPLES, seq.count // length))
    for first in sorted({round(k) for k in np.linspace(0, seq.count - length, count)}):
        frames: list[Gaussians] = []
        for i in range(first, first + length):  # cropped as read: one whole frame held at most
            g = seq.read(i, i + 1).scene.gaussians
            if not frames:
                lo, hi = _central_box(g.means, PROBE_GAUSSIANS)
            frames.append(g.subset(np.all((g.means >= lo) & (g.means <= hi), axis=1)))
            del g
        if any(len(g) for g in frames):
            yield frames


def _central_box(means: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis quantile bounds of a box around the median holding about ``count`` points."""
    if len(means) <= count:
        return np.full(3, -np.inf), np.full(3, np.inf)
    half = 0.5 * (count / len(means)) ** (1 / 3)
    finite = means[np.all(np.isfinite(means), axis=1)]
    lo, hi = np.quantile(finite, [0.5 - half, 0.5 + half], axis=0)
    return lo, hi


def merge_sequence(
    seq: FrameSequence,
    mode: TemporalMode = "merge",
    tolerance: Tolerance | None = None,
    *,
    progress: Progress | None = None,
    max_held: int | None = MAX_HELD,
) -> tuple[Scene | None, MergeStats]:
    """A frame sequence, read a frame at a time, as one merged scene (see merge_frames); None
    (with a note why) when a probe finds merging does not pay, or it would hold too much."""

    def frames() -> Iterator[Gaussians]:
        for k in range(seq.count):
            if progress:
                progress(f"merging frame {k + 1}/{seq.count}")
            yield seq.read(k, k + 1).scene.gaussians

    tol = default_tolerance(seq, tolerance)
    worth, why = probe_merge(seq, mode, tol)
    if worth is None:
        return None, MergeStats(gaussians_in=seq.gaussians, note=why)
    mode = worth
    options = {"fps": seq.fps, "sh_coeffs": seq.sh_coeffs, "tolerance": tol, "max_held": max_held}
    scene, stats = merge_frames(frames(), mode=mode, **options)  # type: ignore[arg-type]
    stats.note = stats.note or why
    if scene is None or mode != "fit" or stats.gaussians_out <= FIT_PAYS_BELOW * stats.gaussians_in:
        return scene, stats
    merged, merged_stats = merge_frames(frames(), mode="merge", **options)  # type: ignore[arg-type]
    merged_stats.note = (
        f"fitted motion kept {stats.gaussians_out} of {stats.gaussians_in} Gaussians, too many to "
        "pay for the coefficient images: merged lifespans only"
    )
    return merged, merged_stats
