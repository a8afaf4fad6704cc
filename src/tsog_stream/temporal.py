"""Temporal evaluation: the static Gaussians of a 4D scene at time t (seconds).

Visibility (docs/spec.md, "Evaluation"):
- type 0: frame id == floor(t * fps) (fps 1 when absent);
- type 1: start <= t < start + duration (in timeline units);
- type 2: opacity times exp(-1/2 ((t - centre) / scale)^2), invisible under the threshold.
Dynamic attributes: base + sum_k c_k (t - t_ref)^k, t_ref = frame time / start / centre,
quaternions renormalised, scales in log space, opacity in logit space.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .constants import SCALE_CAP_SPANS, VISIBILITY_THRESHOLD
from .errors import InputError
from .model import Gaussians, Scene, Timeline, TimelineType

F64 = npt.NDArray[np.float64]
TIME_EPSILON = 1e-9
"""Tolerance (in timeline units) so t = k / fps lands in frame k despite float rounding."""


def visibility_half_width(threshold: float = VISIBILITY_THRESHOLD) -> float:
    """Half-width of a type-2 lifespan in scales: |t - c| <= s * sqrt(2 ln(1/threshold))."""
    if not 0 < threshold < 1:
        raise InputError(f"threshold must be in (0, 1), got {threshold}")
    return math.sqrt(2.0 * math.log(1.0 / threshold))


def reference_times(timeline: Timeline) -> F64:
    """t_ref of each Gaussian in seconds: frame time, start or centre."""
    return timeline.t0 * timeline.seconds_per_unit


def recentre(scene: Scene, t0: F64) -> None:
    """Move each Gaussian's reference time to ``t0`` (timeline units), keeping every path:
    each polynomial base + sum_k c_k (t - t_ref)^k re-expanded about the new t_ref (Taylor's
    shift, exact in float64). In place: the scene's timeline, moving base attributes and
    coefficients are replaced by new arrays (none is written, and nothing else is copied: an
    encoder's job drops its SH bands once read). The encoder stores the attributes about the
    reference time the decoder will read, so a rounded centre or start moves no Gaussian."""
    timeline = scene.timeline
    if timeline is None:
        return
    delta = (np.asarray(t0, np.float64) - timeline.t0) * timeline.seconds_per_unit
    scene.timeline = Timeline(timeline.type, t0, timeline.t1, timeline.fps, timeline.scene_length)
    if not delta.any():
        return
    g = scene.gaussians
    for attr, coeffs in list(scene.temporal.items()):
        base = g.opacities[:, None] if attr == "opacity" else getattr(g, attr)
        moved, scene.temporal[attr] = _shifted(base, coeffs, delta)
        if attr == "opacity":
            g.opacities = moved[:, 0]
        else:
            setattr(g, attr, moved)


def _shifted(
    base: npt.NDArray[np.float32], coeffs: npt.NDArray[np.float32], delta: F64
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(base, coefficients) of base + sum_k c_k (s + delta)^k as a polynomial in s:
    b' = b + sum_k c_k delta^k, c'_j = sum_{k>=j} C(k, j) c_k delta^(k-j). A row whose
    re-expansion leaves float32 (huge coefficients) keeps its own: its attribute then moves
    by the shift, as it did before the encoder re-expanded anything."""
    c = coeffs.astype(np.float64)
    d = delta[:, None]
    new_base = base.astype(np.float64)
    new_coeffs = np.zeros_like(c)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(1, coeffs.shape[1] + 1):
            new_base += c[:, k - 1] * d**k
            for j in range(1, k + 1):
                new_coeffs[:, j - 1] += math.comb(k, j) * c[:, k - 1] * d ** (k - j)
        shifted_base, shifted = new_base.astype(np.float32), new_coeffs.astype(np.float32)
    kept = ~(np.isfinite(shifted_base).all(axis=1) & np.isfinite(shifted).all(axis=(1, 2)))
    if kept.any():
        shifted_base[kept], shifted[kept] = base[kept], coeffs[kept]
    return shifted_base, shifted


def scale_cap(timeline: Timeline) -> float:
    """Largest type-2 scale worth storing: SCALE_CAP_SPANS times the scene's span.

    A larger scale changes the temporal opacity factor by less than 0.13 % anywhere in the
    scene, while an unbounded one (a float16 overflow in .splatv gives 65504) would stretch the
    linear 16-bit range so far that short lifespans lose all precision.
    """
    if timeline.scene_length:
        span = float(timeline.scene_length)
    elif len(timeline):
        span = float(timeline.t0.max() - timeline.t0.min())
    else:
        span = 0.0
    return SCALE_CAP_SPANS * max(span, 1e-3)


def lifespans(timeline: Timeline, threshold: float = VISIBILITY_THRESHOLD) -> tuple[F64, F64]:
    """(start, end) in seconds of each Gaussian's visible interval, end exclusive."""
    spu = timeline.seconds_per_unit
    if timeline.type is TimelineType.FRAME:
        return timeline.t0 * spu, (timeline.t0 + 1.0) * spu
    if timeline.type is TimelineType.START_DURATION:
        return timeline.t0 * spu, (timeline.t0 + timeline.t1) * spu
    half = timeline.t1 * visibility_half_width(threshold)
    return timeline.t0 - half, timeline.t0 + half


def time_range(timeline: Timeline, threshold: float = VISIBILITY_THRESHOLD) -> tuple[float, float]:
    """(first, last) second: [0, scene_length] if declared, else the hull of the lifespans."""
    if timeline.scene_length is not None:
        return 0.0, float(timeline.scene_length)
    if len(timeline) == 0:
        return 0.0, 0.0
    start, end = lifespans(timeline, threshold)
    return float(min(0.0, start.min())), float(end.max())


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


def _check_time(t: float) -> None:
    """Reject a time that is not a finite number of seconds."""
    if not math.isfinite(t):
        raise InputError(f"time must be a finite number of seconds, got {t}")


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


def _threshold(threshold: float | None) -> float:
    """The visibility threshold to use (the format default when None)."""
    return VISIBILITY_THRESHOLD if threshold is None else threshold


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
