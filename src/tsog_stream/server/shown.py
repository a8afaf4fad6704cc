"""How many Gaussians a scene shows at one time, from its index alone (no chunk is read).

The scene list gives it beside ``gaussians`` (every Gaussian of the source, summed over the
frames of a flipbook), because a viewer asks how heavy one picture is, not the whole clip.
Sans-I/O: a pure function of the manifest.
"""

from __future__ import annotations

from ..schemas.manifest import ChunkEntry, Manifest, Node

_TICKS_PER_WINDOW = 1_000_000
"""Times are compared on a grid of this many ticks a window, so a frame's end and the next
frame's start, computed by different float roundings, meet instead of overlapping by an ulp."""
_END, _START, _POINT_END = 0, 1, 2
"""Order of events at one tick: what ends there leaves before what starts there is counted,
and a chunk of one instant (a static scene) is counted before it leaves."""


def gaussians_per_frame(manifest: Manifest) -> int:
    """The most Gaussians the player holds at any one time: the largest sum, over time, of the
    counts of the chunks that time needs (every quality layer, every level of a hierarchy or
    hybrid node covering it; SH-band chunks add no Gaussians).

    A chunk counts while its own visible interval, cut to its node's time span, holds the time
    (half-open, so consecutive frames never add up); a chunk of one instant counts at that
    instant. It is exact at chunk granularity: an upper bound on the Gaussians drawn, since a
    Gaussian may be faint for part of its chunk's interval.
    """
    tick = manifest.window_s / _TICKS_PER_WINDOW
    events: list[tuple[int, int, int]] = []
    for node in manifest.nodes:
        for cid in node.chunks:
            chunk = manifest.chunks[cid]
            if chunk.holds_gaussians and chunk.count:
                events.extend(_events(chunk, node, tick))
    events.sort()
    held = most = 0
    for _, kind, count in events:
        held += count if kind == _START else -count
        most = max(most, held)
    return most


def _events(chunk: ChunkEntry, node: Node, tick: float) -> list[tuple[int, int, int]]:
    """When ``chunk`` starts and stops being held within ``node`` (in ticks), or nothing when
    its interval only touches the node's edge."""
    lo = round(max(chunk.start_s, node.start_s) / tick)
    hi = round(min(chunk.end_s, node.end_s) / tick)
    if lo < hi:
        return [(lo, _START, chunk.count), (hi, _END, chunk.count)]
    instant = round(chunk.start_s / tick) == round(chunk.end_s / tick)
    if instant and round(node.start_s / tick) <= lo <= round(node.end_s / tick):
        return [(lo, _START, chunk.count), (lo, _POINT_END, chunk.count)]
    return []
