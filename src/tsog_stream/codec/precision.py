"""Error-budgeted precision (``--quality``): the low bits of a 16-bit code a Gaussian can lose
while its error stays within a budget set by the quality.

Sans-I/O. A coarsened code is still a 16-bit code over the chunk's ``[min, max]``: its dropped
bits are zeros, which make the ``_l`` image's planes constant or nearly so (lossless WebP then
spends almost nothing on them), and every SOG/TSOG reader decodes the chunk unchanged. What a
quality level guarantees is stated in docs/spec.md, Appendix A.2 (what a writer may round:
§5.1).

Budgets, per Gaussian, at quality q (``f = (1 - q/100)²``, 0 at 100: today's precision):
- position: :func:`position_fraction` (about f down to quality 50, POSITION_AT_ZERO at 0)
  times CORE_AT_ZERO of the chunk's dense-core radius (about a pixel of a 1080p view framing
  the core) times its :func:`faintness` (1 / alpha, at most FAINT_MAX), at every
  time it is visible inside the scene's time range; when it moves, a third each for the
  base position and the orders of its motion (as a root mean square over that part of its
  lifespan, see :func:`coarsen_motion`). The third its reference time's rounding took until
  the encoder stored every polynomial about the rounded reference time
  (:func:`~tsog_stream.temporal.recentre`) is left unspent: spent on the other two, 6 of
  the 10 moving scenes of bench_rate took more bytes at `.4dgs`'s PSNR;
- rotation: the turn that moves its ellipsoid's surface by TURN_SURFACE position budgets;
- scales and base colours: at most ``f * SCALE_AT_ZERO`` (log-sigma) and ``f *
  COLOUR_AT_ZERO`` (colour 0..1) beyond their codebook error: labels move to fewer distinct
  entries of the same 256-entry codebook; opacity within ``f * ALPHA_AT_ZERO``;
- SH bands: the colour they add in a view within ``f * COLOUR_AT_ZERO`` beyond the full
  palette's error, as a root mean square over Gaussians and view directions: palette
  entries merge while it holds (:func:`~tsog_stream.sh_palette.fit_palette`'s ``slack``);
- the motion of rotations, scales, colours and opacity (their temporal coefficients): over
  the Gaussian's lifespan, each may add as much again as its base may move (the rotation
  budget; the scale, colour and opacity slacks), split evenly over the orders, as a root
  mean square over the lifespan;
- timeline (type 2 centre and scale, type 1 start and duration): ``f * TIME_AT_ZERO`` times
  its temporal scale (type 2 scale as stored; type 1 duration); the encoder stores the
  attributes at the rounded reference time, so rounding it moves nothing but the lifespan,
  and where anything moves, the reference time within that share of its reach too (a
  moved t_ref lengthens the reach of every polynomial).
  Frame ids, and lifespans the encoder stores in whole frames, stay exact.
- which Gaussians: below quality 100, none of alpha within ``f * FAINT_AT_ZERO`` (twice the
  opacity's slack; :func:`faint_at`: ``tsog encode`` and ``tsog segment`` leave them out
  before encoding).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from ..columns import across, row_blocks
from ..constants import SH_C0, U16_MAX
from ..errors import InputError
from ..framing import dense_core, framing_sample
from ..model import Gaussians, Scene, Timeline, TimelineType, reference_times
from ..opacity import logit_to_alpha
from ..temporal import lifespans, scale_cap, time_range

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
U16 = npt.NDArray[np.uint16]
CodesT = TypeVar("CodesT", npt.NDArray[np.uint8], npt.NDArray[np.uint16])
MAX_TURN = 0.5
"""Radians a rotation may turn at most, whatever its budget (within it the small-angle bound of
:func:`coarsen_rotations` holds)."""
TURN_SURFACE = 2.0
"""How far, in position bounds, a turn may move the ends of a Gaussian's ellipsoid: a turn
moves its ends, not its mass, and twice the bound spent 2-5 % fewer bytes at equal PSNR on
every moving scene of bench_rate, the fireworks unchanged (docs/design/chunk-codec.md)."""
SCALE_AT_ZERO = 0.2
"""At quality 0 a log-sigma may move this much beyond its codebook error (sigma x 0.82..1.22)."""
COLOUR_AT_ZERO = 0.1
"""At quality 0 a base colour (0..1) may move this much beyond its codebook error."""
ALPHA_AT_ZERO = 0.1
"""At quality 0 an opacity (alpha, 0..1) may move this much."""
QUAT_STEP = float(np.sqrt(2.0)) / 255.0
"""A smallest-three quaternion byte's step in component units (SOG v2 quats.webp)."""
TURN_PER_COMPONENT = 4.0 * float(np.sqrt(3.0))
"""Radians a rotation turns at most per unit of error in each stored quaternion component
(twice the quaternion distance, the fourth component rederived)."""
LOGIT_PER_ALPHA = 4.0
"""Logit units per alpha unit that keep an opacity's change within it (d alpha / d logit <=
1/4)."""

