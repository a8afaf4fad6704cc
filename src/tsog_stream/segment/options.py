"""What segmenting takes and gives: :class:`SegmentOptions`, :class:`SegmentReport`, the
progress callbacks, and how many Gaussians a chunk may hold under the pixel budget."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ..codec.layout import image_size
from ..codec.precision import QUALITY_MAX
from ..constants import DEFAULT_MAX_PIXELS, SH_CENTROIDS_PER_ROW, SH_COEFFS_BY_BANDS, WEBP_MAX_SIDE
from ..errors import InputError
from ..schemas.cameras import Camera
from ..schemas.manifest import Layer, Policy
from ..sh_palette import palette_size
from .layout import Choice
from .plan import DEFAULT_MAX_COPIES

DEFAULT_POLICY: Policy = "hybrid"
"""The policy of frame sequences stored per frame (nothing crosses a window: any would do)."""

MIN_PIXELS = 16

ChunkProgress = Callable[[int, int, float | None], None]
"""Told of each chunk written (and every ``meter.TICK_S`` while none is): chunks written,
chunks in all, and the seconds encoding has left (None until known)."""

StageProgress = Callable[[str], None]
"""Told what segmenting does next, before each phase that can take a while."""


@dataclass(frozen=True)
class SegmentOptions:
    """How to segment (defaults: docs/design/segmenter.md); a window or policy left None is
    chosen by the cost model."""

    window_s: float | None = None
    policy: Policy | None = None
    max_pixels: int = DEFAULT_MAX_PIXELS
    max_copies: int = DEFAULT_MAX_COPIES
    workers: int = 1
    seed: int = 0
    slice_s: float | None = None
    """Chunks of a node cut by start time into slices this long (chosen with the layout)."""
    quality: int = QUALITY_MAX
    """Error budgets of the chunks' codes, 0..100 (codec/precision.py; 100: full precision)."""
    layers: int | None = None
    """Quality layers (segment/layers.py): None chooses by measurement, 1 is one layer."""
    sh_apart: bool = True
    """A layered stream keeps its base's SH bands in SH-band chunks (spec §8.7)."""
    cluster: str | None = None
    """Encode on Dask: ``local`` (a LocalCluster of ``workers``) or a scheduler address; None
    encodes here or in a local process pool."""


@dataclass
class SegmentReport:
    """What segmenting produced."""

    path: str
    bytes: int
    chunks: int
    windows: int
    gaussians: int
    stored: int
    dropped: int
    bytes_per_level: dict[int, int] = field(default_factory=dict)
    bytes_per_window: list[int] = field(default_factory=list)
    """Bytes of the window chunks (level 0) of each window, in time order."""
    layout: Choice | None = None
    """The layout used, its estimates, the others tried and why it was chosen."""
    view: Camera | None = None
    """Where a player opens the scene (the index's ``view``)."""
    view_why: str = ""
    """Why that view (framing.opening_view)."""
    layers: list[Layer] = field(default_factory=list)
    """The index's quality layers (empty: one layer)."""
    layers_why: str = ""
    """How the layers were chosen (segment/layers.py)."""
    faint: int = 0
    """Gaussians too faint to store at the quality, left out (precision.faint_at)."""
    start_s: float = 0.0
    end_s: float = 0.0
    """The stream's time range (the index's ``scene.start_s``, ``scene.end_s``)."""
    static: bool = False
    """A static scene: a stream of one moment (no timeline)."""
    duration_assumed: bool = False
    """The scene's length was assumed by its reader (the index's ``duration_assumed``)."""


def palette_pixels(count: int, sh_bands: int) -> int:
    """Most pixels the shN centroid image of a ``count``-Gaussian chunk can take (0 without
    SH): rows of SH_CENTROIDS_PER_ROW entries x coefficients, palette_size(count) entries."""
    coeffs = SH_COEFFS_BY_BANDS[sh_bands]
    if coeffs == 0 or count < 1:
        return 0
    rows = -(-palette_size(count) // SH_CENTROIDS_PER_ROW)
    return rows * SH_CENTROIDS_PER_ROW * coeffs


MAX_CHUNK_GAUSSIANS = 1 << 20
"""No chunk holds more Gaussians than this, whatever the pixel budget allows: one encode job
must not hold most of a scene (docs/design/cluster.md), and the SH palette saturates at
65536 entries long before."""


def max_gaussians_per_chunk(max_pixels: int, sh_bands: int = 0) -> int:
    """Largest Gaussian count whose SOG images (the SH palette's included) fit in
    ``max_pixels`` pixels each (and in WebP), at most MAX_CHUNK_GAUSSIANS."""
    if max_pixels < MIN_PIXELS or max_pixels > WEBP_MAX_SIDE * WEBP_MAX_SIDE:
        raise InputError(
            f"pixel budget must be between {MIN_PIXELS} and {WEBP_MAX_SIDE}^2, got {max_pixels}",
            where="--max-pixels",
        )
    if palette_pixels(1, sh_bands) > max_pixels:
        raise InputError(
            f"a chunk with {sh_bands} SH bands needs a {palette_pixels(1, sh_bands)}-pixel "
            f"palette image, over the budget of {max_pixels}",
            where="--max-pixels",
        )
    lo, hi = 1, max_pixels
    while lo < hi:
        mid = (lo + hi + 1) // 2
        try:
            w, h = image_size(mid)
            fits = w * h <= max_pixels and palette_pixels(mid, sh_bands) <= max_pixels
        except InputError:
            fits = False
        lo, hi = (mid, hi) if fits else (lo, mid - 1)
    return min(lo, MAX_CHUNK_GAUSSIANS)


STATIC_WINDOW_S = 1.0
"""The ``window_s`` of a static scene's index (its one window: any positive length would do)."""
