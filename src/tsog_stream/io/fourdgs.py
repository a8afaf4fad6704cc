""".4dgs files (the 4dgs container of Avala AI) <-> Scene, through the optional ``fourdgs`` package.

Reading gives type 2 (centre = mu_t, scale = sigma_t, velocity = order-1 ``means``), or type 1
(the windows, exact) when no Gaussian fades; writing maps type 2 directly and types 0/1 to
windows of never-fading Gaussians, refusing motion beyond linear unless ``lossy=True``. The
model and what is lost each way: docs/inputs.md, "`.4dgs`", and the returned notes.
``fourdgs`` is imported on first use; its exceptions become :mod:`tsog_stream.errors` here."""

from __future__ import annotations

import importlib
import io
import os
from pathlib import Path
from types import ModuleType
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from .._version import __version__
from ..constants import GENERATOR, SH_BANDS_BY_COEFFS, SH_C0, VISIBILITY_THRESHOLD
from ..errors import FormatError, InputError, UnsupportedError
from ..model import Gaussians, Scene, Timeline, TimelineType
from ..opacity import alpha_to_logit, logit_to_alpha
from ..temporal import time_range, visibility_half_width
from .files import atomic_write_bytes, read_bytes
from .loaded import Loaded4D

F64 = npt.NDArray[np.float64]

MAGIC_PREFIX: Final = b"\x894DGS"
"""First five bytes of every .4dgs file; byte 5 is the major version, then CR LF."""
PROFILES: Final = ("fine", "default", "coarse")
"""fourdgs quantisation profiles (error bounds scale with the scene's median Gaussian size)."""
SH_RANGE: Final = (-4.0, 4.0)
"""SH coefficient = lo + byte (hi - lo) / 255 (4dgs spec section 6.5)."""
NEVER_FADES_SIGMAS: Final = 16.0
"""A never-fading Gaussian read into type 2 gets scale = this x its distance to the far end of
the scene: exp(-1/2 / 16^2) > 1 - 1/510, so its opacity stays within half an 8-bit step."""
INSTALL_HINT: Final = "pip install tsog-stream[4dgs]"


def sniff_4dgs(head: bytes | memoryview) -> bool:
    """True when ``head`` starts with the .4dgs magic (any major version)."""
    return bytes(head[:5]) == MAGIC_PREFIX and bytes(head[6:8]) == b"\r\n"


def _fourdgs() -> ModuleType:
    """The ``fourdgs`` package, or UnsupportedError saying how to install it."""
    try:
        return importlib.import_module("fourdgs")
    except ImportError as exc:
        raise UnsupportedError(
            f".4dgs support needs the optional fourdgs package: {INSTALL_HINT}"
        ) from exc


# --- reading ---------------------------------------------------------------------------------


def read_4dgs(source: str | os.PathLike[str] | bytes) -> Loaded4D:
    """Read a .4dgs file (path or bytes) as a Scene; notes say what the mapping changed."""
    if isinstance(source, bytes | bytearray | memoryview):
        return parse_4dgs(bytes(source))
    return parse_4dgs(read_bytes(source), name=os.fspath(source))


def parse_4dgs(data: bytes, *, name: str = "<bytes>") -> Loaded4D:
    """Decode .4dgs bytes (sans-I/O): type 2, or type 1 when no Gaussian fades."""
    fd = _fourdgs()
    try:
        decoded = fd.read(data, recover_truncated=False)
    except (fd.UnsupportedVersion, fd.UnsupportedCodec) as exc:
        raise UnsupportedError(str(exc), where=name) from exc
    except (fd.FourdgsError, ValueError, OverflowError, EOFError) as exc:
        raise FormatError(f"not a readable .4dgs file: {exc}", where=name) from exc
    if decoded.objects.tracks:
        raise UnsupportedError(
            f"{len(decoded.objects.tracks)} object tracks move Gaussians along keyframed rigid "
            "poses, which TSOG's polynomial motion cannot hold",
            where=name,
        )
    notes = _ignored_records(decoded)
    gs = decoded.gaussians
    duration = float(decoded.duration_sec)
    g = _gaussians(gs)
    motion = np.asarray(gs.motions, np.float64)
    never = ~np.isfinite(np.asarray(gs.sigma_t, np.float64))
    if len(g) and never.all():
        g, timeline = _start_duration(gs, g, motion, duration, notes)
    else:
        timeline = _centre_scale(gs, duration, float(decoded.header.cutoff), notes)
    temporal = {"means": motion[:, None, :].astype(np.float32)} if np.any(motion) else {}
    scene = Scene(g, timeline, temporal)
    order = _source_order(gs.source_index, len(scene))
    return Loaded4D(scene if order is None else scene.subset(order), notes)