QUALITY_MAX = 100
"""Today's precision: every code keeps its 16 bits (the library's default)."""
DEFAULT_QUALITY = 90
"""``tsog encode`` and ``tsog segment``'s default: within about 0.1 dB of quality 100's
rendered PSNR on the real scenes measured, for fewer bytes (docs/design/chunk-codec.md,
"Default 90")."""
CORE_AT_ZERO = 2.0**-9
"""At quality 0 an opaque Gaussian's position may move by this fraction of its chunk's
dense-core radius (framing.dense_core; about a pixel of a 1080p view framing the core),
whatever its size: a shift of d pixels adds the same squared error to a picture whether the
Gaussian is wide or thin (a² c² pi/2 d², integrated over its footprint; docs/design/
chunk-codec.md)."""
CORE_SAMPLE = 8192
"""At most this many Gaussians of a chunk (evenly strided) measure its dense core."""
POSITION_AT_ZERO = 16.0
"""At quality 0 the position budget is this many times CORE_AT_ZERO (16 pixels of a 1080p view
framing the core, an opaque Gaussian): positions were the cheapest decibels measured, so the
bottom of the scale reaches lower rates through them (docs/design/chunk-codec.md)."""
MOTION_AT_ZERO = 8.0
"""At quality 0 the means' motion may take this many times its third of the position budget
(:func:`stretch`: 1.03x at quality 50): on the .splatv captures the motion's codes were the
cheapest decibels left at the bottom of the scale (docs/design/chunk-codec.md)."""
FAINT_MAX = 32.0
"""A Gaussian's position budget grows as 1 / alpha up to this many times an opaque one's
(alpha 1/32 and fainter)."""
TIME_AT_ZERO = 0.1
"""At quality 0 a lifespan's centre, start, scale or duration may move by this fraction of the
Gaussian's temporal scale: a lifespan coarsened less leaves its motion more room
(docs/design/chunk-codec.md)."""


def check_quality(quality: int) -> int:
    """``quality`` when it is an integer in 0..100 (InputError otherwise)."""
    if isinstance(quality, bool) or not isinstance(quality, int) or not 0 <= quality <= 100:
        raise InputError(f"expected an integer from 0 to 100, got {quality!r}", where="quality")
    return quality


def budget_fraction(quality: int) -> float:
    """``(1 - quality/100)²``: 0 at 100, 1 at 0 (finer steps near the top, where they show)."""
    return (1.0 - check_quality(quality) / QUALITY_MAX) ** 2


ALPHA_BYTE_ZERO = 0.5 / 255.0
"""Alphas up to this are stored as byte 0 (SOG's opacity byte): drawn by no reader."""
FAINT_AT_ZERO = 0.2
"""At quality 0 a Gaussian of alpha up to this is left out (``f`` times it at quality q):
twice the opacity's slack. At `.4dgs`'s PSNR on every bench_rate scene, leaving out up to
1x / 1.5x / 2x the slack took the long guitar clip 0.766 -> 0.719 / 0.702 / 0.686x its
bytes, spinach 0.545 -> 0.454 / 0.434 / 0.407x, the donuts alike, the fireworks unchanged;
at 2x a quality draws up to 0.7 dB less on the FreeTimeGS clips, 2.1 dB on coffee10 at 10,
for 39 % fewer bytes there (docs/design/chunk-codec.md)."""


