"""SOG v2 decoder: validated meta + WebP images -> static Gaussians in texel order.

Formulas follow splat-transform's reader (agreeing to float32 rounding): alpha clamped to
[1e-6, 1 - 1e-6], labels past the palette give zero SH, an unknown quaternion tag the identity.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from ..model import Gaussians
from ..opacity import alpha_to_logit
from .layout import from_image
from .positions import decode_means
from .rotations import decode_quats
from .webp import ImageDecoder, in_two

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]


def _lookup(codebook: list[float], indices: U8) -> F32:
    """Codebook values (256 entries, by the schema) of byte indices, a gather per channel."""
    table = np.asarray(codebook, dtype=np.float32)
    out = np.empty(indices.shape, np.float32)
    for channel in range(indices.shape[-1]):
        np.take(table, indices[..., channel], out=out[..., channel])
    return out


_LOGIT_OF_BYTE = alpha_to_logit(np.arange(256) / 255.0)
"""The opacity logit of each stored alpha byte."""


def decode_sh(shn: Any, images: Mapping[str, U8], count: int) -> F32:
    """(N, K, 3) SH rest coefficients from the palette; labels past the palette give zeros."""
    coeffs = C.SH_COEFFS_BY_BANDS[int(shn.bands)]
    centroid_image = images[shn.files[0]]
    label_texels = from_image(images[shn.files[1]], count)
    labels = label_texels[:, 0].astype(np.intp) | (label_texels[:, 1].astype(np.intp) << 8)
    rows, width = centroid_image.shape[:2]
    entries = centroid_image.reshape(rows * (width // coeffs), coeffs, 4)
    usable = max(0, min(int(shn.count), entries.shape[0]))  # the schema says count >= 1
    # One gather over the palette's bytes, then whole rows by label, each in two halves on
    # both cores; mode="clip" writes straight into ``out`` (bytes < 256; labels checked).
    table = np.asarray(shn.codebook, dtype=np.float32)
    palette = entries[:usable, :, :3]
    values = np.empty(palette.shape, np.float32)
    in_two(usable, lambda a, b: np.take(table, palette[a:b], out=values[a:b], mode="clip"))
    valid = labels < usable
    if valid.all():
        out = np.empty((count, coeffs, 3), np.float32)
        in_two(
            count,
            lambda a, b: np.take(values, labels[a:b], axis=0, out=out[a:b], mode="clip"),
        )
        return out
    if usable == 0:
        return np.zeros((count, coeffs, 3), np.float32)
    out = np.take(values, np.where(valid, labels, 0), axis=0)
    out[~valid] = 0.0
    return out


def decode_sog(meta: Any, decoder: ImageDecoder) -> Callable[[], Gaussians]:
    """Schedule each attribute's decoding as its images arrive (costliest first); the function
    returned waits and gives the Gaussians (texel order) of a parsed ChunkMeta."""
    count = int(meta.count)
    shn = meta.shN
    rest = (
        decoder.then(shn.files, lambda images: decode_sh(shn, images, count))
        if shn is not None
        else None
    )
    quats = decoder.then(
        meta.quats.files,
        lambda images: decode_quats(from_image(images[meta.quats.files[0]], count)),
    )
    means = decoder.then(meta.means.files, lambda images: _means(meta.means, images, count))
    colours = decoder.then(meta.sh0.files, lambda images: _colours(meta.sh0, images, count))
    scales = decoder.then(
        meta.scales.files,
        lambda images: _lookup(
            meta.scales.codebook, from_image(images[meta.scales.files[0]], count)[:, :3]
        ),
    )

    def gaussians() -> Gaussians:
        sh0, opacities = colours.result()
        no_rest = np.zeros((count, 0, 3), np.float32)
        shn_values = rest.result() if rest is not None else no_rest
        return Gaussians(
            means.result(), scales.result(), quats.result(), opacities, sh0, shn_values
        )

    return gaussians


def _means(means: Any, images: Mapping[str, U8], count: int) -> F32:
    """Positions from the low/high byte images over the meta's log-space ranges."""
    low = from_image(images[means.files[0]], count)[:, :3]
    high = from_image(images[means.files[1]], count)[:, :3]
    ranges = np.asarray(means.mins, np.float64), np.asarray(means.maxs, np.float64)
    return decode_means(low, high, *ranges)


def _colours(sh0: Any, images: Mapping[str, U8], count: int) -> tuple[F32, F32]:
    """(f_dc colours, opacity logits) from the sh0 image: codebook RGB, alpha byte."""
    texels = from_image(images[sh0.files[0]], count)
    return _lookup(sh0.codebook, texels[:, :3]), np.take(_LOGIT_OF_BYTE, texels[:, 3])
