"""Cutting a scene into chunk jobs: its nodes' Gaussians by time slice, quality layer and Morton
run, the SH-band chunks, and the part (the Gaussians themselves) each job encodes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..codec.chunk import texel_order_of
from ..codec.precision import faint_at
from ..codec.sh_bands import without_sh
from ..model import Scene
from ..morton import morton_parts
from ..temporal import lifespans
from .layers import LayerPlan, importance
from .layout import chunk_counts, time_slices
from .meter import encode_work
from .plan import NodeKey, Plan

Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ChunkJob:
    """One chunk to encode: its node, its Gaussians (indices into the scene) and layer; for
    an SH-band chunk, the id of the chunk whose bands it holds."""

    key: NodeKey
    indices: Ints
    layer: int = 0
    sh_of: int | None = None


def node_groups(
    scene: Scene, plan: Plan, slice_s: float | None = None
) -> list[tuple[NodeKey, Ints]]:
    """Every node's Gaussians, cut by start time into slices of ``slice_s`` when given; ordered
    by node start time, coarser levels first, then by slice (a seek's chunks sit together)."""
    start = lifespans(scene.timeline)[0] if scene.timeline is not None else None
    keys = sorted(plan.buckets, key=lambda k: (plan.node_interval(k)[0], -k.level, k.index))
    return [
        (key, group)
        for key in keys
        for group in _by_slice(plan.buckets[key], start, plan.node_interval(key)[0], slice_s)
    ]


def chunk_jobs(
    scene: Scene,
    groups: Sequence[tuple[NodeKey, Ints]],
    max_count: int,
    layer_of: Ints | None = None,
) -> list[ChunkJob]:
    """Split every group (:func:`node_groups`) into contiguous Morton runs of at most
    ``max_count`` (members in index order), by quality layer (``layer_of``: each Gaussian's;
    None: one layer); ordered by layer, then in the groups' order."""
    jobs: list[ChunkJob] = []
    layers = int(layer_of.max(initial=0)) + 1 if layer_of is not None else 1
    for layer in range(layers):
        for key, group in groups:
            members = group if layer_of is None else group[layer_of[group] == layer]
            if members.size == 0 and layers > 1:
                continue
            parts = max(1, int(chunk_counts(members.size, max_count)))  # empty: one empty chunk
            runs = morton_parts(scene.gaussians.means[members], parts)
            jobs.extend(ChunkJob(key, members[run], layer) for run in runs)
    return jobs


def with_sh_jobs(jobs: Sequence[ChunkJob], first_id: int = 0) -> list[ChunkJob]:
    """``jobs`` (as :func:`chunk_jobs` orders them, the first to be chunk ``first_id``) with
    the SH bands of every base chunk as a chunk of its own at the start of layer 1."""
    base = [job for job in jobs if job.layer == 0]
    bands = [ChunkJob(job.key, job.indices, 1, first_id + i) for i, job in enumerate(base)]
    return [*base, *bands, *(job for job in jobs if job.layer > 0)]


def job_part(scene: Scene, job: ChunkJob, split: bool) -> Part:
    """The part a job encodes: its Gaussians (without SH bands when :func:`_bare`), in the
    order the encoder stores them, so that it need not copy them again to order them."""
    source = without_sh(scene) if _bare(job, split) else scene  # bands never copied
    rows = job.indices
    timeline = scene.timeline.subset(rows) if scene.timeline is not None else None
    ordered = rows[texel_order_of(scene.gaussians.means[rows], timeline)]
    return Part(job.key, source.subset(ordered), job.layer, job.sh_of)


def job_work(scene: Scene, job: ChunkJob, split: bool) -> float:
    """What encoding :func:`job_part`'s part costs, before it is made."""
    coeffs = 0 if _bare(job, split) else scene.gaussians.shN.shape[1]
    return encode_work(job.indices.size, coeffs)


def _bare(job: ChunkJob, split: bool) -> bool:
    """Whether the job's part is a base chunk whose SH bands are split off."""
    return split and job.layer == 0


def _by_slice(
    members: np.ndarray, start: np.ndarray | None, node_start: float, slice_s: float | None
) -> list[np.ndarray]:
    """A node's members grouped by time slice, in slice order (one group without slices)."""
    if start is None or slice_s is None:
        return [members]
    slices = time_slices(start[members], np.full(members.size, node_start), slice_s)
    order = np.argsort(slices, kind="stable")
    cut = np.flatnonzero(np.diff(slices[order])) + 1
    return np.split(members[order], cut)


@dataclass(frozen=True)
class Part:
    """One chunk to encode: its node, its Gaussians and its quality layer (for an SH-band
    chunk, the host's Gaussians and the host's id)."""

    key: NodeKey
    scene: Scene
    layer: int = 0
    sh_of: int | None = None


def part_work(part: Part) -> float:
    """What encoding a part costs (segment/meter.py)."""
    return encode_work(len(part.scene), part.scene.gaussians.shN.shape[1])


def without_faint_members(
    groups: list[tuple[NodeKey, Ints]], scene: Scene, quality: int
) -> tuple[list[tuple[NodeKey, Ints]], int]:
    """The groups (:func:`node_groups`) without the Gaussians too faint to store at
    ``quality`` (a group left empty goes), and how many those are (indices, not a copy)."""
    faint = faint_at(scene, quality)
    count = int(np.count_nonzero(faint))
    if count == 0:
        return groups, 0
    kept = [(key, members[~faint[members]]) for key, members in groups]
    return [(key, members) for key, members in kept if len(members)], count


def window_jobs(scene: Scene, w: int, max_count: int, layering: LayerPlan) -> list[ChunkJob]:
    """The chunk jobs of window ``w`` of a frame sequence, each frame's most important
    Gaussians in its base (SH-band chunks' hosts numbered from 0 within the window)."""
    layer_of = None
    if layering.layers > 1:
        layer_of = layering.assign(importance(scene.gaussians), _frame_groups(scene))
    window = [(NodeKey(0, w), np.arange(len(scene)))]
    jobs = chunk_jobs(scene, window, max_count, layer_of)
    return with_sh_jobs(jobs) if layering.sh_apart else jobs


def window_parts(scene: Scene, w: int, max_count: int, layering: LayerPlan) -> list[Part]:
    """The parts of :func:`window_jobs`, all at once (``scene`` is left as it is)."""
    jobs = window_jobs(scene, w, max_count, layering)
    return [job_part(scene, job, layering.sh_apart) for job in jobs]


def _frame_groups(scene: Scene) -> list[Ints]:
    """Index arrays of each frame of a frame-sequence scene (its frames are contiguous)."""
    assert scene.timeline is not None
    cut = np.flatnonzero(np.diff(scene.timeline.t0)) + 1
    return np.split(np.arange(len(scene)), cut)