def _gaussians(gs: Any) -> Gaussians:
    """Static attributes in the 3DGS PLY domain (log scales, wxyz, logits, f_dc, f_rest)."""
    colors = np.asarray(gs.colors, np.float64)
    return Gaussians.from_arrays(
        means=np.asarray(gs.positions, np.float64),
        scales=np.log(np.maximum(np.asarray(gs.scales, np.float64), 1e-30)),
        quats=np.asarray(gs.rotations, np.float64)[:, [3, 0, 1, 2]],
        opacities=alpha_to_logit(colors[:, 3]),
        sh0=(colors[:, :3] - 0.5) / SH_C0,
        shN=_sh_from_bytes(gs.sh, len(colors)),
    )


def _sh_from_bytes(sh: Any, n: int) -> npt.NDArray[np.float32]:
    """(N, K, 3) coefficients from 4dgs's (N, 3K) channel-major bytes (zero bands if absent)."""
    if sh is None:
        return np.zeros((n, 0, 3), np.float32)
    raw = np.asarray(sh, np.float64)
    k = raw.shape[1] // 3
    if k not in SH_BANDS_BY_COEFFS or raw.shape != (n, 3 * k):
        raise FormatError(f"SH bytes of shape {raw.shape} do not fit {n} Gaussians")
    lo, hi = SH_RANGE
    values = lo + raw * ((hi - lo) / 255.0)
    return values.reshape(n, 3, k).transpose(0, 2, 1).astype(np.float32)


def _start_duration(
    gs: Any, g: Gaussians, motion: F64, duration: float, notes: list[str]
) -> tuple[Gaussians, Timeline]:
    """Type 1 for files whose Gaussians never fade: the window is the lifespan (exact)."""
    lo, hi = np.asarray(gs.win_lo, np.float64), np.asarray(gs.win_hi, np.float64)
    start, end = np.clip(lo, 0.0, duration), np.clip(hi, 0.0, duration)
    outside = int(np.count_nonzero((lo < 0.0) | (hi > duration)))
    if outside:
        notes.append(
            f"{outside} validity windows reach beyond the scene's [0, {duration:g}] s and were "
            "clipped to it (type-1 lifespans are finite)"
        )
    mu = np.asarray(gs.mu_t, np.float64)
    means = g.means + motion * (start - mu)[:, None]  # t_ref moves from mu_t to the start
    based = Gaussians.from_arrays(means, g.scales, g.quats, g.opacities, g.sh0, shN=g.shN)
    lifespan = np.maximum(end - start, 0.0)
    return based, Timeline(TimelineType.START_DURATION, start, lifespan, scene_length=duration)


def _centre_scale(gs: Any, duration: float, cutoff: float, notes: list[str]) -> Timeline:
    """Type 2 (centre = mu_t, scale = sigma_t), noting windows and cutoffs it cannot hold."""
    mu = np.asarray(gs.mu_t, np.float64)
    sigma = np.asarray(gs.sigma_t, np.float64)
    never = ~np.isfinite(sigma)
    far = np.maximum(np.abs(mu), np.abs(duration - mu))
    scale = np.where(never, NEVER_FADES_SIGMAS * np.maximum(far, 1e-3), sigma)
    if never.any():
        notes.append(
            f"{int(never.sum())} Gaussians never fade (sigma_t = inf): given a scale of "
            f"{NEVER_FADES_SIGMAS:g}x their distance to the far end of the scene"
        )
    half = scale * visibility_half_width()
    lo, hi = np.asarray(gs.win_lo, np.float64), np.asarray(gs.win_hi, np.float64)
    cut = (lo > np.maximum(mu - half, 0.0)) | (hi < np.minimum(mu + half, duration))
    if cut.any():
        notes.append(
            f"{int(cut.sum())} Gaussians have a validity window that cuts their fade; type 2 "
            "has no hard window, so they fade in and out beyond [win_lo, win_hi)"
        )
    if abs(cutoff - VISIBILITY_THRESHOLD) > 1e-9:
        notes.append(
            f"the file hides Gaussians whose temporal factor is under {cutoff:g}; TSOG's "
            f"threshold is 1/255, so they fade out further (Scene.at(t, threshold={cutoff:g}) "
            "matches the file)"
        )
    return Timeline(TimelineType.CENTER_SCALE, mu, scale, scene_length=duration)


def _ignored_records(decoded: Any) -> list[str]:
    """Notes naming what the file carried that a Scene does not hold."""
    found = {
        "audio sources": len(decoded.audio_sources),
        "camera trajectory": int(decoded.camera is not None),
        "provenance records": int(bool(decoded.provenance)),
        "metadata records": len(decoded.metadata),
        "attachments": len(decoded.attachments),
        "unknown records": len(decoded.skipped_opcodes),
        "object table": int(decoded.objects.table is not None),
        "object ids": int(decoded.gaussians.object_id is not None),
    }
    notes = (
        [f"ignored: {', '.join(k for k, v in found.items() if v)}"] if any(found.values()) else []
    )
    if decoded.summary_crc_ok is False:
        notes.append("the summary (chunk index) CRC does not match; the chunks were read anyway")
    return notes


