"""Error budgets (``--quality``): how far each Gaussian's attributes may move at a quality q,
as ``f = (1 - q/100)²`` (0 at 100: nothing moves) times each one's room at quality 0.

- position: :func:`position_fraction` times CORE_AT_ZERO of the chunk's dense-core radius times
  its :func:`faintness`, at every time it is visible; when the means move, a third each for
  the base and the motion's orders (a root mean square over the lifespan);
- rotation: the turn that moves its ellipsoid's surface by TURN_SURFACE position budgets;
- scales, base colours, opacity and SH bands: the chunk's :class:`Slacks`;
- the motion of rotations, scales, colours and opacity: as much again as the base may move,
  split over the orders, a root mean square over the lifespan;
- timeline: ``f * TIME_AT_ZERO`` of its temporal scale (frame ids stay exact).
What a quality guarantees: docs/spec.md, Appendix A.2; measurements: docs/design/chunk-codec.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..columns import across
from ..constants import SH_C0
from ..errors import InputError
from ..framing import dense_core, framing_sample
from ..model import Gaussians, Scene, Timeline, TimelineType, reference_times
from ..opacity import logit_to_alpha
from ..temporal import lifespans, scale_cap, time_range

F64 = npt.NDArray[np.float64]

QUALITY_MAX = 100
"""Today's precision: every code keeps its 16 bits (the library's default)."""
MAX_TURN = 0.5
"""Radians a rotation may turn at most, whatever its budget (the small-angle bound holds)."""
TURN_SURFACE = 2.0
"""How far, in position budgets, a turn may move the ends of a Gaussian's ellipsoid (a turn
moves its ends, not its mass)."""
SCALE_AT_ZERO = 0.2
"""At quality 0 a log-sigma may move this much beyond its codebook error (sigma x 0.82..1.22)."""
COLOUR_AT_ZERO = 0.1
"""At quality 0 a base colour (0..1) may move this much beyond its codebook error."""
ALPHA_AT_ZERO = 0.1
"""At quality 0 an opacity (alpha, 0..1) may move this much."""
TURN_PER_COMPONENT = 4.0 * float(np.sqrt(3.0))
"""Radians a rotation turns at most per unit of error in each stored quaternion component
(twice the quaternion distance, the fourth component rederived)."""
LOGIT_PER_ALPHA = 4.0
"""Logit units per alpha unit that keep an opacity's change within it (d alpha / d logit <=
1/4)."""
CORE_AT_ZERO = 2.0**-9
"""At quality 0 an opaque Gaussian's position may move by this fraction of its chunk's
dense-core radius (about a pixel of a 1080p view framing the core), whatever its size: a shift
of d pixels adds the same squared error whether the Gaussian is wide or thin."""
CORE_SAMPLE = 8192
"""At most this many Gaussians of a chunk (evenly strided) measure its dense core."""
POSITION_AT_ZERO = 16.0
"""At quality 0 the position budget is this many times CORE_AT_ZERO (positions were the
cheapest decibels measured at the bottom of the scale)."""
MOTION_AT_ZERO = 8.0
"""At quality 0 the means' motion may take this many times its third of the position budget
(:func:`stretch`; the cheapest decibels left on the .splatv captures)."""
FAINT_MAX = 32.0
"""A Gaussian's position budget grows as 1 / alpha up to this many times an opaque one's."""
TIME_AT_ZERO = 0.1
"""At quality 0 a lifespan's centre, start, scale or duration may move by this fraction of the
Gaussian's temporal scale."""


def check_quality(quality: int) -> int:
    """``quality`` when it is an integer in 0..100 (InputError otherwise)."""
    if isinstance(quality, bool) or not isinstance(quality, int) or not 0 <= quality <= 100:
        raise InputError(f"expected an integer from 0 to 100, got {quality!r}", where="quality")
    return quality


def budget_fraction(quality: int) -> float:
    """``(1 - quality/100)²``: 0 at 100, 1 at 0 (finer steps near the top, where they show)."""
    return (1.0 - check_quality(quality) / QUALITY_MAX) ** 2


@dataclass(frozen=True)
class Slacks:
    """What every Gaussian's scale, colour and opacity may move at a quality, beyond their
    codebook errors (the same for the whole chunk)."""

    scale: float
    """Log-sigma."""
    colour: float
    """f_dc."""
    alpha: float
    """Alpha (0..1)."""
    bands: float
    """The colour (0..1) the SH bands add in a view: the RMS over Gaussians and directions of
    its error beyond the full palette's (``sh_palette.fit_palette``'s ``slack``)."""

    @classmethod
    def at(cls, f: float) -> Slacks:
        """The slacks at a budget fraction f."""
        colour = f * COLOUR_AT_ZERO
        return cls(f * SCALE_AT_ZERO, colour / SH_C0, f * ALPHA_AT_ZERO, colour)