def faint_at(scene: Scene, quality: int) -> npt.NDArray[np.bool_]:
    """The Gaussians too faint to store below quality 100: an alpha within ``f *
    FAINT_AT_ZERO`` (twice the slack within which the opacity may move), or one its byte
    would store as zero anyway (ALPHA_BYTE_ZERO), at every time (a lifespan only scales it
    down): such a Gaussian changes the picture less than its position's error would (its
    budget grows as 1 / alpha), and costs as many bytes as any other (spec, Appendix A.2).
    None at 100, none whose opacity moves (temporal coefficients), and none when every one
    is (a chunk holds at least one Gaussian)."""
    none = np.zeros(len(scene), np.bool_)
    f = budget_fraction(quality)
    if f <= 0.0 or len(scene) == 0 or "opacity" in scene.temporal:
        return none
    logits = np.asarray(scene.gaussians.opacities, np.float64).reshape(len(scene))
    # NaN compares False: kept, and refused by the encoder
    faint = logit_to_alpha(logits) <= max(f * FAINT_AT_ZERO, ALPHA_BYTE_ZERO)
    return none if faint.all() else faint


def without_faint(scene: Scene, quality: int, *, given_up: bool = False) -> Scene:
    """``scene`` less the Gaussians :func:`faint_at` ``quality`` (itself when there are none):
    what ``tsog encode`` and ``tsog segment`` store. A Gaussian drawn that faintly changes the
    picture less than its position's error would, and costs as many bytes as any other.
    ``given_up``: the caller is done with ``scene``, so the rows kept are gathered in its own
    arrays (:meth:`Scene.keeping`) instead of a copy beside them."""
    faint = faint_at(scene, quality)
    if not faint.any():
        return scene
    kept = np.flatnonzero(~faint)
    del faint
    return scene.keeping(kept) if given_up else scene.subset(kept)


Tolerance = F64 | Callable[[slice], F64]
"""Tolerances in codes broadcast against the codes, or a block of rows' tolerances from the
rows (where the tolerances of every row are themselves several arrays of every row)."""


def coarsen(codes: CodesT, tolerance: Tolerance, *, shared: bool = False) -> CodesT:
    """Each code (16-bit, or 8-bit) rounded to the coarsest grid of power-of-two steps whose
    rounding error is within its ``tolerance`` (in codes); a code that would round out of the
    code range keeps its value. With ``shared`` the grids are laid
    through each channel's most frequent code, so a value many Gaussians share (a zero rate of
    turn) stays one value whatever their steps; else through code 0.

    Whole-block integer arithmetic: a code on a grid of one code rounds to itself, so every
    code goes through the same few passes (gathering the moving ones and scattering them back
    took twice as long at low quality, where nearly all move). A block of rows at a time
    (``columns.row_blocks``): every row's temporaries at once were ~10 arrays of the codes'
    rows."""
    anchor = most_frequent(codes).astype(np.int32) if shared else None
    of_rows = tolerance if callable(tolerance) else _rows_of(tolerance, codes.shape)
    out = np.empty_like(codes)
    for rows in row_blocks(len(codes)):
        out[rows] = _on_grids(codes[rows], of_rows(rows), anchor)
    return out


def _rows_of(tolerance: F64, shape: tuple[int, ...]) -> Callable[[slice], F64]:
    """A block of rows' tolerances of tolerances broadcast against codes of ``shape``."""
    every = np.broadcast_to(tolerance, shape)
    return lambda rows: every[rows]


def _on_grids(codes: CodesT, tolerance: F64, anchor: npt.NDArray[np.int32] | None) -> CodesT:
    """:func:`coarsen` of a block of rows, the grids through ``anchor`` (else code 0)."""
    top = int(np.iinfo(codes.dtype).max)
    tol = np.minimum(np.fmax(tolerance, 0.5), float(top))  # NaN, -inf and < 0.5: 0.5; inf: top
    # floor(log2(2 tol)): 0 for a tolerance under one code
    bits = np.minimum(np.frexp(tol)[1], top.bit_length() - 1)
    if not bits.any():
        return codes
    grid = np.left_shift(np.int32(1), bits, dtype=np.int32)
    q = codes.astype(np.int32)  # codes, grids and sums all fit in int32
    rounded = q + (grid >> 1)
    if anchor is not None:
        rounded -= anchor
        rounded &= -grid  # floor to the grid
        rounded += anchor
    else:
        rounded &= -grid
    outside = rounded > top
    if anchor is not None:  # a grid through the anchor may round below 0 too
        outside |= rounded < 0
    return np.where(outside, q, rounded).astype(codes.dtype)


