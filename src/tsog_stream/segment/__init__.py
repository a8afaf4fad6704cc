"""The segmenter: a 4D scene -> time nodes -> spatial chunks under a pixel budget -> container.

The package's face: what callers import. Its rooms (``segmenter`` the two entry points and the
layout, ``options``, ``plan``, ``layout``, ``layers``, ``jobs``, ``encoding``, ``engines``,
``write``, ``sequence``, ``meter``, and ``live`` for live events) are described in
docs/design/segmenter.md and docs/live.md.
"""

from .options import (
    DEFAULT_POLICY,
    STATIC_WINDOW_S,
    ChunkProgress,
    SegmentOptions,
    SegmentReport,
    StageProgress,
    max_gaussians_per_chunk,
)
from .segmenter import (
    merge_or_frames,
    plan_scene,
    scene_layout,
    segment_scene,
    segment_sequence,
    static_plan,
    views_of,
)
from .sequence import WindowJob
from .write import Views

__all__ = [
    "DEFAULT_POLICY",
    "STATIC_WINDOW_S",
    "ChunkProgress",
    "SegmentOptions",
    "SegmentReport",
    "StageProgress",
    "Views",
    "WindowJob",
    "max_gaussians_per_chunk",
    "merge_or_frames",
    "plan_scene",
    "scene_layout",
    "segment_scene",
    "segment_sequence",
    "static_plan",
    "views_of",
]
