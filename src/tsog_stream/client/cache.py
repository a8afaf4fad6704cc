"""``SceneCache``: the client's decoded chunks, bounded by the bytes of their arrays.

Decoded chunks are kept, not bytes: decoding costs more than fetching on a fast link.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

from cachetools import LRUCache

from ..codec.sh_bands import ShBands
from ..model import Scene

Decoded = Scene | ShBands
"""What a chunk decodes to: Gaussians, or the SH bands of another chunk's Gaussians."""


def scene_nbytes(scene: Decoded) -> int:
    """Memory held by a decoded chunk's arrays (the cache's measure of size)."""
    if isinstance(scene, ShBands):
        return scene.nbytes
    return sum(a.nbytes for a in scene.arrays())


@dataclass
class CacheStats:
    """Lookups of chunks a frame needed: found decoded (hits) or not (misses)."""

    hits: int = 0
    misses: int = 0

    @property
    def hit_rate(self) -> float:
        """Fraction of lookups that were hits (0 before any lookup)."""
        total = self.hits + self.misses
        return self.hits / total if total else 0.0


class SceneCache:
    """Decoded chunks by id, least recently used evicted first, ``max_bytes`` at most in all.

    A chunk larger than the whole budget is not kept (its caller has it already): the bound
    holds, and one huge chunk does not evict every other.
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._items: LRUCache[int, Decoded] = LRUCache(max_bytes, getsizeof=scene_nbytes)

    def __contains__(self, chunk_id: int) -> bool:
        return chunk_id in self._items

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held."""
        return int(self._items.currsize)

    def get(self, chunk_id: int) -> Decoded | None:
        """The chunk if cached (and mark it recently used)."""
        return self._items.get(chunk_id)

    def put(self, chunk_id: int, scene: Decoded) -> None:
        """Keep a chunk not yet here, evicting the least recently used beyond the budget."""
        if chunk_id not in self._items:
            with contextlib.suppress(ValueError):  # cachetools: larger than the whole budget
                self._items[chunk_id] = scene
