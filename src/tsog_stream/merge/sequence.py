"""Merge a frame sequence into one scene: the ``--temporal`` modes of ``tsog segment``.

``off`` keeps one Gaussian per frame (timeline type 0, the paper's conversion); ``merge`` turns
runs of unchanged Gaussians into lifespans (type 1); ``fit`` also gives smoothly moving ones
polynomial motion. Frames are read one at a time, so memory is the merged scene plus a frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from typing import Final, Literal

import numpy as np

from ..errors import InputError
from ..io.sequence import FrameSequence
from ..model import Gaussians, Scene
from .features import Steps, Tolerance
from .runs import DEFAULT_REACH, FrameMerger, MergeStats

TemporalMode = Literal["off", "merge", "fit"]
TEMPORAL_MODES: Final = ("off", "merge", "fit")
SOG_FRAME_STEPS: Final = 1.0
"""Default tolerance in steps for SOG frames: each frame is already rounded to its own
codebooks, so one unchanged Gaussian differs between frames by up to a step."""

FIT_PAYS_BELOW: Final = 0.8
"""``fit`` keeps its motion only when it stores at most this share of the frames' Gaussians:
above it (little follows a path), the coefficient images every Gaussian of a chunk then carries
outweigh the Gaussians saved, and ``merge`` is smaller (measured: docs/design/temporal-merge.md)."""
MAX_HELD: Final = 4_000_000
"""Gaussians a merge may hold in memory (a few GiB) before the sequence is stored per frame."""

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
    """Frames in order (all padded to ``sh_coeffs``) as one type-1 scene, and what merging did.

    Quantisation steps and the motion search reach come from the first frame. The scene is
    None when the merger came to hold more than ``max_held`` Gaussians (memory bound: the
    caller then stores the frames one window at a time instead).
    """
    if mode not in ("merge", "fit"):
        raise InputError(f"expected merge or fit, got {mode!r}", where="temporal")
    merger: FrameMerger | None = None
    for g in frames:
        if merger is None:
            extent = g.means.max(axis=0) - g.means.min(axis=0) if len(g) else np.zeros(3)
            merger = FrameMerger(
                Steps.of(g),
                tolerance or Tolerance(),
                fps,
                sh_coeffs,
                fit=mode == "fit",
                reach=DEFAULT_REACH * extent.astype(np.float64),
            )
        merger.add(g)
        if max_held is not None and merger.held > max_held:
            return None, replace(merger.stats)
    if merger is None:
        raise InputError("the sequence has no frames")
    scene = merger.scene()
    return scene, replace(merger.stats)


def merge_sequence(
    seq: FrameSequence,
    mode: TemporalMode = "merge",
    tolerance: Tolerance | None = None,
    *,
    progress: Progress | None = None,
    max_held: int | None = MAX_HELD,
) -> tuple[Scene | None, MergeStats]:
    """A frame sequence, read one frame at a time, as one merged scene (see merge_frames)."""

    def frames() -> Iterator[Gaussians]:
        for k in range(seq.count):
            if progress:
                progress(f"merging frame {k + 1}/{seq.count}")
            yield seq.read(k, k + 1).scene.gaussians

    tol = default_tolerance(seq, tolerance)
    options = {"fps": seq.fps, "sh_coeffs": seq.sh_coeffs, "tolerance": tol, "max_held": max_held}
    scene, stats = merge_frames(frames(), mode=mode, **options)  # type: ignore[arg-type]
    if scene is None or mode != "fit" or stats.gaussians_out <= FIT_PAYS_BELOW * stats.gaussians_in:
        return scene, stats
    merged, merged_stats = merge_frames(frames(), mode="merge", **options)  # type: ignore[arg-type]
    merged_stats.note = (
        f"fitted motion kept {stats.gaussians_out} of {stats.gaussians_in} Gaussians, too many to "
        "pay for the coefficient images: merged lifespans only"
    )
    return merged, merged_stats
