"""How many quality layers a player can keep fetching without stalling: throughput and deadlines.

Pure decisions over the index (no I/O), shared by the client's adaptive playback and mirrored
by the web player's ``adapt.js``. A chunk is due when the playback reaches its first visible
second; a layer set is playable when its chunks, fetched back to back in due order (earliest
deadline first, the best order for meeting deadlines on one link) at the measured throughput,
all arrive in time. See docs/client.md ("Adaptive playback").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from ..container.stream_index import StreamIndex
from ..schemas.manifest import ChunkEntry

EWMA_WEIGHT = 0.3
"""Weight of the newest throughput sample (DASH players use 0.2-0.5: quick to follow a drop)."""
SAFETY = 0.85
"""Share of the measured throughput the plan counts on (headroom for jitter and requests)."""
STARTUP_FACTOR = 4.0
STARTUP_MIN_S = 2.0
"""After the first picture, playback waits for more layers at most max(STARTUP_MIN_S,
STARTUP_FACTOR x the first picture's wait): a fast link starts at full quality, a slow one on
the layers it keeps up with (docs/design/segmenter.md, "Quality layers")."""
UPGRADE_MARGIN = 0.8
"""A layer is taken on while playing only when its missing bytes need at most this share of the
playback left (kept while they need at most all of it): no flapping at the edge."""
BASE_LATE_S = 0.5
"""How late the base may look before a playback gives up every enhancement layer."""
HORIZON_S = 4.0
"""Scene seconds ahead whose chunks an adaptive playback keeps fetching."""


class Throughput:
    """Bytes per second the link gives, an EWMA over busy time (time with a request in flight),
    so requests sharing the link are not each counted at a fraction of it."""

    def __init__(self, clock: Callable[[], float]) -> None:
        self._clock = clock
        self._in_flight = 0
        self._busy_since = 0.0
        self._busy = 0.0
        self._bytes = 0
        self.estimate: float | None = None

    def started(self) -> None:
        """A request went out."""
        if self._in_flight == 0:
            self._busy_since = self._clock()
        self._in_flight += 1

    def finished(self, nbytes: int) -> None:
        """A request that went out came back with ``nbytes`` (0 for a failure)."""
        now = self._clock()
        self._busy += now - self._busy_since
        self._busy_since = now
        self._in_flight = max(self._in_flight - 1, 0)
        self._bytes += nbytes
        if self._bytes > 0 and self._busy > 0:
            sample = self._bytes / self._busy
            old = self.estimate
            self.estimate = sample if old is None else old + EWMA_WEIGHT * (sample - old)
            self._bytes, self._busy = 0, 0.0


def due_order(chunks: Sequence[ChunkEntry], t: float) -> list[ChunkEntry]:
    """Chunks by the scene time they are first needed from ``t`` on, base layers first."""
    return sorted(chunks, key=lambda c: (max(c.start_s, t), c.layer, c.offset))


def delay_needed(chunks: Sequence[ChunkEntry], t: float, speed: float, rate: float) -> float:
    """Wall seconds playback must wait, from now, so that ``chunks`` (not yet fetched), fetched
    back to back in due order at ``rate`` bytes/s, each arrive by the time scene time ``t``
    has advanced to their first second (<= 0: no wait needed; inf: no rate)."""
    if not chunks:
        return -math.inf
    if rate <= 0:
        return math.inf
    worst, sent = -math.inf, 0
    for c in due_order(chunks, t):
        sent += c.length
        worst = max(worst, sent / rate - max(c.start_s - t, 0.0) / speed)
    return worst


def choose_layers(
    index: StreamIndex,
    t: float,
    end: float,
    *,
    speed: float,
    rate: float | None,
    have: Callable[[int], bool],
    current: int,
    allowance: float,
) -> int:
    """How many layers to keep fetching for [t, end] (1 at least: the base always).

    At startup (``current`` 0): the most whose missing chunks, fetched in due order, arrive in
    time if playback waits at most ``allowance`` seconds. While playing: enhancement layers
    are never waited for, so a layer count is kept while its missing bytes can still arrive
    before the end (at the throughput the plan counts on), raised when the next one's can with
    UPGRADE_MARGIN to spare, and dropped to the base when the base itself would be more than
    BASE_LATE_S late (chunks under way count whole, so a little lateness is normal).
    """
    budget = (rate or 0.0) * SAFETY

    def missing(layers: int) -> list[ChunkEntry]:
        return [c for c in index.chunks_for_interval(t, end, layers) if not have(c.id)]

    if current == 0:
        best = 1
        for layers in range(1, index.layer_count + 1):
            if delay_needed(missing(layers), t, speed, budget) <= allowance:
                best = layers
        return best
    if delay_needed(missing(1), t, speed, budget) > BASE_LATE_S:
        return 1
    remaining = max(end - t, 0.0) / speed

    def fits(layers: int, share: float) -> bool:
        return budget > 0 and sum(c.length for c in missing(layers)) / budget <= share * remaining

    level = current
    while level > 1 and not fits(level, 1.0):
        level -= 1
    if level == current and level < index.layer_count and fits(level + 1, UPGRADE_MARGIN):
        level += 1
    return level


def startup_allowance(first_picture_s: float) -> float:
    """How much longer than the first picture a playback may wait for more layers."""
    return max(STARTUP_MIN_S, STARTUP_FACTOR * first_picture_s)


def layers_shown(index: StreamIndex, t: float, have: Callable[[int], bool]) -> int:
    """The most layers whose every chunk for ``t`` has arrived (0: not even the base)."""
    chunks = index.chunks_for(t)  # every layer's, chosen once (a frame asks this each time)
    shown = 0
    for layer in range(index.layer_count):
        if not all(have(c.id) for c in chunks if c.layer == layer):
            break
        shown = layer + 1
    return shown
