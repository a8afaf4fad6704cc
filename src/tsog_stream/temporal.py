"""Lifespans: when each Gaussian of a 4D scene is visible, and moving the time each Gaussian's
motion is stored about (:func:`recentre`). Evaluating a scene at t is the model's."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .constants import SCALE_CAP_SPANS, VISIBILITY_THRESHOLD
from .errors import InputError
from .model import Scene, Timeline, TimelineType

F64 = npt.NDArray[np.float64]


def visibility_half_width(threshold: float = VISIBILITY_THRESHOLD) -> float:
    """Half-width of a type-2 lifespan in scales: |t - c| <= s * sqrt(2 ln(1/threshold))."""
    if not 0 < threshold < 1:
        raise InputError(f"threshold must be in (0, 1), got {threshold}")
    return math.sqrt(2.0 * math.log(1.0 / threshold))


def recentre(scene: Scene, t0: F64) -> None:
    """Move each Gaussian's reference time to ``t0`` (timeline units), keeping every path (each
    polynomial re-expanded about the new time), so a rounded centre or start moves no
    Gaussian. The scene's timeline, moving attributes and coefficients are replaced by new
    arrays; none is written."""
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
    """(base, coefficients) of base + sum_k c_k (s + delta)^k as a polynomial in s; a row whose
    re-expansion leaves float32 keeps its own (its attribute then moves by the shift)."""
    c = coeffs.astype(np.float64)
    d = delta[:, None]
    new_base = base.astype(np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(1, coeffs.shape[1] + 1):
            new_base += c[:, k - 1] * d**k
        new_coeffs = shifted_coefficients(c, delta)
        shifted_base, shifted = new_base.astype(np.float32), new_coeffs.astype(np.float32)
    kept = ~(np.isfinite(shifted_base).all(axis=1) & np.isfinite(shifted).all(axis=(1, 2)))
    if kept.any():
        shifted_base[kept], shifted[kept] = base[kept], coeffs[kept]
    return shifted_base, shifted


def shifted_coefficients(coeffs: F64, delta: F64) -> F64:
    """c'_j = sum_{k>=j} C(k, j) c_k delta^(k-j): the (M, K, C) coefficients of
    sum_k c_k (s + delta)^k as a polynomial in s, per row's ``delta`` (M,)."""
    d = delta[:, None]
    out = np.zeros_like(coeffs)
    for k in range(1, coeffs.shape[1] + 1):
        for j in range(1, k + 1):
            out[:, j - 1] += math.comb(k, j) * coeffs[:, k - 1] * d ** (k - j)
    return out


def scale_cap(timeline: Timeline) -> float:
    """Largest type-2 scale worth storing: SCALE_CAP_SPANS times the scene's span (a larger one
    changes the opacity factor by < 0.13 %, and would cost short lifespans their precision)."""
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
