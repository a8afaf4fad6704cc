"""Seeded synthetic 4D scenes for tests, benchmarks and the demo: a static background (ground
disc and dome) plus blobs that appear, follow a polynomial path and disappear, in any timeline
type (type 0 repeats each live Gaussian once per frame, like a PLY sequence).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from .constants import SH_COEFFS_BY_BANDS, TEMPORAL_CHANNELS
from .errors import InputError
from .framing import look_at
from .model import Gaussians, Scene, Timeline, TimelineType
from .schemas.cameras import Camera
from .temporal import shifted_coefficients, visibility_half_width

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SceneSpec:
    """What to generate. Durations in seconds; counts are totals before per-frame repetition."""

    timeline_type: TimelineType = TimelineType.CENTER_SCALE
    background: int = 4000
    objects: int = 6
    per_object: int = 500
    duration: float = 4.0
    fps: float = 10.0
    sh_bands: int = 1
    motion_order: int = 2
    dynamic: tuple[str, ...] = ("means",)
    seed: int = 0
    size_spread: float = 0.0
    """Log-sigma of a size factor drawn per Gaussian (0: sizes vary smoothly in space only; 1.0
    skews sizes as real captures are, docs/benchmarks.md)."""

    def __post_init__(self) -> None:
        if self.sh_bands not in SH_COEFFS_BY_BANDS:
            raise InputError(f"sh_bands must be 0-3, got {self.sh_bands}", where="sh_bands")
        if not 1 <= self.motion_order <= 3:
            raise InputError(
                f"motion_order must be 1-3, got {self.motion_order}", where="motion_order"
            )
        unknown = set(self.dynamic) - set(TEMPORAL_CHANNELS)
        if unknown:
            raise InputError(f"unknown dynamic attributes {sorted(unknown)}", where="dynamic")
        if self.duration <= 0 or self.fps <= 0:
            raise InputError("duration and fps must be positive", where="duration")
        if not 0 <= self.size_spread <= 4:
            raise InputError(f"must be 0-4, got {self.size_spread}", where="size_spread")


def _static_attributes(rng: np.random.Generator, means: F64, sh_bands: int) -> Gaussians:
    """Plausible attributes: colours and sizes vary smoothly in space (as in trained scenes),
    plus noise; opacities are mostly high with a faint tail; rotations are random."""
    n = means.shape[0]
    k = SH_COEFFS_BY_BANDS[sh_bands]
    phase = rng.uniform(0, 2 * np.pi, 3)
    pattern = np.sin(means[:, [0, 1, 2]] * 1.3 + phase) + np.cos(means[:, [1, 2, 0]] * 0.7)
    sh0 = 0.8 * pattern + rng.normal(0, 0.1, (n, 3))
    scales = -3.8 + 0.4 * pattern[:, [2, 0, 1]] + rng.normal(0, 0.25, (n, 3))
    faint = rng.uniform(0, 1, n) < 0.25
    opacities = np.where(faint, rng.normal(-2.5, 1.0, n), rng.normal(3.0, 1.2, n))
    shn = 0.1 * pattern[:, None, :] / (1 + np.arange(k))[None, :, None] + rng.normal(
        0, 0.02, (n, k, 3)
    )
    return Gaussians.from_arrays(
        means=means,
        scales=scales,
        quats=rng.normal(0, 1, (n, 4)),
        opacities=opacities,
        sh0=sh0,
        shN=shn,
    )


def _background_positions(rng: np.random.Generator, n: int) -> F64:
    """Half the points on a ground disc, half on a dome of radius 6 around the origin."""
    ground = n // 2
    r = 6 * np.sqrt(rng.uniform(0, 1, ground))
    a = rng.uniform(0, 2 * np.pi, ground)
    disc = np.stack([r * np.cos(a), np.full(ground, -1.0), r * np.sin(a)], axis=1)
    dome = rng.normal(0, 1, (n - ground, 3))
    dome = 6 * dome / np.linalg.norm(dome, axis=1, keepdims=True)
    dome[:, 1] = np.abs(dome[:, 1]) - 1
    return np.concatenate([disc, dome]) + rng.normal(0, 0.02, (n, 3))


@dataclass(frozen=True)
class _Objects:
    """Moving objects: per object birth/death (s) and path; per point its object and rest offset."""

    birth: F64
    death: F64
    paths: F64
    owner: npt.NDArray[np.intp]
    points: F64


def _objects(rng: np.random.Generator, spec: SceneSpec) -> _Objects:
    """Objects with random lifespans, polynomial paths (objects, order, 3) and point blobs."""
    birth = rng.uniform(0, 0.6 * spec.duration, spec.objects)
    life = rng.uniform(0.3, 1.0, spec.objects) * (spec.duration - birth)
    scale = np.array([0.8, 0.3, 0.08])[: spec.motion_order]
    paths = rng.normal(0, 1, (spec.objects, spec.motion_order, 3)) * scale[None, :, None]
    owner = np.repeat(np.arange(spec.objects), spec.per_object)
    start = rng.uniform(-2, 2, (spec.objects, 3)) * [1, 0.3, 1] + [0, 0.5, 0]
    points = start[owner] + rng.normal(0, 0.25, (owner.size, 3))
    return _Objects(birth, birth + life, paths, owner, points)


def _dynamic_coefficients(
    rng: np.random.Generator, n: int, spec: SceneSpec, motion: F64 | None
) -> dict[str, npt.NDArray[np.float32]]:
    """Temporal coefficients: the object paths for means, small random drifts for the rest."""
    out: dict[str, npt.NDArray[np.float32]] = {}
    for attr in spec.dynamic:
        channels = TEMPORAL_CHANNELS[attr]
        if attr == "means" and motion is not None:
            out[attr] = motion.astype(np.float32)
        else:
            out[attr] = (rng.normal(0, 0.05, (n, spec.motion_order, channels))).astype(np.float32)
    return out


def generate_scene(spec: SceneSpec | None = None) -> Scene:
    """A seeded synthetic 4D scene; the same spec always gives the same arrays."""
    spec = spec or SceneSpec()
    scene = _generate(spec)
    if spec.size_spread == 0:
        return scene
    rng = np.random.default_rng([spec.seed, 1])  # its own stream: the rest is unchanged
    factor = rng.normal(-(spec.size_spread**2) / 2, spec.size_spread, len(scene))[:, None]
    g = replace(scene.gaussians, scales=(scene.gaussians.scales + factor).astype(np.float32))
    return replace(scene, gaussians=g)


def _generate(spec: SceneSpec) -> Scene:
    """The scene of ``spec`` with sizes varying smoothly in space only."""
    rng = np.random.default_rng(spec.seed)
    background = _background_positions(rng, spec.background)
    obj = _objects(rng, spec)
    if spec.timeline_type is TimelineType.FRAME:
        return _frame_scene(rng, spec, background, obj)
    owner, birth, death = obj.owner, obj.birth, obj.death
    means = np.concatenate([background, obj.points])
    g = _static_attributes(rng, means, spec.sh_bands)
    n_bg = spec.background
    motion = np.concatenate([np.zeros((n_bg, spec.motion_order, 3)), obj.paths[owner]])
    if spec.timeline_type is TimelineType.START_DURATION:
        frames = round(spec.duration * spec.fps)
        first = np.concatenate([np.zeros(n_bg), np.floor(birth[owner] * spec.fps)])
        count = np.concatenate([np.full(n_bg, frames), np.ceil((death - birth)[owner] * spec.fps)])
        timeline = Timeline(
            TimelineType.START_DURATION, first, count, fps=spec.fps, scene_length=spec.duration
        )
    else:
        centre = np.concatenate([np.full(n_bg, spec.duration / 2), ((birth + death) / 2)[owner]])
        sigma = np.concatenate([np.full(n_bg, spec.duration * 4), ((death - birth) / 5)[owner]])
        timeline = Timeline(TimelineType.CENTER_SCALE, centre, sigma, scene_length=spec.duration)
    return Scene(g, timeline, _dynamic_coefficients(rng, len(g), spec, motion))


def _frame_scene(
    rng: np.random.Generator, spec: SceneSpec, background: F64, obj: _Objects
) -> Scene:
    """Type 0: every frame repeats the background and the live objects at their path position."""
    frames = round(spec.duration * spec.fps)
    parts_means: list[F64] = []
    parts_frame: list[F64] = []
    parts_motion: list[F64] = []
    zeros = np.zeros((background.shape[0], spec.motion_order, 3))
    for f in range(frames):
        t = f / spec.fps
        live = (obj.birth[obj.owner] <= t) & (t < obj.death[obj.owner])
        live_paths = obj.paths[obj.owner[live]]
        dt = t - obj.birth[obj.owner[live]]
        parts_means += [background, obj.points[live] + _path(live_paths, dt)]
        parts_frame.append(np.full(background.shape[0] + int(live.sum()), float(f)))
        parts_motion += [zeros, shifted_coefficients(live_paths, dt)]
    means = np.concatenate(parts_means)
    g = _static_attributes(rng, means, spec.sh_bands)
    frame_ids = np.concatenate(parts_frame)
    zero = np.zeros_like(frame_ids)
    timeline = Timeline(
        TimelineType.FRAME, frame_ids, zero, fps=spec.fps, scene_length=spec.duration
    )
    motion = np.concatenate(parts_motion)
    return Scene(g, timeline, _dynamic_coefficients(rng, len(g), spec, motion))


def _path(coeffs: F64, dt: F64) -> F64:
    """Displacement sum_k c_k dt^k of paths (M, order, 3) after dt (M,) seconds."""
    powers = dt[:, None] ** np.arange(1, coeffs.shape[1] + 1)
    return np.asarray(np.einsum("mk,mkc->mc", powers, coeffs), np.float64)


def small_scene(
    kind: TimelineType,
    *,
    sh_bands: int = 1,
    motion_order: int = 2,
    seed: int = 0,
    dynamic: Iterable[str] = ("means",),
) -> Scene:
    """A few thousand Gaussians of the given timeline type, quick enough for unit tests."""
    spec = SceneSpec(
        timeline_type=kind,
        background=600,
        objects=4,
        per_object=150,
        duration=2.0,
        fps=5.0,
        sh_bands=sh_bands,
        motion_order=motion_order,
        dynamic=tuple(dynamic),
        seed=seed,
    )
    return generate_scene(spec)


def static_gaussians(n: int, *, sh_bands: int = 0, seed: int = 0) -> Gaussians:
    """``n`` static Gaussians with trained-looking statistics (for codec tests and benchmarks)."""
    if n < 0:
        raise InputError(f"n must be >= 0, got {n}", where="n")
    rng = np.random.default_rng(seed)
    clusters = rng.normal(0, 3, (max(1, n // 2000), 3))
    means = clusters[rng.integers(0, len(clusters), n)] + rng.normal(0, 0.4, (n, 3))
    g = _static_attributes(rng, means, sh_bands)
    decay = 1.0 / (1.0 + np.arange(g.shN.shape[1]))[None, :, None]  # higher bands are smaller
    return Gaussians.from_arrays(g.means, g.scales, g.quats, g.opacities, g.sh0, shN=g.shN * decay)


def freetime_scene(
    g: Gaussians,
    *,
    duration_s: float,
    lifespan: tuple[float, float],
    speed: float = 0.05,
    seed: int = 0,
) -> Scene:
    """A FreeTimeGS-style scene from any static Gaussians: each a random centre in [0,
    duration_s], a type-2 lifespan drawn from ``lifespan`` (fractions of the clip) and a linear
    velocity of up to ``speed`` scene extents per second."""
    lo, hi = lifespan
    if not (0 < lo <= hi) or duration_s <= 0:
        raise InputError(f"expected 0 < {lo} <= {hi} and a positive duration", where="lifespan")
    rng = np.random.default_rng(seed)
    n = len(g)
    visible = rng.uniform(lo, hi, n) * duration_s
    centre = rng.uniform(0.0, duration_s, n)
    scale = visible / (2 * visibility_half_width())
    finite = g.means[np.all(np.isfinite(g.means), axis=1)]
    extent = float(np.max(np.ptp(finite, axis=0))) if len(finite) else 1.0
    velocity = rng.normal(0.0, speed * extent / np.sqrt(3), (n, 1, 3))
    timeline = Timeline(TimelineType.CENTER_SCALE, centre, scale, scene_length=duration_s)
    return Scene(g, timeline, {"means": velocity.astype(np.float32)})


def rig_cameras(count: int = 8, width: int = 1280, height: int = 720) -> list[Camera]:
    """Capture cameras for a generated scene (+y up): a ring of ``count`` at radius 12, 4 units
    above the ground, looking at the scene's centre, as a capture rig would stand."""
    focal = 0.5 * height / math.tan(math.radians(25))  # 50 degrees vertically
    cameras = []
    for k in range(count):
        phi = 2 * math.pi * k / count
        eye = np.array([12 * math.sin(phi), 4.0, 12 * math.cos(phi)])
        c2w = look_at(eye, [0.0, 0.5, 0.0], [0.0, 1.0, 0.0])[:3, :3].T
        cameras.append(
            Camera(
                name=f"rig_{k:02d}",
                width=width,
                height=height,
                fx=focal,
                fy=focal,
                position=(float(eye[0]), float(eye[1]), float(eye[2])),
                rotation=tuple(tuple(float(v) for v in row) for row in c2w),
            )
        )
    return cameras
