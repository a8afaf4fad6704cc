"""Quality layers: the Gaussians that matter most for the picture first.

Each group a chunk is cut from (a node's time slice) is stored in layers of decreasing
importance, each layer its own standalone chunks: a viewer on a slow link draws the base at
once and adds layers as bytes arrive. Each cut is the smallest share of every group whose
picture, rendered from the opening view at a few times, reaches that layer's PSNR target
(docs/design/segmenter.md, "Quality layers").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from ..constants import MAX_PSNR_DB
from ..errors import InputError
from ..model import Gaussians, Scene, count_at, shown_at
from ..opacity import logit_to_alpha
from ..render import draw, to_uint8
from ..render.camera import from_capture
from ..render.metrics import mse, psnr_from_mse
from ..render.project import Projected, project
from ..render.sh import sh_colors
from ..schemas.cameras import Camera
from ..temporal import time_range

LAYER_TARGETS_DB = (25.0, 33.0, 38.0, 42.0, 45.0, 48.0, 50.0)
"""PSNR (against all layers) that layers 0, 1, ... reach with the layers below them: the base
is a recognisable picture, the second one good enough to play on at half the full bitrate."""
MAX_LAYERS = len(LAYER_TARGETS_DB) + 1
AUTO_LAYERS = 3
"""Layers of a scene big enough to layer when ``--layers`` is not given (base, middle, rest)."""
LAYERED_MIN_GAUSSIANS = 16384
"""Layers are chosen (``--layers`` not given) when a frame shows at least this many Gaussians
on average (about 0.5 MB); below it a whole frame arrives quickly anyway."""
AUTO_MAX_FRACTION = 0.75
"""Without ``--layers``, a cut needing more than this share of the Gaussians is not made (the
layer above it would add too little to be worth a request)."""
MEASURE_TIMES = 3
MEASURE_WIDTH = 256
"""Times sampled, and width in pixels of the renders, when cutting layers."""
FRACTIONS: tuple[float, ...] = (0.02, 0.03, 0.05, 0.07, 0.1, 0.13, 0.16, 0.2, 0.25, 0.3)
FRACTIONS += (0.35, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Shares of the Gaussians (most important first) a cut may be made at."""
F64 = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
Bools = npt.NDArray[np.bool_]


def importance(gaussians: Gaussians) -> F64:
    """How much each Gaussian contributes to a picture: alpha x sqrt(area of its two largest
    axes), the best picture for a given share among the weights measured."""
    alpha = logit_to_alpha(gaussians.opacities)
    axes = np.sort(np.exp(gaussians.scales.astype(np.float64)), axis=1)
    weights: F64 = alpha * np.sqrt(axes[:, 1] * axes[:, 2])
    return weights


def ranked(weights: F64, groups: Sequence[Ints]) -> list[Ints]:
    """Each group's rows, most important first (ties by index)."""
    return [g[np.argsort(-weights[g], kind="stable")] for g in groups]


def top_share(weights: F64, groups: Sequence[Ints], share: float) -> Ints:
    """The most important ``share`` of each group (at least one of a non-empty group), sorted."""
    keep = _top_of(ranked(weights, groups), share)
    return np.sort(np.concatenate(keep)) if keep else np.zeros(0, np.int64)


def _top_of(ranked_groups: Sequence[Ints], share: float) -> list[Ints]:
    """The first ``share`` of each ranked group (at least one of a non-empty group)."""
    return [r[: math.ceil(share * r.size)] for r in ranked_groups]