def most_frequent(codes: CodesT) -> npt.NDArray[np.int64]:
    """The most frequent code of each channel (the columns of a 2-D array; all of a 1-D one),
    shaped to broadcast against ``codes``; 0 when there are none."""
    columns = codes.reshape(len(codes), -1)
    modes = [
        int(np.bincount(columns[:, c]).argmax()) if len(columns) else 0
        for c in range(columns.shape[1])
    ]
    return np.asarray(modes, np.int64).reshape(codes.shape[1:])


def to_codes(tolerance: F64, mins: F64, maxs: F64) -> F64:
    """A tolerance in value units as one in 16-bit codes over ``[mins, maxs]`` (per channel, the
    last axis; unlimited where the range is empty: every code is 0 there)."""
    span = np.asarray(maxs, np.float64) - np.asarray(mins, np.float64)
    empty = ~(span > 0)
    out: F64 = np.multiply(tolerance, float(U16_MAX)) / np.where(empty, 1.0, span)
    if empty.any():
        out[..., empty] = np.inf
    return out


@dataclass(frozen=True)
class Slacks:
    """What every Gaussian's scale, colour and opacity may move at a quality, beyond their
    codebook errors: the same for the whole chunk (the codebooks need nothing else)."""

    scale: float
    """Log-sigma."""
    colour: float
    """f_dc."""
    alpha: float
    """Alpha (0..1)."""
    bands: float
    """The colour (0..1) the SH bands add in a view: the RMS over Gaussians and directions of
    its error beyond the full palette's (sh_palette.fit_palette's ``slack``)."""

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
    scale), in the timeline's units (a rounded reference time moves no attribute: the
    encoder stores them about it)."""
    reach: F64
    """(N,) seconds from its reference time to the far end of its lifespan, with the room a
    coarsened lifespan may add."""
    around_reference: npt.NDArray[np.bool_]
    """(N,) whether that part of its lifespan holds its reference time: its motion's error
    may then be budgeted as a root mean square (:func:`coarsen_motion`)."""
    fading: F64
    """(N, 2) seconds of a type-2 Gaussian's temporal scale and of the part of its lifespan
    inside the scene (the motion's error weighed by its temporal opacity,
    :meth:`motion_span`); infinite scales for the other timeline types."""
    moving: bool
    """Whether the chunk stores motion of the means: the base position and the motion then
    take a third of the position budget each."""
    rotation: F64
    """(N,) radians its rotation may turn: TURN_SURFACE position budgets over how far the
    turn moves its ellipsoid's surface (largest minus smallest sigma), at most MAX_TURN."""
    slacks: Slacks
    """What every Gaussian's scale, colour and opacity may move."""
    motion_stretch: float = 1.0
    """The means' motion's share over its third of the position budget (:func:`stretch`
    with MOTION_AT_ZERO)."""

    @classmethod
    def of(cls, scene: Scene, quality: int) -> Budgets | None:
        """The budgets of ``scene`` at ``quality``; None at 100 (nothing is coarsened).

        A non-finite input value gives a NaN budget, which :func:`coarsen` reads as none: such
        a Gaussian keeps its codes, and numpy's warnings about it are silenced here.
        """
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
        """(N,) (or of ``rows``) what an error d in a coefficient of order k may be multiplied
        by, at most, in the motion's share of the error: d x this bounds the change it makes
        over the lifespan (the largest, or the root mean square where the lifespan holds
        t_ref).

        The root mean square over |t - t_ref| <= reach is at most reach^k / sqrt(2k + 1).
        A type-2 Gaussian is drawn at exp(-(t - c)² / 2s²) of its opacity, and an error
        drawn at alpha a changes the picture a² times as much (as :func:`faintness`); with
        t_ref = c, the mean over a part of length L of that weight times (t - c)^2k is at
        most Gamma(k + 1/2) s^(2k+1) / L (the integral over all t), so a long-lived
        Gaussian's motion may be coarser where it fades."""
        far = self.reach[rows] ** order
        scale, length = self.fading[rows, 0], self.fading[rows, 1]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            weighted = np.sqrt(math.gamma(order + 0.5) * scale ** (2 * order + 1) / length)
        around = self.around_reference[rows]
        return np.where(around, np.fmin(far / rms_room(order), weighted), far)

    def change_over_lifespan(self, attr: str, channels: int, rows: slice = slice(None)) -> F64:
        """(N, channels) (or of ``rows``) how far the motion of ``attr`` may move it over the
        lifespan, in the units its coefficients are stored in (docs/spec.md §6): means a third
        of the position budget times ``motion_stretch``; quats the rotation budget as
        quaternion components (as the base's bytes); scales and sh0 colours their slacks;
        opacity (logit; sh0's A channel) four times the alpha slack (d alpha / d logit <= 1/4)."""
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
    """1 + (at_zero - 1) f⁴: 1 at quality 100, within 0.4 % x (at_zero - 1) of 1 down to
    quality 50, ``at_zero`` at quality 0 (how the bottom of the scale reaches lower rates)."""
    return 1.0 + (at_zero - 1.0) * f**4


