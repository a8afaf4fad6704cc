"""Where a viewer starts: camera geometry, the scene's up axis and a floater-proof framing.

Pure numerics over :class:`~tsog_stream.schemas.cameras.Camera` values. A scene opens
from its first capture camera; without one, from a camera framing the *dense core*: the
opacity-weighted median of the centres and a weighted percentile of their distances, so a
few floaters far away do not push the camera out of the room (docs/design/player.md, "The
first view").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from .errors import InputError
from .model import Gaussians
from .opacity import logit_to_alpha
from .schemas.cameras import Camera, HeaderCamera

F64 = npt.NDArray[np.float64]
DEFAULT_UP: tuple[float, float, float] = (0.0, -1.0, 0.0)
"""The up axis of a scene without cameras: COLMAP's y-down world, which trained captures keep."""
CORE_QUANTILE = 0.8
"""Share of the opacity-weighted Gaussians the framing fits into the view."""
FRAMING_FOV_DEG = 50.0
"""Vertical field of view of a framing camera."""
FRAMING_ELEVATION_DEG = 20.0
"""How far above the horizon a framing camera looks down on the core."""
FRAMING_SIZE = (1280, 720)
"""Image size recorded for a framing camera (only the aspect and focal length matter)."""
MARGIN = 1.1
MIN_COVERAGE = 0.5
"""A header camera that sees less of the scene than this (opacity-weighted) is not its view;
nor is a capture camera, unless it looks at the dense core (:func:`looks_at_core`)."""
CORE_IN_MIDDLE = 0.25
"""A camera looks at the dense core when the core's centre projects at most this share of
the image's sides from its middle..."""
CORE_DISTANCE = (0.1, 10.0)
"""...and lies in front of it between these many core radii."""
FRAMING_NAME = "framing"
"""The ``name`` of a framing camera (capture cameras carry their image names)."""
FRAMING_SAMPLE = 1 << 20
"""Gaussians the view of a bigger scene is measured on, every k-th (a median of 2^20 is as
good a centre, in far less time)."""


def rotation(camera: Camera) -> F64:
    """The camera-to-world rotation as a (3, 3) array (columns: right, down, forward)."""
    return np.array(camera.rotation, dtype=np.float64)


def world_to_camera(camera: Camera) -> F64:
    """The (4, 4) world-to-camera matrix of a capture camera."""
    r = rotation(camera)
    w2c = np.eye(4)
    w2c[:3, :3] = r.T
    w2c[:3, 3] = -r.T @ np.array(camera.position, dtype=np.float64)
    return w2c


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike) -> F64:
    """World-to-camera matrix of a camera at ``eye`` looking at ``target`` (y down, z forward)."""
    eye_v = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye_v
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise InputError("the camera position equals its target")
    forward /= norm
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise InputError("the view direction is parallel to the up vector")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([right, down, forward])
    w2c[:3, 3] = -w2c[:3, :3] @ eye_v
    return w2c


def scene_up(cameras: Sequence[Camera]) -> F64:
    """The up axis: the mean of the cameras' -y axes when they agree on one, else DEFAULT_UP."""
    if cameras:
        ups = -np.array([c.rotation for c in cameras], dtype=np.float64)[:, :, 1]
        mean = ups.mean(axis=0)  # negated first: the mean of -0.0s is +0.0
        norm = float(np.linalg.norm(mean))
        if norm > 1e-6:
            return np.asarray(mean / norm, np.float64)
    return np.array(DEFAULT_UP, dtype=np.float64)


def weighted_quantile(values: F64, weights: F64, q: float) -> float:
    """The ``q`` quantile of ``values`` where each counts ``weights`` times."""
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    at = int(np.searchsorted(cumulative, q * cumulative[-1]))
    return float(values[order[min(at, len(order) - 1)]])


def weighted_centres(gaussians: Gaussians) -> tuple[F64, F64]:
    """The finite centres of the Gaussians with some opacity, and their opacities (alpha) as
    weights: what framing and coverage count."""
    means = gaussians.means.astype(np.float64)
    alpha = logit_to_alpha(gaussians.opacities)
    keep = np.all(np.isfinite(means), axis=1) & np.isfinite(alpha) & (alpha > 0)
    return means[keep], alpha[keep]