@dataclass(frozen=True)
class LayerPlan:
    """Where layers are cut: layers 0..k hold the most important ``shares[k]`` of each group,
    and the PSNR measured with them (None for the last layer, the full scene)."""

    shares: tuple[float, ...]
    psnr_db: tuple[float | None, ...]
    why: str = ""
    sh_apart: bool = False
    """The base's SH bands beyond DC are stored in SH-band chunks of layer 1 (spec §8.7)."""

    @property
    def layers(self) -> int:
        """Number of layers."""
        return len(self.shares)

    @classmethod
    def single(cls, why: str = "") -> LayerPlan:
        """Today's layout: one layer holding everything."""
        return cls((1.0,), (None,), why)

    def sizes(self, group_sizes: Sequence[int]) -> list[int]:
        """Gaussians of each layer when groups of ``group_sizes`` are cut (as :meth:`assign`)."""
        out = [0] * self.layers
        for n in group_sizes:
            cuts = [0, *(math.ceil(share * n) for share in self.shares)]
            for k in range(self.layers):
                out[k] += cuts[k + 1] - cuts[k]
        return out

    def assign(self, weights: F64, groups: Sequence[Ints]) -> Ints:
        """The layer of each Gaussian of ``groups`` given its importance (ties by index)."""
        layer = np.zeros(weights.size, np.int64)
        for order in ranked(weights, groups):
            cuts = [math.ceil(share * order.size) for share in self.shares]
            layer[order] = np.searchsorted(np.asarray(cuts), np.arange(order.size), "right")
        return layer


ONE_LAYER_ASKED = LayerPlan.single("one layer asked for (--layers 1)")


def check_layers(layers: int | None) -> None:
    """Refuse a layer count outside 1..MAX_LAYERS."""
    if layers is not None and not 1 <= layers <= MAX_LAYERS:
        raise InputError(f"expected 1 to {MAX_LAYERS} layers, got {layers}", where="--layers")


def _times(scene: Scene) -> list[float]:
    """Centres of MEASURE_TIMES equal parts of the scene's time range (a static scene: its
    one moment, 0 s)."""
    if scene.timeline is None:
        return [0.0]
    first, last = time_range(scene.timeline)
    return [first + (k + 0.5) * (last - first) / MEASURE_TIMES for k in range(MEASURE_TIMES)]


def plan_layers(
    scene: Scene,
    groups: Sequence[Ints],
    view: Camera | None,
    layers: int | None,
    times: Sequence[float] = (),
    *,
    sh_apart: bool = True,
    told: Callable[[str], None] = lambda _: None,
) -> LayerPlan:
    """Cut ``scene``, stored as ``groups`` (index arrays), into ``layers`` quality layers
    (None: choose), each cut's picture measured from ``view`` at ``times`` (none given:
    MEASURE_TIMES spread over the scene); ``sh_apart``: see :attr:`LayerPlan.sh_apart`;
    ``told`` hears each step (a time projected, a share measured)."""
    check_layers(layers)
    if layers == 1:
        return ONE_LAYER_ASKED
    if view is None or len(scene) < 2:
        return LayerPlan.single("one layer: nothing visible to measure layers on")
    times = list(times) or _times(scene)
    if layers is None:
        shown = np.mean([count_at(scene, t) for t in times])
        if shown < LAYERED_MIN_GAUSSIANS:
            return LayerPlan.single(
                f"one layer: a frame shows {shown:.0f} Gaussians "
                f"(layered from {LAYERED_MIN_GAUSSIANS})"
            )
    camera = from_capture(view, MEASURE_WIDTH)
    sh_apart = sh_apart and scene.gaussians.sh_bands > 0
    samples = []
    for k, t in enumerate(times, 1):
        samples.append(_sampled(scene, t, camera, sh_apart))
        told(f"measuring quality layers: {k}/{len(times)} times drawn")
    quality = _quality_of_share(scene, groups, samples, told)
    limit = 1.0 if layers else AUTO_MAX_FRACTION
    shares: list[float] = []
    psnr: list[float | None] = []
    for target in LAYER_TARGETS_DB[: (layers or AUTO_LAYERS) - 1]:
        bare = sh_apart and not shares  # the base is stored without its SH bands
        share, reached = _smallest_share(quality, target, shares[-1] if shares else 0.0, bare)
        if share > limit or share >= 1.0:
            break
        shares.append(share)
        psnr.append(reached)
    if not shares:
        return LayerPlan.single("one layer: no share of the Gaussians reaches the base target")
    why = ", ".join(f"{f:.0%}: {p:.1f} dB" for f, p in zip(shares, psnr, strict=True) if p)
    bands = ", the base's SH bands apart" if sh_apart else ""
    return LayerPlan(
        (*shares, 1.0), (*psnr, None), f"{len(shares) + 1} layers ({why}{bands})", sh_apart
    )