def position_fraction(f: float) -> float:
    """The position budget's fraction at budget fraction f: f (1 + (POSITION_AT_ZERO - 1) f⁴),
    within 6 % of f down to quality 50, POSITION_AT_ZERO at quality 0."""
    return f * stretch(f, POSITION_AT_ZERO)


def faintness(logits: npt.NDArray[np.floating]) -> F64:
    """1 / alpha of each Gaussian, from 1 (opaque) up to FAINT_MAX: an error in a Gaussian drawn
    at alpha a changes the picture a times as much as the same error in an opaque one (a² of
    the squared error), so budgets growing as 1 / a spend the bits where they show."""
    alpha = logit_to_alpha(np.asarray(logits, np.float64).reshape(len(logits)))
    return 1.0 / np.maximum(alpha, 1.0 / FAINT_MAX)


def _core_radius(gaussians: Gaussians) -> float:
    """The dense-core radius of ``gaussians`` (at most CORE_SAMPLE of them, evenly strided:
    quantiles of a 5M chunk cost seconds); 0 when none is visible."""
    try:
        return dense_core(framing_sample(gaussians, CORE_SAMPLE))[1]
    except InputError:
        return 0.0


def _finite_or_zero(values: F64) -> F64:
    """``values`` with every non-finite entry 0 (such a Gaussian keeps its codes as they are)."""
    return np.where(np.isfinite(values), values, 0.0)


def _time_budget(timeline: Timeline | None, f: float) -> F64:
    """Per Gaussian and timeline channel, how far it may move: a share of its temporal scale
    (type 2) or duration (type 1); zeros for frame ids. The timeline encoder keeps whole
    frames exact whatever this says."""
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
    """(start, end) seconds of the part of each lifespan inside the scene's time range
    (nothing is drawn outside it: a .splatv Gaussian may live for hours in a 1 s clip); end
    below start for a Gaussian never seen."""
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
    """(N, 2): each type-2 Gaussian's temporal scale and the length of the part of its
    lifespan inside the scene, in seconds, with the room a coarsened lifespan may take (the
    scale larger, the part shorter); an infinite scale for the other types."""
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


def coarsen_positions(codes: U16, mins: F64, maxs: F64, means: F64, budget: F64) -> U16:
    """Position codes (SOG's symmetric-log domain) coarsened within ``budget`` scene units per
    Gaussian: d(log)/dx = 1 / (1 + |x|) turns the budget into a log-domain one per axis."""
    log_budget = budget[:, None] / (1.0 + np.abs(means))
    return coarsen(codes, to_codes(log_budget, mins, maxs))


