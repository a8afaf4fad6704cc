"""In-memory model: static Gaussians (struct of arrays) and the 4D extension (timeline + temporal).

Time convention (docs/spec.md, "Time"): every public API takes and returns time in **seconds**.
A :class:`Timeline` stores its values in *timeline units*: frames when ``fps`` is set (types 0
and 1), seconds otherwise. Readers convert their source's unit once, on input.

A scene at time t (:meth:`Scene.at`, :func:`evaluate_at`; docs/spec.md, "Evaluation"):
- type 0: frame id == floor(t * fps) (fps 1 when absent);
- type 1: start <= t < start + duration (in timeline units);
- type 2: opacity times exp(-1/2 ((t - centre) / scale)^2), invisible under the threshold.
Dynamic attributes: base + sum_k c_k (t - t_ref)^k, t_ref = frame time / start / centre,
quaternions renormalised, scales in log space, opacity in logit space.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import TypeVar, cast

import numpy as np
import numpy.typing as npt

from .constants import (
    SH_BANDS_BY_COEFFS,
    SH_COEFFS_BY_BANDS,
    TEMPORAL_CHANNELS,
    VISIBILITY_THRESHOLD,
)
from .errors import InputError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Index = npt.NDArray[np.intp] | npt.NDArray[np.bool_]
A = TypeVar("A", bound=np.ndarray)


def rows(values: A, index: Index) -> A:
    """``values[index]`` along the first axis. Integer indexes go through ``np.take``, faster
    than fancy indexing on wide rows."""
    if np.asarray(index).dtype == np.bool_:
        return cast(A, values[index])
    return cast(A, np.take(values, index, axis=0))


def _as_f32(name: str, value: npt.ArrayLike, shape_tail: tuple[int, ...]) -> F32:
    """Coerce ``value`` to a C-contiguous float32 array of shape (N, *shape_tail) or raise."""
    arr = np.ascontiguousarray(value, dtype=np.float32)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(N" + "".join(f", {d}" for d in shape_tail) + ")"
        raise InputError(f"expected shape {want}, got {arr.shape}", where=name)
    return arr


@dataclass(eq=False)
class Gaussians:
    """Static 3D Gaussians in the 3DGS PLY domain, one row per Gaussian.

    ``scales`` are natural-log sigmas, ``quats`` are (w, x, y, z) and need not be unit length,
    ``opacities`` are logits, ``sh0`` are f_dc values, ``shN`` is (N, K, 3) with K in
    {0, 3, 8, 15}: ``shN[i, k, c]`` is PLY ``f_rest_{c*K + k}``.
    """

    means: F32
    scales: F32
    quats: F32
    opacities: F32
    sh0: F32
    shN: F32 = field(default_factory=lambda: np.zeros((0, 0, 3), np.float32))

    def __post_init__(self) -> None:
        self.means = _as_f32("means", self.means, (3,))
        n = self.means.shape[0]
        self.scales = _as_f32("scales", self.scales, (3,))
        self.quats = _as_f32("quats", self.quats, (4,))
        self.opacities = np.ascontiguousarray(self.opacities, dtype=np.float32).reshape(-1)
        self.sh0 = _as_f32("sh0", self.sh0, (3,))
        shn = np.ascontiguousarray(self.shN, dtype=np.float32)
        if shn.size == 0 and (shn.ndim != 3 or n > 0):
            shn = np.zeros((n, 0, 3), np.float32)  # no SH bands, whatever empty shape was given
        if shn.ndim != 3 or shn.shape[2] != 3 or shn.shape[1] not in SH_BANDS_BY_COEFFS:
            raise InputError(
                f"expected shape (N, K, 3) with K in 0/3/8/15, got {shn.shape}", where="shN"
            )
        self.shN = shn
        for name in ("scales", "quats", "opacities", "sh0", "shN"):
            got = getattr(self, name).shape[0]
            if got != n:
                raise InputError(f"has {got} rows but means has {n}", where=name)

    @classmethod
    def from_arrays(
        cls,
        means: npt.ArrayLike,
        scales: npt.ArrayLike,
        quats: npt.ArrayLike,
        opacities: npt.ArrayLike,
        sh0: npt.ArrayLike,
        *,
        shN: npt.ArrayLike | None = None,
    ) -> Gaussians:
        """Build from any array-likes (any float dtype); shapes are checked, data made float32."""

        def f32(a: npt.ArrayLike) -> F32:
            return np.ascontiguousarray(a, dtype=np.float32)

        rest = np.zeros((0, 0, 3), np.float32) if shN is None else f32(shN)
        return cls(f32(means), f32(scales), f32(quats), f32(opacities), f32(sh0), rest)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_bands(self) -> int:
        """Number of SH bands beyond DC (0-3)."""
        return SH_BANDS_BY_COEFFS[self.shN.shape[1]]

    def subset(self, index: Index) -> Gaussians:
        """The Gaussians selected by an integer or boolean index, in that order."""
        return Gaussians(
            rows(self.means, index),
            rows(self.scales, index),
            rows(self.quats, index),
            rows(self.opacities, index),
            rows(self.sh0, index),
            rows(self.shN, index),
        )

    @staticmethod
    def concat(parts: Sequence[Gaussians], *, sh_bands: int | None = None) -> Gaussians:
        """All Gaussians of ``parts`` in order; parts with fewer SH bands are zero-padded."""
        bands = max((p.sh_bands for p in parts), default=0) if sh_bands is None else sh_bands
        if not parts:
            return Gaussians.empty(bands)
        k = SH_COEFFS_BY_BANDS[bands]

        def rest(g: Gaussians) -> F32:
            out = np.zeros((len(g), k, 3), np.float32)
            n = min(k, g.shN.shape[1])
            out[:, :n] = g.shN[:, :n]
            return out

        return Gaussians(
            np.concatenate([p.means for p in parts]),
            np.concatenate([p.scales for p in parts]),
            np.concatenate([p.quats for p in parts]),
            np.concatenate([p.opacities for p in parts]),
            np.concatenate([p.sh0 for p in parts]),
            np.concatenate([rest(p) for p in parts]),
        )

    @staticmethod
    def empty(sh_bands: int = 0) -> Gaussians:
        """A scene with no Gaussians (and ``sh_bands`` bands, so concatenation stays typed)."""
        k = SH_COEFFS_BY_BANDS[sh_bands]
        z = np.zeros
        return Gaussians.from_arrays(
            z((0, 3)), z((0, 3)), z((0, 4)), z(0), z((0, 3)), shN=z((0, k, 3))
        )


class TimelineType(IntEnum):
    """The ``timeline.type`` values of TSOG (paper section 3.2); values are the stored numbers."""

    FRAME = 0
    """R = frame id: the Gaussian exists in that frame only."""
    START_DURATION = 1
    """R = start, G = duration: visible for start <= t < start + duration."""
    CENTER_SCALE = 2
    """R = centre, G = scale: opacity times exp(-1/2 ((t - centre) / scale)^2)."""


@dataclass(eq=False)
class Timeline:
    """Per-Gaussian lifespans in timeline units (frames if ``fps`` is set for types 0/1, else s).

    ``t0`` is frame id / start / centre, ``t1`` duration / scale (zeros for type 0).
    ``scene_length`` (seconds) is optional; when absent it is derived from the lifespans.
    """

    type: TimelineType
    t0: npt.NDArray[np.float64]
    t1: npt.NDArray[np.float64]
    fps: float | None = None
    scene_length: float | None = None

    def __post_init__(self) -> None:
        self.type = TimelineType(self.type)
        self.t0 = np.ascontiguousarray(self.t0, dtype=np.float64).reshape(-1)
        self.t1 = np.ascontiguousarray(self.t1, dtype=np.float64).reshape(-1)
        if self.t1.shape != self.t0.shape:
            raise InputError(
                f"t1 has {self.t1.shape[0]} rows, t0 has {self.t0.shape[0]}", where="timeline"
            )
        if self.fps is not None and not (np.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"fps must be a positive number, got {self.fps}", where="timeline.fps")
        if self.fps is not None and self.type is TimelineType.CENTER_SCALE:
            raise InputError("fps applies to timeline types 0 and 1 only", where="timeline.fps")
        if not (np.all(np.isfinite(self.t0)) and np.all(np.isfinite(self.t1))):
            raise InputError("timeline values must be finite", where="timeline")
        if self.type is TimelineType.CENTER_SCALE and np.any(self.t1 <= 0):
            raise InputError("type-2 scales must be positive", where="timeline.scale")
        if self.type is TimelineType.START_DURATION and np.any(self.t1 < 0):
            raise InputError("type-1 durations must not be negative", where="timeline.duration")

    def __len__(self) -> int:
        return int(self.t0.shape[0])

    @property
    def seconds_per_unit(self) -> float:
        """Seconds in one timeline unit: 1/fps when frames are the unit, else 1."""
        return 1.0 / self.fps if self.fps else 1.0

    def subset(self, index: Index) -> Timeline:
        """The lifespans selected by ``index``."""
        t0, t1 = rows(self.t0, index), rows(self.t1, index)
        return Timeline(self.type, t0, t1, self.fps, self.scene_length)


@dataclass(eq=False)
class Scene:
    """A (possibly dynamic) scene: base Gaussians, optional timeline and temporal coefficients.

    ``temporal[attr]`` is (N, order, channels) float32 for the attributes of
    :data:`~tsog_stream.constants.TEMPORAL_CHANNELS`; coefficient k (1-based) multiplies
    ``(t - t_ref)**k`` with t in seconds, so its unit is attribute-unit per second**k.
    ``t_ref`` is the frame time (type 0), the start (type 1) or the centre (type 2).
    """

    gaussians: Gaussians
    timeline: Timeline | None = None
    temporal: dict[str, F32] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.gaussians)
        if self.timeline is not None and len(self.timeline) != n:
            raise InputError(
                f"timeline has {len(self.timeline)} rows, scene has {n}", where="timeline"
            )
        if self.temporal and self.timeline is None:
            raise InputError(
                "temporal coefficients need a timeline (their reference time)", where="temporal"
            )
        for attr, coeffs in list(self.temporal.items()):
            if attr not in TEMPORAL_CHANNELS:
                raise InputError(f"unknown dynamic attribute {attr!r}", where="temporal")
            arr = np.ascontiguousarray(coeffs, dtype=np.float32)
            channels = TEMPORAL_CHANNELS[attr]
            if arr.ndim != 3 or arr.shape[0] != n or arr.shape[2] != channels or arr.shape[1] < 1:
                raise InputError(
                    f"expected shape ({n}, order>=1, {channels}), got {arr.shape}",
                    where=f"temporal.{attr}",
                )
            self.temporal[attr] = arr

    def __len__(self) -> int:
        return len(self.gaussians)

    def subset(self, index: Index) -> Scene:
        """The Gaussians selected by ``index``, with their lifespans and coefficients."""
        timeline = self.timeline.subset(index) if self.timeline is not None else None
        temporal = {k: rows(v, index) for k, v in self.temporal.items()}
        return Scene(self.gaussians.subset(index), timeline, temporal)

    def arrays(self) -> list[np.ndarray]:
        """Every per-Gaussian array of the scene (one row per Gaussian)."""
        g = self.gaussians
        out: list[np.ndarray] = [g.means, g.scales, g.quats, g.opacities, g.sh0, g.shN]
        if self.timeline is not None:
            out += [self.timeline.t0, self.timeline.t1]
        return out + list(self.temporal.values())

    def at(self, t: float, threshold: float | None = None) -> Gaussians:
        """The static Gaussians visible at time ``t`` (seconds): :func:`evaluate_at`."""
        return evaluate_at(self, t, threshold)


# --- a scene at time t (docs/spec.md, "Evaluation") ----------------------------------------

TIME_EPSILON = 1e-9
"""Tolerance (in timeline units) so t = k / fps lands in frame k despite float rounding."""


def reference_times(timeline: Timeline) -> F64:
    """t_ref of each Gaussian in seconds: frame time, start or centre."""
    return timeline.t0 * timeline.seconds_per_unit


def _check_time(t: float) -> None:
    """Reject a time that is not a finite number of seconds."""
    if not math.isfinite(t):
        raise InputError(f"time must be a finite number of seconds, got {t}")


def _threshold(threshold: float | None) -> float:
    """The visibility threshold to use (the format default when None)."""
    return VISIBILITY_THRESHOLD if threshold is None else threshold


def _visible(
    timeline: Timeline, t: float, threshold: float
) -> tuple[npt.NDArray[np.bool_], F64 | None]:
    """Mask of Gaussians alive at t, and for type 2 their temporal opacity factor."""
    units = t / timeline.seconds_per_unit
    if timeline.type is TimelineType.FRAME:
        frame = math.floor(units + TIME_EPSILON)
        return np.rint(timeline.t0) == frame, None
    if timeline.type is TimelineType.START_DURATION:
        start, duration = timeline.t0, timeline.t1
        return (start <= units + TIME_EPSILON) & (units + TIME_EPSILON < start + duration), None
    factor = np.exp(-0.5 * ((t - timeline.t0) / timeline.t1) ** 2)
    return factor >= threshold, factor


def _polynomial(coeffs: npt.NDArray[np.float32], dt: F64) -> F64:
    """sum_k c_k dt^k for coefficients (N, order, C) and offsets (N,)."""
    powers = dt[:, None] ** np.arange(1, coeffs.shape[1] + 1)  # (N, order)
    return np.asarray(np.einsum("nk,nkc->nc", powers, coeffs.astype(np.float64)), np.float64)


def evaluate_at(scene: Scene, t: float, threshold: float | None = None) -> Gaussians:
    """Static Gaussians visible at time ``t`` (seconds), attributes evaluated at t."""
    _check_time(t)
    if scene.timeline is None:
        return scene.gaussians
    mask, factor = _visible(scene.timeline, t, _threshold(threshold))
    return _evaluate(scene, scene.timeline, t, mask, None if factor is None else factor[mask])


def shown_at(scene: Scene, t: float, threshold: float | None = None) -> npt.NDArray[np.bool_]:
    """Which Gaussians :func:`evaluate_at` gives at ``t`` (it gives them in row order), without
    evaluating them."""
    _check_time(t)
    if scene.timeline is None:
        return np.ones(len(scene), bool)
    return _visible(scene.timeline, t, _threshold(threshold))[0]


def count_at(scene: Scene, t: float, threshold: float | None = None) -> int:
    """How many Gaussians :func:`evaluate_at` gives at ``t``, without evaluating them."""
    return int(np.count_nonzero(shown_at(scene, t, threshold)))


def evaluate_all(
    scene: Scene, t: float, threshold: float | None = None
) -> tuple[Gaussians, npt.NDArray[np.bool_]]:
    """Every Gaussian evaluated at ``t`` (index-aligned with the scene) and the visibility mask.

    Used to compare two encodings of one scene Gaussian by Gaussian, even where quantisation
    moved a lifespan edge across t.
    """
    _check_time(t)
    if scene.timeline is None:
        return scene.gaussians, np.ones(len(scene), bool)
    mask, factor = _visible(scene.timeline, t, _threshold(threshold))
    return _evaluate(scene, scene.timeline, t, np.ones(len(scene), bool), factor), mask


def opacity_at(scene: Scene, t: float, threshold: float | None = None) -> npt.NDArray[np.float32]:
    """Every Gaussian's opacity logit at ``t``, index-aligned with the scene and -inf where it
    is not visible: what :func:`evaluate_at` gives the visible ones, evaluating nothing else
    (a caller that keeps only the most opaque evaluates only those)."""
    _check_time(t)
    if scene.timeline is None:
        return scene.gaussians.opacities
    mask, factor = _visible(scene.timeline, t, _threshold(threshold))
    index = np.flatnonzero(mask)
    dt = t - reference_times(scene.timeline)[index]
    out = np.full(len(scene), -np.inf, np.float32)
    out[index] = _opacity(scene, index, dt, None if factor is None else factor[index])
    return out


def _evaluate(
    scene: Scene, timeline: Timeline, t: float, index: npt.NDArray[np.bool_], factor: F64 | None
) -> Gaussians:
    """Attributes of the selected Gaussians at t; ``factor`` is their type-2 opacity factor."""
    g = scene.gaussians.subset(index)
    dt = t - reference_times(timeline)[index]
    attrs = {
        "means": g.means.astype(np.float64),
        "scales": g.scales.astype(np.float64),
        "quats": g.quats.astype(np.float64),
        "sh0": g.sh0.astype(np.float64),
    }
    for attr, coeffs in scene.temporal.items():
        if attr in attrs:
            attrs[attr] = attrs[attr] + _polynomial(coeffs[index], dt)
    quats = attrs["quats"]
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    quats = np.divide(quats, norm, out=np.tile([1.0, 0, 0, 0], (len(quats), 1)), where=norm > 0)
    opacity = _opacity(scene, index, dt, factor)
    return Gaussians.from_arrays(
        attrs["means"], attrs["scales"], quats, opacity, attrs["sh0"], shN=g.shN
    )


def _opacity(
    scene: Scene, index: npt.NDArray[np.bool_] | npt.NDArray[np.intp], dt: F64, factor: F64 | None
) -> F64:
    """Opacity logits at t of the selected Gaussians (``dt``: t minus their reference times)."""
    logits = scene.gaussians.opacities[index].astype(np.float64)
    coeffs = scene.temporal.get("opacity")
    if coeffs is not None:
        logits = logits + _polynomial(coeffs[index], dt)[:, 0]
    return logits if factor is None else _scale_opacity(logits, factor)


def _scale_opacity(logits: F64, factor: F64) -> F64:
    """logit(sigmoid(logits) * factor), computed stably."""
    with np.errstate(over="ignore", divide="ignore"):
        alpha = factor / (1.0 + np.exp(-logits))
        return np.log(alpha) - np.log1p(-np.minimum(alpha, 1.0 - 1e-12))
