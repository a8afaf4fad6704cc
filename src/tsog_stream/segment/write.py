"""Writing the container as its chunks arrive, in order, and its index (manifest) last."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._version import __version__
from ..constants import GENERATOR
from ..container.objects import container_output
from ..schemas.cameras import Camera
from ..schemas.manifest import Box, ChunkEntry, Layer, Live, Manifest, Node
from .encoding import Encoded, PartInfo
from .layers import LayerPlan
from .meter import Meter
from .options import ChunkProgress, SegmentOptions, SegmentReport
from .plan import NodeKey, Plan


@dataclass(frozen=True)
class Views:
    """The capture cameras an index stores and the view a player opens the scene from."""

    cameras: list[Camera]
    view: Camera | None
    core: dict[str, Any] | None
    why: str = ""
    """Why the view is the one it is (framing.opening_view)."""


def _union(boxes: Sequence[Box]) -> dict[str, list[float]]:
    """The box holding every box (zeros when there are none)."""
    if not boxes:
        return {"min": [0.0] * 3, "max": [0.0] * 3}
    lo = np.min([b.min for b in boxes], axis=0)
    hi = np.max([b.max for b in boxes], axis=0)
    return {"min": lo.tolist(), "max": hi.tolist()}


def write_container(
    path: str | os.PathLike[str],
    chunks: Encoded,
    *,
    total: int,
    plan: Plan,
    scene_fields: dict[str, Any],
    options: SegmentOptions,
    on_chunk: ChunkProgress | None,
    views: Views,
    layering: LayerPlan,
    meter: Meter,
) -> SegmentReport:
    """Append the chunks as they are encoded (in order) and finish the container with its
    index; the encoding stops (engine shut down) whatever ends the writing."""
    entries: list[ChunkEntry] = []
    keys: list[NodeKey] = []
    if on_chunk is not None:  # the ETA redrawn while no chunk comes (the first takes longest)
        meter.on_tick = lambda: on_chunk(len(entries), max(total, len(entries)), meter.eta_s())
    with container_output(path) as out, contextlib.closing(chunks) as encoded:
        for i, (info, payload) in enumerate(encoded):
            entries.append(entry_of(i, info, *out.add(payload)))
            keys.append(info.key)
            if on_chunk:
                on_chunk(i + 1, max(total, i + 1), meter.eta_s())
                meter.ticked()
        if scene_fields["gaussians"] is None:  # a frame sequence: each stored once
            counted = sum(e.count for e in entries if e.holds_gaussians)
            scene_fields = {**scene_fields, "gaussians": counted, "stored": counted}
        manifest = index_of(
            entries,
            keys,
            plan=plan,
            scene_fields=scene_fields,
            options=options,
            views=views,
            layering=layering,
        )
        size = out.finish(manifest)
    return _report(str(path), size, manifest, plan=plan, views=views, layering=layering)


def entry_of(i: int, info: PartInfo, offset: int, length: int, digest: str) -> ChunkEntry:
    """The index's entry of chunk ``i``, stored at ``offset`` with ``length`` bytes."""
    return ChunkEntry(
        id=i,
        file=f"chunks/{i:06d}.sog",
        offset=offset,
        length=length,
        sha256=digest,
        count=info.count,
        level=info.key.level,
        node=info.key.index,
        start_s=info.start_s,
        end_s=info.end_s,
        bbox=info.bbox,
        layer=info.layer,
        sh_of=info.sh_of,
    )


def index_of(
    entries: list[ChunkEntry],
    keys: Sequence[NodeKey],
    *,
    plan: Plan,
    scene_fields: dict[str, Any],
    options: SegmentOptions,
    views: Views,
    layering: LayerPlan,
    live: Live | None = None,
) -> Manifest:
    """The container's index of ``entries`` (``keys``: each one's node; ``live``: a live
    stream's publication)."""
    scene = {
        **scene_fields,
        "start_s": plan.start_s,
        "end_s": plan.end_s,
        "bbox": _union([e.bbox for e in entries]),
        "core": views.core,
    }
    return Manifest.model_validate(
        {
            "generator": f"{GENERATOR} {__version__}",
            "policy": options.policy,
            "window_s": plan.window_s,
            "max_pixels": options.max_pixels,
            "scene": scene,
            "nodes": _nodes(plan, keys),
            "chunks": entries,
            "payload_bytes": sum(e.length for e in entries),
            "cameras": views.cameras,
            "view": views.view,
            "layers": _layers(layering, entries),
            "live": live,
        }
    )


def _report(
    path: str, size: int, manifest: Manifest, *, plan: Plan, views: Views, layering: LayerPlan
) -> SegmentReport:
    """What the CLI says of a container of ``size`` bytes written with ``manifest``."""
    entries = manifest.chunks
    per_level: dict[int, int] = {}
    per_window = [0] * plan.windows
    for e in entries:
        per_level[e.level] = per_level.get(e.level, 0) + e.length
        if e.level == 0:
            per_window[e.node] += e.length
    return SegmentReport(
        path,
        size,
        len(entries),
        plan.windows,
        manifest.scene.gaussians,
        sum(e.count for e in entries if e.holds_gaussians),
        plan.dropped,
        per_level,
        per_window,
        view=views.view,
        view_why=views.why,
        layers=manifest.layers,
        layers_why=layering.why,
        start_s=manifest.scene.start_s,
        end_s=manifest.scene.end_s,
        static=manifest.scene.timeline_type is None,
        duration_assumed=manifest.scene.duration_assumed,
    )


def _layers(layering: LayerPlan, entries: Sequence[ChunkEntry]) -> list[Layer]:
    """The index's layers (none for one layer): Gaussians (SH-band chunks hold none), bytes
    and measured PSNR of each."""
    if layering.layers == 1:
        return []
    sizes, counts = [0] * layering.layers, [0] * layering.layers
    for e in entries:
        sizes[e.layer] += e.length
        counts[e.layer] += e.count if e.holds_gaussians else 0
    return [
        Layer(index=k, gaussians=count, bytes=size, psnr_db=psnr)
        for k, (count, size, psnr) in enumerate(zip(counts, sizes, layering.psnr_db, strict=True))
    ]


def _nodes(plan: Plan, keys: Sequence[NodeKey]) -> list[Node]:
    """Manifest nodes (windows first, then coarser levels), each with its chunk ids."""
    members: dict[NodeKey, list[int]] = {}
    for i, key in enumerate(keys):
        members.setdefault(key, []).append(i)
    ordered = [NodeKey(0, w) for w in range(plan.windows)]
    ordered += sorted((k for k in members if k.level > 0), key=lambda k: (k.level, k.index))
    out = []
    for key in ordered:
        start, end = plan.node_interval(key)
        out.append(
            Node(
                level=key.level,
                index=key.index,
                start_s=start,
                end_s=end,
                chunks=members.get(key, []),
            )
        )
    return out
