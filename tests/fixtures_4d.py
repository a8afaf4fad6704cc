"""Seeded 4D inputs with known ground truth: FreeTimeGS PLY / npz, hand-built splatv bytes.

Every generator is deterministic (numpy ``default_rng(seed)``). :class:`FreeTimeTruth` holds the
values *as stored* (float32 where the file is float32) and :func:`freetime_expected` evaluates
the FreeTimeGS equations independently of tsog-stream's temporal code:

    position(t) = mean + v (t_n - mu_t),  alpha(t) = sigmoid(o) exp(-1/2 ((t_n - mu_t) / sigma)^2)

with t_n = t / scene_length, visible iff the temporal factor >= 1/255.
"""

from __future__ import annotations

import io
import json
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tsog_stream.constants import VISIBILITY_THRESHOLD
from tsog_stream.io.ply import ply_bytes
from tsog_stream.io.splatv import MAGIC, RECORD
from tsog_stream.model import Gaussians

F64 = npt.NDArray[np.float64]
EDGE = math.sqrt(2.0 * math.log(255.0))
"""Half-width of a type-2 lifespan in sigmas at the 1/255 threshold."""


@dataclass(frozen=True)
class FreeTimeTruth:
    """Base Gaussians (at their centre time), centres, log sigmas and velocities (normalised)."""

    gaussians: Gaussians
    times: npt.NDArray[np.float32]
    log_sigma: npt.NDArray[np.float32]
    velocity: npt.NDArray[np.float32]

    @property
    def sigma(self) -> F64:
        """sigma in normalised time, from the stored log value."""
        return np.exp(self.log_sigma.astype(np.float64))


def freetime_truth(n: int = 48, seed: int = 7, sh_bands: int = 1) -> FreeTimeTruth:
    """Random FreeTimeGS Gaussians; a few have sigma under the 0.02 checkpoint floor."""
    rng = np.random.default_rng(seed)
    k = {0: 0, 1: 3, 2: 8, 3: 15}[sh_bands]
    f32 = np.float32
    gaussians = Gaussians.from_arrays(
        rng.uniform(-2, 2, (n, 3)).astype(f32),
        rng.uniform(-5, -1, (n, 3)).astype(f32),
        rng.normal(size=(n, 4)).astype(f32),
        rng.uniform(-2, 4, n).astype(f32),
        rng.normal(size=(n, 3)).astype(f32),
        shN=rng.normal(scale=0.1, size=(n, k, 3)).astype(f32),
    )
    times = rng.uniform(-0.1, 1.1, n).astype(f32)
    times[0] = 0.5  # Gaussian 0 is used to probe the visibility edge
    log_sigma = np.log(rng.uniform(0.01, 0.3, n)).astype(f32)
    log_sigma[0] = math.log(0.05)
    log_sigma[1] = math.log(0.005)  # below FreeTimeGsVanilla's MIN_DURATION
    velocity = rng.normal(scale=0.8, size=(n, 3)).astype(f32)
    return FreeTimeTruth(gaussians, times, log_sigma, velocity)


def freetime_expected(
    truth: FreeTimeTruth,
    t: float,
    scene_length: float,
    *,
    min_sigma: float = 0.0,
    use_velocity: bool = True,
) -> tuple[npt.NDArray[np.bool_], F64, F64]:
    """(visible mask, means (M, 3), alphas (M,)) of the visible Gaussians at ``t`` seconds."""
    t_n = t / scene_length
    sigma = np.maximum(truth.sigma, min_sigma)
    dt = t_n - truth.times.astype(np.float64)
    factor = np.exp(-0.5 * (dt / sigma) ** 2)
    visible = factor >= VISIBILITY_THRESHOLD
    means = truth.gaussians.means.astype(np.float64)
    if use_velocity:
        means = means + truth.velocity.astype(np.float64) * dt[:, None]
    alpha = factor / (1.0 + np.exp(-truth.gaussians.opacities.astype(np.float64)))
    return visible, means[visible], alpha[visible]


def edge_times(truth: FreeTimeTruth, scene_length: float, rel: float = 1e-4) -> list[float]:
    """Seconds just inside and just outside both visibility edges of Gaussian 0."""
    c, s = float(truth.times[0]), float(truth.sigma[0])
    return [
        (c + sign * s * EDGE * (1.0 + slack)) * scene_length
        for sign in (-1.0, 1.0)
        for slack in (-rel, rel)
    ]


def freetime_ply(
    truth: FreeTimeTruth,
    *,
    time_name: str = "time",
    duration_name: str = "log_duration",
    velocity_names: Sequence[str] = ("velocity_0", "velocity_1", "velocity_2"),
    linear: bool = False,
    comments: Sequence[str] = (),
    more: dict[str, npt.NDArray[np.float32]] | None = None,
) -> bytes:
    """A FreeTimeGS-style PLY: 3DGS layout plus time, duration and velocity properties."""
    duration = np.exp(truth.log_sigma.astype(np.float64)) if linear else truth.log_sigma
    extra: dict[str, npt.ArrayLike] = {time_name: truth.times, duration_name: duration}
    extra.update({n: truth.velocity[:, i] for i, n in enumerate(velocity_names)})
    extra.update(more or {})
    data = ply_bytes(truth.gaussians, extra)
    head = b"format binary_little_endian 1.0\n"
    lines = b"".join(f"comment {c}\n".encode() for c in comments)
    return data.replace(head, head + lines, 1)


def freetime_npz(truth: FreeTimeTruth, **overrides: npt.ArrayLike | None) -> bytes:
    """A FreeTimeGsVanilla checkpoint's splats as an ``.npz`` (an override of None drops a key)."""
    g, n = truth.gaussians, len(truth.gaussians)
    arrays: dict[str, npt.ArrayLike | None] = {
        "means": g.means,
        "scales": g.scales,
        "quats": g.quats,
        "opacities": g.opacities,
        "sh0": g.sh0.reshape(n, 1, 3),
        "shN": g.shN,
        "times": truth.times.reshape(n, 1),
        "durations": truth.log_sigma.reshape(n, 1),
        "velocities": truth.velocity,
    }
    arrays.update(overrides)
    buffer = io.BytesIO()
    named: dict[str, Any] = {k: np.asarray(v) for k, v in arrays.items() if v is not None}
    np.savez(buffer, **named)
    return buffer.getvalue()


def splatv_records(n: int) -> npt.NDArray[np.void]:
    """``n`` zeroed splatv records to fill in."""
    return np.zeros(n, RECORD)


def splatv_bytes(
    records: npt.NDArray[np.void],
    *,
    chunks: list[dict[str, object]] | None = None,
    slots: int | None = None,
) -> bytes:
    """A .splatv file: magic, JSON chunk list, the records as the ``splat`` chunk body."""
    size = (slots if slots is not None else len(records)) * RECORD.itemsize
    header = chunks if chunks is not None else [{"type": "splat", "size": size, "texwidth": 4096}]
    text = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<II", MAGIC, len(text)) + text + records.tobytes()
