"""SOG v2 encoder: static Gaussians -> per-Gaussian byte images + the SOG part of meta.json.

Images are returned as raw (H, W, 4) arrays; :mod:`tsog_stream.codec.chunk` encodes them to
WebP in parallel. Where splat-transform truncates a float to a byte we round (half the error).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from ..columns import row_blocks
from ..model import Gaussians
from ..opacity import logit_to_alpha
from ..quantize import assign_codebook, build_codebook, short_codebook
from ..sh_palette import fit_palette, palette_size
from .budgets import Budgets, Slacks
from .coarsen import coarsen_alpha, coarsen_positions, coarsen_rotations, thin_labels
from .layout import texels, to_image
from .positions import encode_means, split_u16
from .rotations import encode_quats
from .webp import ImageEncoder

U8 = npt.NDArray[np.uint8]
Progress = Callable[[str], None]
FractionDone = Callable[[float], None]


def _floats(values: npt.ArrayLike) -> list[float]:
    """JSON-ready list of float32 values, each the shortest decimal that reads back as the
    same float32 (0.1, not 0.10000000149011612): codebooks take half the bytes, exactly."""
    out = []
    for v in np.asarray(values, dtype=np.float32).reshape(-1):
        short = float(str(v))
        out.append(short if np.float32(short) == v else float(v))
    return out


def opacity_bytes(logits: npt.NDArray[np.float32]) -> U8:
    """Alpha byte = round(sigmoid(logit) * 255), clamped; +inf -> 255, -inf -> 0."""
    alpha = logit_to_alpha(logits)
    return np.clip(np.rint(alpha * 255.0), 0, 255).astype(np.uint8)


def _codebook_texels(
    columns: npt.NDArray[np.float32],
    alpha: npt.ArrayLike = 255,
    slack: float = 0.0,
    weights: npt.ArrayLike | None = None,
) -> tuple[U8, list[float]]:
    """One shared 256-entry codebook over (N, 3) columns (entries short to write, see
    short_codebook), fitted to ``weights`` when given (one per value); texels of the
    per-column indices, moved to fewer distinct entries within ``slack`` (codec/coarsen.py)."""
    codebook = short_codebook(build_codebook(columns, weights))
    labels = assign_codebook(columns, codebook).reshape(columns.shape)
    labels, codebook = thin_labels(labels, codebook, slack)
    return texels(labels[:, 0], labels[:, 1], labels[:, 2], alpha=alpha), _floats(codebook)


def scale_importance(gaussians: Gaussians) -> npt.NDArray[np.float64]:
    """(N, 3) weights of the scale codebook's fit: each Gaussian's alpha times the square
    root of its footprint's area (its two largest sigmas), on all three of its axes: a
    label's error shows in proportion to opacity and size (docs/design/quantizers.md)."""
    alpha = logit_to_alpha(gaussians.opacities).reshape(-1)
    logs = np.sort(gaussians.scales.astype(np.float64), axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        weight = alpha * np.exp(0.5 * (logs[:, 1] + logs[:, 2]))
    return np.broadcast_to(weight[:, None], gaussians.scales.shape)


def _vectors_for_fit(gaussians: Gaussians) -> npt.NDArray[np.float32]:
    """(N, 3K) f_rest vectors in PLY order (channel-major: all R coefficients, then G, then
    B), the vectors the palette is fitted on."""
    n, k, _ = gaussians.shN.shape
    return np.ascontiguousarray(gaussians.shN.transpose(0, 2, 1).reshape(n, 3 * k))


def encode_sh_palette(
    gaussians: Gaussians,
    width: int,
    height: int,
    seed: int,
    note: Progress,
    *,
    on_palette: FractionDone | None = None,
    slack: float = 0.0,
) -> tuple[dict[str, U8], dict[str, Any]]:
    """Palette (k-means on f_rest), its codebook, the centroid image and the label image;
    ``on_palette`` hears the fitting's fraction done (most of an SH chunk's encoding).
    ``slack``: the view-dependent colour error the palette may add (Slacks.bands)."""
    coeffs, bands = gaussians.shN.shape[1], gaussians.sh_bands

    def fitted(fraction: float) -> None:
        note(f"SH palette {100 * fraction:3.0f}%")
        if on_palette is not None:
            on_palette(fraction)

    centroids, labels = fit_palette(
        _vectors_for_fit(gaussians),
        palette_size(len(gaussians)),
        seed=seed,
        progress=fitted,
        slack=slack,
    )
    count = centroids.shape[0]
    codebook = short_codebook(build_codebook(centroids))
    cbytes = assign_codebook(centroids, codebook).reshape(count, 3, coeffs)
    rows = -(-count // C.SH_CENTROIDS_PER_ROW)
    cells = np.zeros((rows * C.SH_CENTROIDS_PER_ROW, coeffs, 4), np.uint8)
    cells[:count, :, :3] = cbytes.transpose(0, 2, 1)  # (palette entry, coefficient j, channel)
    cells[:count, :, 3] = 255
    centroid_image = cells.reshape(rows, C.SH_CENTROIDS_PER_ROW * coeffs, 4)
    labels = labels.astype(np.uint32)
    label_texels = texels(labels & 0xFF, labels >> 8, np.zeros_like(labels, np.uint8))
    images = {
        C.SHN_CENTROIDS: centroid_image,
        C.SHN_LABELS: to_image(label_texels, width, height),
    }
    meta = {
        "count": int(count),
        "bands": bands,
        "codebook": _floats(codebook),
        "files": [C.SHN_CENTROIDS, C.SHN_LABELS],
    }
    return images, meta


def encode_geometry(
    gaussians: Gaussians, width: int, height: int, images: ImageEncoder, budgets: Budgets | None
) -> dict[str, Any]:
    """Positions and rotations of Gaussians already in texel order: their images handed to
    ``images``, their SOG keys of meta.json returned; with ``budgets`` they keep only the bits
    they need. Made a block of rows at a time."""
    mins, maxs, codes = encode_means(gaussians.means)
    quats = np.empty((len(gaussians), 4), np.uint8)
    limits = (budgets.base_position(), budgets.rotation) if budgets is not None else None
    for rows in row_blocks(len(gaussians), 8 * 4):  # a quaternion or a position in float64
        quats[rows] = encode_quats(gaussians.quats[rows])
        if limits is not None:
            means = gaussians.means[rows].astype(np.float64)
            codes[rows] = coarsen_positions(codes[rows], mins, maxs, means, limits[0][rows])
            quats[rows] = coarsen_rotations(quats[rows], limits[1][rows])
    low, high = split_u16(codes)
    images.add(
        {
            C.MEANS_L: to_image(texels(low[:, 0], low[:, 1], low[:, 2]), width, height),
            C.MEANS_U: to_image(texels(high[:, 0], high[:, 1], high[:, 2]), width, height),
            C.QUATS: to_image(quats, width, height),
        }
    )
    return {
        "means": {"mins": _floats(mins), "maxs": _floats(maxs), "files": [C.MEANS_L, C.MEANS_U]},
        "quats": {"files": [C.QUATS]},
    }


def encode_appearance(
    gaussians: Gaussians,
    width: int,
    height: int,
    images: ImageEncoder,
    *,
    seed: int = 0,
    progress: Progress | None = None,
    slacks: Slacks | None = None,
    on_palette: FractionDone | None = None,
) -> dict[str, Any]:
    """Scales, colours, opacities and SH bands of Gaussians already in texel order: their
    images handed to ``images``, their SOG keys of meta.json returned; with ``slacks`` labels
    and opacity bytes move within them. The SH palette is fitted last."""
    note = progress or (lambda _msg: None)
    note("scale codebook")
    scale_texels, scale_codebook = _codebook_texels(
        gaussians.scales,
        slack=slacks.scale if slacks is not None else 0.0,
        weights=scale_importance(gaussians),
    )
    images.add({C.SCALES: to_image(scale_texels, width, height)})
    del scale_texels  # not held through the fit
    note("colour codebook")
    alpha = opacity_bytes(gaussians.opacities)
    if slacks is not None:
        alpha = coarsen_alpha(alpha, slacks.alpha)
    colour_slack = slacks.colour if slacks is not None else 0.0
    sh0_texels, sh0_codebook = _codebook_texels(gaussians.sh0, alpha, colour_slack)
    images.add({C.SH0: to_image(sh0_texels, width, height)})
    del sh0_texels, alpha
    meta: dict[str, Any] = {
        "scales": {"codebook": scale_codebook, "files": [C.SCALES]},
        "sh0": {"codebook": sh0_codebook, "files": [C.SH0]},
    }
    if gaussians.sh_bands > 0 and len(gaussians) > 0:
        note("SH palette")
        sh_images, meta["shN"] = encode_sh_palette(
            gaussians,
            width,
            height,
            seed,
            note,
            on_palette=on_palette,
            slack=slacks.bands if slacks is not None else 0.0,
        )
        images.add(sh_images)
    return meta