def _source_order(source_index: Any, n: int) -> npt.NDArray[np.intp] | None:
    """The permutation restoring the writer's input order, when the file stores one."""
    if source_index is None:
        return None
    index = np.asarray(source_index, np.int64)
    if index.shape != (n,) or not np.array_equal(np.sort(index), np.arange(n)):
        return None
    return np.argsort(index).astype(np.intp)


# --- writing ---------------------------------------------------------------------------------


def write_4dgs(
    path: str | os.PathLike[str],
    scene: Scene,
    *,
    profile: str = "default",
    duration: float | None = None,
    keep_order: bool = False,
    lossy: bool = False,
) -> list[str]:
    """Write ``scene`` as .4dgs atomically; returns notes on what the format could not hold."""
    data, notes = encode_4dgs(
        scene, profile=profile, duration=duration, keep_order=keep_order, lossy=lossy
    )
    atomic_write_bytes(Path(path), data)
    return notes


def encode_4dgs(
    scene: Scene,
    *,
    profile: str = "default",
    duration: float | None = None,
    keep_order: bool = False,
    lossy: bool = False,
) -> tuple[bytes, list[str]]:
    """The .4dgs bytes of ``scene`` and notes on what was lost (sans-I/O).

    ``profile`` picks fourdgs's error bounds; ``duration`` (seconds) overrides the scene
    length (required for a static scene); ``keep_order`` stores each Gaussian's index so
    :func:`read_4dgs` restores the input order; ``lossy`` drops temporal coefficients 4dgs
    cannot hold instead of refusing the scene.
    """
    fd = _fourdgs()
    if profile not in PROFILES:
        raise InputError(
            f"unknown profile {profile!r}; known: {', '.join(PROFILES)}", where="profile"
        )
    notes: list[str] = []
    motion = _linear_motion(scene, lossy=lossy, notes=notes)
    span = _duration(scene, duration)
    mu, sigma, win_lo, win_hi = _times(scene, notes)
    mu_grid = _on_mu_grid(fd, mu, sigma, profile)
    g = scene.gaussians
    positions = g.means.astype(np.float64) + motion * (mu_grid - mu)[:, None]
    sh, degree = _sh_to_bytes(g.shN, notes)
    gaussians = fd.GaussianSet(
        positions=positions.astype(np.float32),
        scales=np.exp(g.scales.astype(np.float64)).astype(np.float32),
        rotations=_rotations(g.quats, notes),
        colors=_colors(g, notes),
        motions=motion.astype(np.float32),
        mu_t=mu_grid.astype(np.float32),
        sigma_t=sigma.astype(np.float32),
        win_lo=win_lo,
        win_hi=win_hi,
        sh=sh,
        sh_degree=degree,
    )
    options = fd.WriteOptions(
        profile=profile,
        cutoff=VISIBILITY_THRESHOLD,
        library=f"{GENERATOR} {__version__}",
        preserve_source_ids=keep_order,
    )
    buffer = io.BytesIO()
    try:
        fd.write(buffer, gaussians, span, options=options)
    except (fd.FourdgsError, ValueError) as exc:
        raise InputError(f"fourdgs cannot write this scene: {exc}", where=".4dgs") from exc
    return buffer.getvalue(), notes


def _linear_motion(scene: Scene, *, lossy: bool, notes: list[str]) -> F64:
    """Per-Gaussian velocity (N, 3); refuse (or, if lossy, drop) what 4dgs cannot hold."""
    motion = np.zeros((len(scene), 3))
    problems = []
    for attr, coeffs in scene.temporal.items():
        if attr == "means":
            motion = coeffs[:, 0].astype(np.float64)
            if coeffs.shape[1] > 1 and np.any(coeffs[:, 1:]):
                problems.append(
                    f"order-{coeffs.shape[1]} motion of means beyond order 1 "
                    "(4dgs moves Gaussians linearly)"
                )
        elif np.any(coeffs):
            problems.append(f"temporal {attr} coefficients (4dgs animates positions only)")
    if problems and not lossy:
        raise InputError(
            f"cannot be written to .4dgs without loss: {'; '.join(problems)}; "
            "pass lossy=True to drop them",
            where="temporal",
        )
    notes.extend(f"dropped {p}" for p in problems)
    return motion