@dataclass(frozen=True)
class Budgets:
    """The error each Gaussian of a chunk may take (in texel order)."""

    position: F64
    """(N,) scene units a position may move, in all, at any time it is visible."""
    time: F64
    """(N, 2) how far its timeline channels may move (R: frame/start/centre, G: duration/
    scale), in the timeline's units."""
    reach: F64
    """(N,) seconds from its reference time to the far end of its lifespan, with the room a
    coarsened lifespan may add."""
    around_reference: npt.NDArray[np.bool_]
    """(N,) whether that part of its lifespan holds its reference time (its motion's error is
    then budgeted as a root mean square)."""
    fading: F64
    """(N, 2) seconds of a type-2 Gaussian's temporal scale and of the part of its lifespan
    inside the scene (:meth:`motion_span`); infinite scales for the other timeline types."""
    moving: bool
    """Whether the chunk stores motion of the means (the base then takes a third)."""
    rotation: F64
    """(N,) radians its rotation may turn: TURN_SURFACE position budgets over its largest minus
    smallest sigma, at most MAX_TURN."""
    slacks: Slacks
    """What every Gaussian's scale, colour and opacity may move."""
    motion_stretch: float = 1.0
    """The means' motion's share over its third of the position budget (MOTION_AT_ZERO)."""

    @classmethod
    def of(cls, scene: Scene, quality: int) -> Budgets | None:
        """The budgets of ``scene`` at ``quality``; None at 100 (nothing is coarsened). A
        non-finite value gives a NaN budget, which ``coarsen`` reads as none (codes kept)."""
        f = budget_fraction(quality)
        if f == 0.0:
            return None
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return cls._at(scene, f)

    @classmethod
    def _at(cls, scene: Scene, f: float) -> Budgets:
        """The budgets at a budget fraction f > 0, numpy's warnings silenced (see :meth:`of`)."""
        sigmas = np.exp(scene.gaussians.scales.astype(np.float64))
        smallest, largest = across(np.minimum, sigmas), across(np.maximum, sigmas)
        pixel = CORE_AT_ZERO * _core_radius(scene.gaussians)
        position = _finite_or_zero(
            position_fraction(f) * pixel * faintness(scene.gaussians.opacities)
        )
        spread = _finite_or_zero(largest - smallest)  # no budget for non-finite scales
        surface = TURN_SURFACE * position
        rotation = np.minimum(np.where(spread > 0, surface / spread, np.inf), MAX_TURN)
        timeline = scene.timeline
        reach, around_reference = _reach(timeline)
        time = _time_budget(timeline, f)
        if scene.temporal and timeline is not None:
            # a moved reference time lengthens the reach of every polynomial: within its room
            room = f * TIME_AT_ZERO * reach / timeline.seconds_per_unit
            time[:, 0] = np.minimum(time[:, 0], room)
        reach = reach * (1.0 + f * TIME_AT_ZERO)
        fading = _fading(timeline, f)
        return cls(
            position,
            time,
            reach,
            around_reference,
            fading,
            "means" in scene.temporal,
            rotation,
            Slacks.at(f),
            motion_stretch=stretch(f, MOTION_AT_ZERO),
        )

    def base_position(self) -> F64:
        """What the base position may move: a third of the budget when the chunk has motion."""
        return self.position / 3 if self.moving else self.position

    def motion_span(self, order: int, rows: slice = slice(None)) -> F64:
        """(N,) (or of ``rows``) the most an error d in a coefficient of order k may be
        multiplied by: d x this bounds the change it makes over the lifespan (the largest, or
        the root mean square where the lifespan holds t_ref: at most reach^k / sqrt(2k + 1),
        and for a type-2 Gaussian weighed by its fading, Gamma(k + 1/2) s^(2k+1) / L)."""
        far = self.reach[rows] ** order
        scale, length = self.fading[rows, 0], self.fading[rows, 1]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            weighted = np.sqrt(math.gamma(order + 0.5) * scale ** (2 * order + 1) / length)
        around = self.around_reference[rows]
        return np.where(around, np.fmin(far / rms_room(order), weighted), far)

    def change_over_lifespan(self, attr: str, channels: int, rows: slice = slice(None)) -> F64:
        """(N, channels) (or of ``rows``) how far the motion of ``attr`` may move it over the
        lifespan, in its coefficients' units: means a third of the position budget (times
        ``motion_stretch``), quats the rotation budget, the others their slacks."""
        n = len(self.position[rows])
        if attr == "means":
            per_gaussian = self.position[rows] / 3 * self.motion_stretch
        elif attr == "quats":
            per_gaussian = self.rotation[rows] / TURN_PER_COMPONENT
        else:
            opacity = LOGIT_PER_ALPHA * self.slacks.alpha
            slack = {"scales": self.slacks.scale, "sh0": self.slacks.colour, "opacity": opacity}
            per_gaussian = np.full(n, slack[attr])
        out = np.repeat(per_gaussian[:, None], channels, axis=1)
        if attr == "sh0" and channels == 4:
            out[:, 3] = LOGIT_PER_ALPHA * self.slacks.alpha  # opacity's motion, sh0's A channel
        return out