def coarsen_rotations(texels: U8, budget: F64) -> U8:
    """Smallest-three rotation texels (R, G, B; the A tag kept) coarsened so each rotation
    turns by at most ``budget`` radians: a turn is at most 4·√3 times the largest component
    error (twice the quaternion distance, the fourth component rederived)."""
    out = texels.copy()
    out[:, :3] = coarsen(texels[:, :3], (budget / TURN_PER_COMPONENT / QUAT_STEP)[:, None])
    return out


def thin_labels(labels: U8, codebook: F32, slack: float) -> tuple[U8, F32]:
    """Codebook labels moved to fewer distinct entries, and the codebook they index: entries
    are kept ascending while more than ``slack`` above the last kept one, and each label goes
    to the nearest kept entry, at most ``slack`` from its own, so a value's error grows by at
    most ``slack``. An entry no label points to any more repeats the kept one it moved to (still
    ascending): meta.json deflates repeats, so small chunks stop paying for unused entries."""
    table = np.asarray(codebook, np.float64)
    if slack <= 0 or table.size == 0:
        return labels, codebook
    kept = [0]
    for i in range(1, table.size):
        if table[i] - table[kept[-1]] > slack:
            kept.append(i)
    kept_values = table[kept]
    mids = (kept_values[:-1] + kept_values[1:]) / 2
    nearest = np.asarray(kept)[np.searchsorted(mids, table, side="right")]
    return nearest.astype(np.uint8)[labels], codebook[nearest]


def coarsen_alpha(alpha: U8, slack: float) -> U8:
    """Opacity bytes coarsened within ``slack`` (alpha units)."""
    return coarsen(alpha, np.asarray(slack * 255.0))


def coarsen_timeline(codes: U16, mins: F64, maxs: F64, budget: F64) -> U16:
    """Timeline codes (R and G) coarsened within ``budget`` ((N, 2), value units)."""
    return coarsen(codes, to_codes(budget, mins, maxs))


def rms_room(order: int) -> float:
    """sqrt(2k + 1): the worst-case change of order ``k`` over what its root mean square over
    the lifespan may be (:func:`coarsen_motion`)."""
    return float(np.sqrt(2 * order + 1))


def coarsen_motion(
    codes: U16,
    mins: F64,
    maxs: F64,
    *,
    attr: str,
    order: int,
    orders: int,
    budgets: Budgets,
) -> U16:
    """Codes of order ``order`` of the motion of ``attr`` coarsened so that, over the
    Gaussian's own lifespan (``|t - t_ref| <= reach``), the change it makes to the attribute,
    times the temporal opacity factor g(t) of a type-2 Gaussian, has a root mean square within
    its share of :meth:`Budgets.change_over_lifespan`, split evenly over the ``orders`` (their
    sum's too, by Minkowski's inequality).

    An error d in the coefficient moves the attribute by d |t - t_ref|^k; :meth:`Budgets.
    motion_span` bounds that over d (a root mean square where the lifespan inside the scene
    holds t_ref, else the largest): either spends fewer bytes at equal PSNR than bounding the
    largest change everywhere or leaving out g (docs/design/chunk-codec.md)."""
    shared = attr != "means"  # rates of turn, scale, colour, opacity: mostly one value (zero)

    def tolerance(rows: slice) -> F64:  # a block's at a time, not every row's float64
        share = budgets.change_over_lifespan(attr, codes.shape[1], rows)
        share /= orders
        span = budgets.motion_span(order, rows)
        still = ~(span > 0)  # no time to move in: any coefficient will do
        share /= np.where(still, 1.0, span)[:, None]
        share[still] = np.inf
        return to_codes(share, mins, maxs)

    return coarsen(codes, tolerance, shared=shared)


__all__ = [
    "DEFAULT_QUALITY",
    "MAX_TURN",
    "QUALITY_MAX",
    "TURN_SURFACE",
    "Budgets",
    "Slacks",
    "budget_fraction",
    "check_quality",
    "coarsen",
    "coarsen_alpha",
    "coarsen_motion",
    "coarsen_positions",
    "coarsen_rotations",
    "coarsen_timeline",
    "faintness",
    "position_fraction",
    "rms_room",
    "stretch",
    "thin_labels",
]