@dataclass(frozen=True)
class _Sampled:
    """One sampled time, projected once: every share's picture at that time selects rows of
    this projection (the Gaussians of a share project as they do in the whole scene)."""

    camera: Camera
    full: U8
    """The whole scene's picture."""
    rows: Ints
    """The scene row of each projected row."""
    proj: Projected
    by_depth: Ints
    """The projected rows in drawing order (by depth, ties in row order)."""
    bare_color: F64 | None
    """Each projected row's colour from its DC term alone (None: not needed)."""


def _sampled(scene: Scene, t: float, camera: Camera, bare: bool) -> _Sampled:
    """The scene at ``t`` projected for ``camera`` (``bare``: DC colours kept too), with its
    drawing order, so that a share's draw finds its rows already sorted."""
    at_t = scene.at(t)  # the rows shown at t, in row order
    proj = project(at_t, camera)
    by_depth = np.argsort(proj.depth, kind="stable")
    rows = np.flatnonzero(shown_at(scene, t))[proj.index]
    bare_color = None
    if bare:
        eye = np.asarray(camera.position, np.float64)
        means, sh0 = at_t.means[proj.index], at_t.sh0[proj.index]
        bare_color = sh_colors(means, sh0, np.zeros((len(means), 0, 3), np.float32), eye)
    full = to_uint8(draw(proj, camera, only=by_depth))
    return _Sampled(camera, full, rows, proj, by_depth, bare_color)


def _quality_of_share(
    scene: Scene, groups: Sequence[Ints], samples: Sequence[_Sampled], told: Callable[[str], None]
) -> Callable[[float, bool], float]:
    """PSNR, over the sampled times, of the most important ``share`` of each group (``bare``:
    DC colour only) against the whole scene's picture, each told; cached."""
    order = ranked(importance(scene.gaussians), groups)
    cache: dict[tuple[float, bool], float] = {}

    def quality(share: float, bare: bool) -> float:
        if (share, bare) not in cache:
            chosen = np.zeros(len(scene), bool)
            for top in _top_of(order, share):
                chosen[top] = True
            errors = [mse(_share_picture(s, chosen, bare), s.full) for s in samples]
            cache[share, bare] = min(psnr_from_mse(float(np.mean(errors))), MAX_PSNR_DB)
            colour = ", DC colour only" if bare else ""
            told(f"measuring quality layers: {share:.0%}{colour}: {cache[share, bare]:.1f} dB")
        return cache[share, bare]

    return quality


def _share_picture(sample: _Sampled, chosen: Bools, bare: bool) -> U8:
    """The picture of the ``chosen`` Gaussians at a sampled time (``bare``: DC colour only)."""
    proj = sample.proj
    if bare and sample.bare_color is not None:
        proj = replace(proj, color=sample.bare_color)
    order = sample.by_depth
    return to_uint8(draw(proj, sample.camera, only=order[chosen[sample.rows[order]]]))


def _smallest_share(
    quality: Callable[[float, bool], float], target: float, above: float, bare: bool
) -> tuple[float, float]:
    """The smallest share of FRACTIONS above ``above`` whose picture reaches ``target`` dB
    (bisection), and its PSNR; (1.0, inf) when none does."""
    grid = [f for f in FRACTIONS if f > above]
    lo, hi = 0, len(grid)
    while lo < hi:
        mid = (lo + hi) // 2
        if quality(grid[mid], bare) >= target:
            hi = mid
        else:
            lo = mid + 1
    if lo == len(grid):
        return 1.0, math.inf
    return grid[lo], quality(grid[lo], bare)