def _duration(scene: Scene, duration: float | None) -> float:
    """The file's duration in seconds: given, the scene length, or the end of the lifespans."""
    if duration is None and scene.timeline is not None:
        duration = time_range(scene.timeline)[1]
    if duration is None:
        raise InputError("a static scene needs duration= (a .4dgs file has one)", where="duration")
    if not (np.isfinite(duration) and duration > 0):
        raise InputError(
            f"duration must be a positive number of seconds, got {duration}", where="duration"
        )
    return float(duration)


def _times(scene: Scene, notes: list[str]) -> tuple[F64, F64, F64, F64]:
    """(mu_t, sigma_t, win_lo, win_hi) in seconds; mu_t is also the motion's reference time."""
    n, tl = len(scene), scene.timeline
    always = np.full(n, -np.inf), np.full(n, np.inf)
    if tl is None:
        notes.append("static scene written as Gaussians that never fade")
        return np.zeros(n), np.full(n, np.inf), *always
    if tl.type is TimelineType.CENTER_SCALE:
        return tl.t0.copy(), tl.t1.copy(), *always
    spu = tl.seconds_per_unit
    length = np.ones(n) if tl.type is TimelineType.FRAME else tl.t1
    start, end = tl.t0 * spu, (tl.t0 + length) * spu
    fps = f"; fps {tl.fps:g} is not kept" if tl.fps else ""
    notes.append(
        f"timeline type {int(tl.type)} written as never-fading Gaussians with validity windows "
        f"in seconds; 4dgs has no frames, so it reads back as type 1{fps}"
    )
    return start, np.full(n, np.inf), start, end


def _on_mu_grid(fd: ModuleType, mu: F64, sigma: F64, profile: str) -> F64:
    """mu_t moved onto the grid fourdgs will quantise it to, so only the fade centre moves.

    Positions are re-based to the moved time, which keeps every trajectory exact; the grid
    pitch is fourdgs's own (time step, refined to 5% of the Gaussian's quantised sigma).
    """
    steps = fd.Steps.of(fd.Bounds.for_profile(profile))
    never = ~np.isfinite(sigma)
    safe = np.where(never, 1.0, sigma).astype(np.float32).astype(np.float64)  # as stored
    q_sigma = np.rint(np.log(np.maximum(safe, 1e-30)) / steps.sigma_log)
    q_sigma[never] = 0
    pitch = np.asarray(
        fd.quantization.mu_steps(q_sigma, steps.sigma_log, never, steps.time), np.float64
    )
    snapped = np.rint(mu / pitch) * pitch
    return snapped.astype(np.float32).astype(np.float64)


def _rotations(quats: npt.NDArray[np.float32], notes: list[str]) -> npt.NDArray[np.float32]:
    """(x, y, z, w) rotations; zero quaternions become the identity (noted)."""
    xyzw = quats[:, [1, 2, 3, 0]].astype(np.float32)
    zero = ~np.any(xyzw, axis=1)
    if zero.any():
        xyzw[zero] = (0.0, 0.0, 0.0, 1.0)
        notes.append(f"{int(zero.sum())} zero quaternions written as the identity rotation")
    return xyzw


def _colors(g: Gaussians, notes: list[str]) -> npt.NDArray[np.float32]:
    """RGBA: rgb = 0.5 + SH_C0 f_dc clipped to [0, 1] (what 4dgs holds), alpha = sigmoid."""
    rgb = 0.5 + SH_C0 * g.sh0.astype(np.float64)
    outside = int(np.count_nonzero((rgb < 0.0) | (rgb > 1.0)))
    if outside:
        notes.append(f"{outside} colour values outside [0, 1] clipped (4dgs stores colour)")
    alpha = logit_to_alpha(g.opacities)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), alpha[:, None]], axis=1).astype(np.float32)


def _sh_to_bytes(
    shn: npt.NDArray[np.float32], notes: list[str]
) -> tuple[npt.NDArray[np.uint8] | None, int]:
    """4dgs SH bytes (N, 3K), channel-major, and the degree; values outside [-4, 4] clip."""
    n, k = shn.shape[0], shn.shape[1]
    if k == 0:
        return None, 0
    lo, hi = SH_RANGE
    flat = shn.transpose(0, 2, 1).reshape(n, 3 * k).astype(np.float64)
    outside = int(np.count_nonzero((flat < lo) | (flat > hi)))
    if outside:
        notes.append(f"{outside} SH coefficients outside [{lo:g}, {hi:g}] clipped")
    codes = np.clip(np.rint((flat - lo) * (255.0 / (hi - lo))), 0, 255).astype(np.uint8)
    return codes, SH_BANDS_BY_COEFFS[k]


__all__ = [
    "MAGIC_PREFIX",
    "PROFILES",
    "encode_4dgs",
    "parse_4dgs",
    "read_4dgs",
    "sniff_4dgs",
    "write_4dgs",
]
