"""Seek cost: what showing time t costs (chunks, requests, bytes) against what is visible."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..container.ranges import coalesce
from ..container.stream_index import StreamIndex
from ..model import Scene, evaluate_all
from ..schemas.manifest import ChunkEntry


@dataclass(frozen=True)
class SeekCost:
    """Cost of showing one time: fetched bytes versus the bytes of visible Gaussians."""

    t: float
    chunks: int
    requests: int
    bytes: int
    percent_of_file: float
    visible: int
    visible_bytes: int

    @property
    def overfetch(self) -> float:
        """Fetched bytes per byte of visible Gaussians (1.0 is ideal; inf for nothing visible)."""
        return self.bytes / self.visible_bytes if self.visible_bytes else float("inf")

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON and tables."""
        return {**asdict(self), "overfetch": round(self.overfetch, 3)}


def seek_cost(
    index: StreamIndex, t: float, chunks: Sequence[ChunkEntry], scenes: Sequence[Scene]
) -> SeekCost:
    """The cost of showing ``t`` from the chunks it needs after opening, ``scenes`` those of
    Gaussians decoded (requests = coalesced adjacent ranges; bytes the opening request already
    brought are not fetched again; an SH-band chunk's bytes count with its host's)."""
    visible = 0
    visible_bytes = 0.0
    bands = {c.sh_of: c.length for c in chunks if c.sh_of is not None}
    hosts = [c for c in chunks if c.holds_gaussians]
    for chunk, scene in zip(hosts, scenes, strict=True):
        _, mask = evaluate_all(scene, t)
        n = int(np.count_nonzero(mask))
        visible += n
        visible_bytes += (chunk.length + bands.get(chunk.id, 0)) * n / max(1, chunk.count)
    held = index.opening_bytes  # served again by the reader without a request
    fetched = sum(max(c.offset + c.length - max(c.offset, held), 0) for c in chunks)
    runs = coalesce(index.chunk_range(c) for c in chunks)
    requests = sum(1 for run in runs if run.end > held)
    return SeekCost(
        t,
        len(chunks),
        requests,
        fetched,
        round(100.0 * fetched / index.size, 2),
        visible,
        round(visible_bytes),
    )
