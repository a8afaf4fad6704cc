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
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..codec.sh_bands import without_sh
from ..constants import MAX_PSNR_DB
from ..errors import InputError
from ..model import Gaussians, Scene, count_at, shown_at
from ..opacity import logit_to_alpha
from ..render import render, to_uint8
from ..render.camera import from_capture
from ..render.metrics import mse, psnr_from_mse
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


def importance(gaussians: Gaussians) -> F64:
    """How much each Gaussian contributes to a picture: alpha x sqrt(area of its two largest
    axes), the best picture for a given share among the weights measured."""
    alpha = logit_to_alpha(gaussians.opacities)
    axes = np.sort(np.exp(gaussians.scales.astype(np.float64)), axis=1)
    weights: F64 = alpha * np.sqrt(axes[:, 1] * axes[:, 2])
    return weights


def top_share(weights: F64, groups: Sequence[Ints], share: float) -> Ints:
    """The most important ``share`` of each group (at least one of a non-empty group), sorted."""
    keep = [g[np.argsort(-weights[g], kind="stable")[: math.ceil(share * g.size)]] for g in groups]
    return np.sort(np.concatenate(keep)) if keep else np.zeros(0, np.int64)


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
        for g in groups:
            order = g[np.argsort(-weights[g], kind="stable")]
            cuts = [math.ceil(share * g.size) for share in self.shares]
            layer[order] = np.searchsorted(np.asarray(cuts), np.arange(g.size), "right")
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
) -> LayerPlan:
    """Cut ``scene``, stored as ``groups`` (index arrays), into ``layers`` quality layers
    (None: choose), each cut's picture measured from ``view`` at ``times`` (none given:
    MEASURE_TIMES spread over the scene); ``sh_apart``: see :attr:`LayerPlan.sh_apart`."""
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
    full = [to_uint8(render(scene.at(t), camera)) for t in times]  # a frame at a time
    quality = _quality_of_share(scene, groups, camera, dict(zip(times, full, strict=True)))
    limit = 1.0 if layers else AUTO_MAX_FRACTION
    shares: list[float] = []
    psnr: list[float | None] = []
    sh_apart = sh_apart and scene.gaussians.sh_bands > 0
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


def _quality_of_share(
    scene: Scene, groups: Sequence[Ints], camera: Camera, full_at: dict[float, U8]
) -> Callable[[float, bool], float]:
    """PSNR, over the sampled times (``full_at``: the whole scene's picture at each), of the
    most important ``share`` of each group (``bare``: DC colour only), drawn from ``camera``;
    cached."""
    times, full = list(full_at), list(full_at.values())
    weights = importance(scene.gaussians)
    cache: dict[tuple[float, bool], float] = {}

    def quality(share: float, bare: bool) -> float:
        if (share, bare) not in cache:
            chosen = top_share(weights, groups, share)
            errors = [
                mse(to_uint8(render(_share_at(scene, chosen, t, bare), camera)), f)
                for t, f in zip(times, full, strict=True)
            ]
            cache[share, bare] = min(psnr_from_mse(float(np.mean(errors))), MAX_PSNR_DB)
        return cache[share, bare]

    return quality


def _share_at(scene: Scene, chosen: Ints, t: float, bare: bool) -> Gaussians:
    """``scene.subset(chosen).at(t)`` (``bare``: DC colour only), without copying the chosen
    rows not shown at ``t``."""
    rows = chosen[shown_at(scene, t)[chosen]]
    part = scene.subset(rows)
    return (without_sh(part) if bare else part).at(t)


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
