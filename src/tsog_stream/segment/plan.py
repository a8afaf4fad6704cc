"""Segmentation plan: which Gaussians go into which time node, under each policy (pure numpy).

Time is cut into windows of ``window_s`` seconds (level 0). Policies decide where a Gaussian
whose lifespan crosses window boundaries is stored:

- ``duplicate``: a copy in every window it touches (each window self-contained);
- ``hierarchy``: once, in the smallest node of a binary interval tree over the windows whose
  interval holds its whole lifespan (level l covers 2^l windows);
- ``hybrid``: duplicated when it touches at most ``max_copies`` windows, else as in hierarchy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import get_args

import numpy as np
import numpy.typing as npt

from ..container.stream_index import WINDOW_EPSILON
from ..errors import InputError
from ..schemas.manifest import Policy

F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
POLICIES: tuple[Policy, ...] = get_args(Policy)
DEFAULT_MAX_COPIES = 2


@dataclass(frozen=True)
class NodeKey:
    """A node of the time tree: ``level`` 0 are windows; node i of level l covers windows
    [i * 2^l, (i + 1) * 2^l)."""

    level: int
    index: int


@dataclass(frozen=True)
class Plan:
    """Windows and, per node, the indices of the Gaussians stored there (ascending)."""

    start_s: float
    end_s: float
    window_s: float
    windows: int
    buckets: dict[NodeKey, Ints]
    dropped: int
    """Gaussians never visible inside [start_s, end_s]."""

    def node_interval(self, key: NodeKey) -> tuple[float, float]:
        """Seconds covered by a node, clipped to the scene."""
        span = self.window_s * (1 << key.level)
        start = self.start_s + key.index * span
        return start, min(start + span, self.end_s)

    @property
    def stored(self) -> int:
        """Gaussians stored, duplicates counted."""
        return int(sum(len(v) for v in self.buckets.values()))


def window_count(start_s: float, end_s: float, window_s: float) -> int:
    """Windows needed to cover [start_s, end_s] (at least one)."""
    if not (window_s > 0 and math.isfinite(window_s)):
        raise InputError(
            f"window length must be a positive number of seconds, got {window_s}", where="--window"
        )
    return max(1, math.ceil((end_s - start_s) / window_s - WINDOW_EPSILON))


def window_span(
    start: F64, end: F64, t0: float, window_s: float, windows: int
) -> tuple[Ints, Ints]:
    """First and last window index each lifespan [start, end) touches, clipped to the scene."""
    first = np.floor((start - t0) / window_s + WINDOW_EPSILON).astype(np.int64)
    last = np.ceil((end - t0) / window_s - WINDOW_EPSILON).astype(np.int64) - 1
    last = np.maximum(last, first)
    return np.clip(first, 0, windows - 1), np.clip(last, 0, windows - 1)


def stored_in_windows(copies: Ints, policy: Policy, max_copies: int) -> npt.NDArray[np.bool_]:
    """Which Gaussians (touching ``copies`` windows each) get a copy in every window they
    touch; the others go to one node of the time tree."""
    if policy == "duplicate":
        return np.ones(copies.size, bool)
    if policy == "hierarchy":
        return np.asarray(copies == 1)
    return np.asarray(copies <= max_copies)


def tree_level(first: Ints, last: Ints) -> Ints:
    """Smallest level whose node holds windows first..last: bit length of first XOR last."""
    x = np.bitwise_xor(first, last)
    level = np.zeros_like(x)
    nz = x > 0
    level[nz] = np.floor(np.log2(x[nz])).astype(np.int64) + 1
    return level


def _group(keys_level: Ints, keys_index: Ints, members: Ints) -> dict[NodeKey, Ints]:
    """Bucket ``members`` by (level, index), each bucket's members ascending."""
    order = np.lexsort((members, keys_index, keys_level))
    lv, ix, mb = keys_level[order], keys_index[order], members[order]
    if lv.size == 0:
        return {}
    cut = np.flatnonzero((np.diff(lv) != 0) | (np.diff(ix) != 0)) + 1
    starts = np.concatenate(([0], cut))
    ends = np.concatenate((cut, [lv.size]))
    return {NodeKey(int(lv[s]), int(ix[s])): mb[s:e] for s, e in zip(starts, ends, strict=True)}


def make_plan(
    start: F64,
    end: F64,
    *,
    scene_start: float,
    scene_end: float,
    window_s: float,
    policy: Policy,
    max_copies: int = DEFAULT_MAX_COPIES,
) -> Plan:
    """Assign Gaussians with lifespans [start, end) (seconds) to nodes under ``policy``."""
    if policy not in POLICIES:
        raise InputError(
            f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)}", where="--policy"
        )
    windows = window_count(scene_start, scene_end, window_s)
    alive = (end > scene_start) & (start <= scene_end)
    ids = np.flatnonzero(alive).astype(np.int64)
    first, last = window_span(start[ids], end[ids], scene_start, window_s, windows)
    copies = last - first + 1
    dup = stored_in_windows(copies, policy, max_copies)
    counts = copies[dup]
    rep = np.repeat(np.flatnonzero(dup), counts)  # positions in ids, one per stored copy
    win = first[rep] + np.arange(rep.size) - np.repeat(np.cumsum(counts) - counts, counts)
    level_tree = tree_level(first[~dup], last[~dup])
    node_tree = first[~dup] >> level_tree
    levels = np.concatenate([np.zeros(rep.size, np.int64), level_tree])
    nodes = np.concatenate([win.astype(np.int64), node_tree])
    members = np.concatenate([ids[rep], ids[~dup]])
    buckets = _group(levels, nodes, members)
    return Plan(scene_start, scene_end, window_s, windows, buckets, int(start.size - ids.size))