def framing_sample(gaussians: Gaussians, at_most: int | None = None) -> Gaussians:
    """``gaussians``, or every k-th when there are more than ``at_most`` (FRAMING_SAMPLE)."""
    step = -(-len(gaussians) // (FRAMING_SAMPLE if at_most is None else at_most))
    return gaussians if step <= 1 else gaussians.subset(np.arange(0, len(gaussians), step))


def dense_core(gaussians: Gaussians) -> tuple[F64, float]:
    """Centre and radius of the dense core: the opacity-weighted median of the finite centres
    per axis, and the distance within which :data:`CORE_QUANTILE` of the weight lies."""
    means, weights = weighted_centres(gaussians)
    if len(means) == 0:
        raise InputError("cannot frame a scene without a visible Gaussian")
    centre = np.array([weighted_quantile(means[:, k], weights, 0.5) for k in range(3)])
    distances = np.linalg.norm(means - centre, axis=1)
    radius = max(weighted_quantile(distances, weights, CORE_QUANTILE), 1e-6)
    return centre, radius


def _horizontal(up: F64) -> F64:
    """A unit direction perpendicular to ``up`` (the framing's viewing side)."""
    axis = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    side = axis - up * float(axis @ up)
    return side / np.linalg.norm(side)


Core = tuple[F64, float]
"""(centre, radius) of a dense core, as :func:`dense_core` gives it."""


def framing_camera(gaussians: Gaussians, up: npt.ArrayLike, core: Core | None = None) -> Camera:
    """A camera looking down on the dense core (``core``, else measured) from
    FRAMING_ELEVATION_DEG, its sphere filling the view with a 10 % margin."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    centre, radius = core if core is not None else dense_core(gaussians)
    distance = MARGIN * radius / math.sin(math.radians(FRAMING_FOV_DEG) / 2)
    elevation = math.radians(FRAMING_ELEVATION_DEG)
    back = math.cos(elevation) * -_horizontal(u) + math.sin(elevation) * u
    eye = centre + distance * back
    w2c = look_at(eye, centre, u)
    width, height = FRAMING_SIZE
    focal = 0.5 * height / math.tan(math.radians(FRAMING_FOV_DEG) / 2)
    return Camera(
        name=FRAMING_NAME,
        width=width,
        height=height,
        fx=focal,
        fy=focal,
        position=vec3(eye),
        rotation=_rows(w2c[:3, :3].T),
    )


def coverage(gaussians: Gaussians, camera: Camera) -> float:
    """The share of the scene's opacity-weighted Gaussians whose centres ``camera`` sees (in
    front of it and inside its image)."""
    means, weights = weighted_centres(gaussians)
    if len(means) == 0:
        return 0.0
    x, y, depth = _pixels(camera, means)
    seen = (depth > 0) & (x >= 0) & (x < camera.width) & (y >= 0) & (y < camera.height)
    return float((weights * seen).sum() / weights.sum())


def _pixels(camera: Camera, points: F64) -> tuple[F64, F64, F64]:
    """Where world ``points`` (N, 3) land in ``camera``'s image (x, y in pixels) and their
    depth along its view (behind it: depth <= 0, x and y meaningless)."""
    w2c = world_to_camera(camera)
    local = points @ w2c[:3, :3].T + w2c[:3, 3]
    depth = local[:, 2]
    cx, cy = camera.principal_point
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = camera.fx * local[:, 0] / depth + cx
        y = camera.fy * local[:, 1] / depth + cy
    return x, y, depth


def looks_at_core(camera: Camera, core: Core) -> bool:
    """True when the dense core's centre lies in front of ``camera`` at CORE_DISTANCE and
    projects near its image's middle (CORE_IN_MIDDLE): a camera aimed at the subject."""
    centre, radius = core
    x, y, depth = (float(v[0]) for v in _pixels(camera, np.asarray(centre).reshape(1, 3)))
    near, far = CORE_DISTANCE
    if not near * radius <= depth <= far * radius:
        return False
    return (
        abs(x / camera.width - 0.5) <= CORE_IN_MIDDLE
        and abs(y / camera.height - 0.5) <= CORE_IN_MIDDLE
    )


def opening_view(
    gaussians: Gaussians, cameras: Sequence[Camera], core: Core | None = None
) -> tuple[Camera, str]:
    """Where a viewer opens the scene, and why: the first camera when it sees at least
    MIN_COVERAGE of the scene, or when it is a capture camera (a format's
    :class:`HeaderCamera` may be another scene's) that looks at the dense core; else a framing
    of the core."""
    if not cameras:
        return framing_camera(gaussians, scene_up(cameras), core), "no capture cameras"
    first = cameras[0]
    seen = coverage(gaussians, first)
    if seen >= MIN_COVERAGE:
        return first, f"capture camera 0 sees {seen:.0%} of the scene"
    core = core if core is not None else dense_core(gaussians)
    why = f"capture camera 0 sees only {seen:.0%} of the scene"
    if not isinstance(first, HeaderCamera):
        if looks_at_core(first, core):
            aimed = f"capture camera 0 looks at the dense core (sees {seen:.0%} of the scene)"
            return first, aimed
        why += " and is not aimed at its dense core"
    return framing_camera(gaussians, scene_up(cameras), core), why


def default_view(gaussians: Gaussians, cameras: Sequence[Camera]) -> Camera | None:
    """Where a viewer opens the scene (:func:`opening_view`); None with nothing to frame."""
    try:
        return opening_view(gaussians, cameras)[0]
    except InputError:
        return None


def vec3(v: F64) -> tuple[float, float, float]:
    """A length-3 array as plain floats (for schemas and JSON)."""
    return float(v[0]), float(v[1]), float(v[2])


def _rows(m: F64) -> tuple[tuple[float, float, float], ...]:
    return tuple(vec3(row) for row in m)
