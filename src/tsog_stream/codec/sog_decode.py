"""SOG v2 decoder: validated meta + decoded byte images -> static Gaussians in texel order.

Formulas follow splat-transform's reader so both decoders agree to float32 rounding:
opacity logits are clamped to alpha in [1e-6, 1 - 1e-6]; labels past the palette give zero SH;
an unknown quaternion tag gives the identity rotation.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from ..model import Gaussians
from ..opacity import alpha_to_logit
from .layout import from_image
from .positions import decode_means, join_u16
from .rotations import decode_quats

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]


def _lookup(codebook: list[float], indices: U8) -> F32:
    """Codebook values of byte indices."""
    return np.asarray(codebook, dtype=np.float32)[indices]


def _decode_sh(shn: Any, images: Mapping[str, U8], count: int) -> F32:
    """(N, K, 3) SH rest coefficients from the palette; labels past the palette give zeros."""
    coeffs = C.SH_COEFFS_BY_BANDS[int(shn.bands)]
    centroid_image = images[shn.files[0]]
    label_texels = from_image(images[shn.files[1]], count)
    labels = label_texels[:, 0].astype(np.intp) | (label_texels[:, 1].astype(np.intp) << 8)
    rows, width = centroid_image.shape[:2]
    entries = centroid_image.reshape(rows * (width // coeffs), coeffs, 4)[:, :, :3]
    values = _lookup(shn.codebook, entries)  # (palette, coefficient j, channel)
    valid = labels < min(int(shn.count), values.shape[0])
    out = np.zeros((count, coeffs, 3), np.float32)
    out[valid] = values[labels[valid]]
    return out


def decode_sog(meta: Any, images: Mapping[str, U8]) -> Gaussians:
    """Gaussians (in texel order) from a parsed ChunkMeta and its decoded images."""
    count = int(meta.count)
    low = from_image(images[meta.means.files[0]], count)[:, :3]
    high = from_image(images[meta.means.files[1]], count)[:, :3]
    means = decode_means(
        join_u16(low, high),
        np.asarray(meta.means.mins, np.float64),
        np.asarray(meta.means.maxs, np.float64),
    )
    quats = decode_quats(from_image(images[meta.quats.files[0]], count))
    scales = _lookup(meta.scales.codebook, from_image(images[meta.scales.files[0]], count)[:, :3])
    sh0_texels = from_image(images[meta.sh0.files[0]], count)
    sh0 = _lookup(meta.sh0.codebook, sh0_texels[:, :3])
    opacities = alpha_to_logit(sh0_texels[:, 3] / 255.0)
    shn = meta.shN
    rest = (
        _decode_sh(shn, images, count) if shn is not None else np.zeros((count, 0, 3), np.float32)
    )
    return Gaussians(means, scales, quats, opacities, sh0, rest)