def stretch(f: float, at_zero: float) -> float:
    """1 + (at_zero - 1) f⁴: 1 at quality 100, near 1 down to quality 50, ``at_zero`` at 0."""
    return 1.0 + (at_zero - 1.0) * f**4


def position_fraction(f: float) -> float:
    """The position budget's fraction at budget fraction f: f :func:`stretch` (POSITION_AT_ZERO)."""
    return f * stretch(f, POSITION_AT_ZERO)


def faintness(logits: npt.NDArray[np.floating]) -> F64:
    """1 / alpha of each Gaussian, from 1 (opaque) up to FAINT_MAX: an error in a Gaussian drawn
    at alpha a changes the picture a times as much as in an opaque one."""
    alpha = logit_to_alpha(np.asarray(logits, np.float64).reshape(len(logits)))
    return 1.0 / np.maximum(alpha, 1.0 / FAINT_MAX)


def _core_radius(gaussians: Gaussians) -> float:
    """The dense-core radius of ``gaussians`` (CORE_SAMPLE of them at most); 0 when none is
    visible."""
    try:
        return dense_core(framing_sample(gaussians, CORE_SAMPLE))[1]
    except InputError:
        return 0.0


def _finite_or_zero(values: F64) -> F64:
    """``values`` with every non-finite entry 0 (such a Gaussian keeps its codes as they are)."""
    return np.where(np.isfinite(values), values, 0.0)


def _time_budget(timeline: Timeline | None, f: float) -> F64:
    """Per Gaussian and timeline channel, how far it may move: a share of its temporal scale
    (type 2) or duration (type 1); zeros for frame ids."""
    if timeline is None:
        return np.zeros((0, 2))
    if timeline.type is TimelineType.FRAME:
        return np.zeros((len(timeline), 2))
    scale = timeline.t1.astype(np.float64)
    if timeline.type is TimelineType.CENTER_SCALE:
        scale = np.minimum(scale, scale_cap(timeline))  # as stored (a .splatv may say 65504)
    share = f * TIME_AT_ZERO * scale
    return np.stack([share, share], axis=1)


def _seen_part(timeline: Timeline) -> tuple[F64, F64]:
    """(start, end) seconds of the part of each lifespan inside the scene's time range (end
    below start for a Gaussian never seen)."""
    first, last = time_range(timeline)
    start, end = lifespans(timeline)
    return np.maximum(start, first), np.minimum(end, last)


def _reach(timeline: Timeline | None) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Seconds from each reference time to the far end of the part of its lifespan inside the
    scene's time range, and whether that part holds the reference time."""
    if timeline is None:
        return np.zeros(0), np.zeros(0, bool)
    start, end = _seen_part(timeline)
    ref = reference_times(timeline)
    reach = np.maximum(np.abs(start - ref), np.abs(end - ref))
    seen = end >= start
    return np.where(seen, reach, 0.0), seen & (start <= ref) & (ref <= end)


def _fading(timeline: Timeline | None, f: float) -> F64:
    """(N, 2): each type-2 Gaussian's temporal scale and the length of its lifespan inside the
    scene, in seconds, widened by a coarsened lifespan's room; an infinite scale otherwise."""
    if timeline is None:
        return np.zeros((0, 2))
    n = len(timeline)
    if timeline.type is not TimelineType.CENTER_SCALE:
        return np.stack([np.full(n, np.inf), np.ones(n)], axis=1)
    start, end = _seen_part(timeline)
    length = end - start
    scale = timeline.t1.astype(np.float64) * (1.0 + f * TIME_AT_ZERO)  # type 2: in seconds
    length = np.maximum(length, 0.0) / (1.0 + f * TIME_AT_ZERO)
    return np.stack([scale, length], axis=1)


def rms_room(order: int) -> float:
    """sqrt(2k + 1): the worst-case change of order ``k`` over its root mean square over the
    lifespan."""
    return float(np.sqrt(2 * order + 1))
