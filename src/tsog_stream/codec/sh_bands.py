"""SH-band chunks: a chunk's bands beyond DC stored as a chunk of their own.

A layered stream's base holds DC colour only, so its first picture waits for no SH; its bands
go in an SH-band chunk of the next layer: the host's ``shN`` palette and labels in the host's
texel order, which a reader adds to the host's Gaussians (docs/spec.md, "SH-band chunks").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from .. import constants as C
from .._version import __version__
from ..errors import InputError, IntegrityError, SogError
from ..model import Scene
from ..schemas import ShBandsMeta, dump_sh_meta, parse_sh_meta
from .budgets import QUALITY_MAX, Slacks, budget_fraction
from .bundle import read_bundle
from .chunk import checked_images, is_identity, texel_order
from .layout import image_size
from .sog_decode import decode_sh
from .sog_encode import FractionDone, encode_sh_palette
from .webp import ImageDecoder, encode_many

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class ShBands:
    """The decoded bands beyond DC of a host chunk's Gaussians, (N, K, 3) in its texel order."""

    shN: F32

    def __len__(self) -> int:
        return int(self.shN.shape[0])

    @property
    def nbytes(self) -> int:
        """Memory held (a client cache's measure of size)."""
        return int(self.shN.nbytes)

    def attach(self, host: Scene, *, where: str) -> Scene:
        """``host`` (decoded, in texel order) with these bands; IntegrityError when the counts
        differ (the index paired chunks that do not belong together)."""
        if len(host) != len(self):
            raise IntegrityError(
                f"SH bands of {len(self)} Gaussians for a chunk of {len(host)}", where=where
            )
        return replace(host, gaussians=replace(host.gaussians, shN=self.shN))


def without_sh(scene: Scene) -> Scene:
    """``scene`` with DC colour only (what a layered stream's base chunk stores)."""
    g = scene.gaussians
    bare = replace(g, shN=np.zeros((len(g), 0, 3), np.float32))
    return replace(scene, gaussians=bare)


def encode_sh_bands(
    host: Scene,
    *,
    seed: int = 0,
    quality: int = QUALITY_MAX,
    on_palette: FractionDone | None = None,
) -> dict[str, bytes]:
    """Files of the SH-band chunk of ``host`` (its chunk's Gaussians, in any order), meta.json
    last; ``quality`` sets the palette's slack as for a whole chunk."""
    if len(host) == 0 or host.gaussians.sh_bands == 0:
        raise InputError("an SH-band chunk needs Gaussians with SH bands beyond DC")
    order = texel_order(host)
    ordered = host.gaussians if is_identity(order) else host.gaussians.subset(order)  # read only
    width, height = image_size(len(ordered))
    slack = Slacks.at(budget_fraction(quality)).bands
    images, shn = encode_sh_palette(
        ordered, width, height, seed, lambda _msg: None, on_palette=on_palette, slack=slack
    )
    meta = {
        "version": C.SOG_VERSION,
        "asset": {"generator": f"{C.GENERATOR} {__version__}"},
        "count": len(ordered),
        "shN": shn,
    }
    parsed = parse_sh_meta(meta, where="encoder output")
    files = encode_many(images)
    files[C.META_JSON] = dump_sh_meta(parsed)
    return files


def read_sh_meta(files: Mapping[str, bytes], *, where: str) -> ShBandsMeta:
    """The validated meta.json of an SH-band chunk's files."""
    if C.META_JSON not in files:
        raise SogError("no meta.json", where=where)
    return parse_sh_meta(files[C.META_JSON], where=f"{where}/{C.META_JSON}")


def decode_sh_bands(files: Mapping[str, bytes], *, where: str = "<sh chunk>") -> ShBands:
    """The bands stored in an SH-band chunk's files (image sizes and budgets checked before
    anything is decoded, as for any chunk)."""
    meta = read_sh_meta(files, where=where)
    needed, sizes = checked_images(meta, files, where=where)
    count = int(meta.count)
    with ImageDecoder(needed, where=where, sizes=sizes) as decoder:
        bands = decoder.then(meta.shN.files, lambda images: decode_sh(meta.shN, images, count))
        return ShBands(bands.result())


def decode_sh_bands_bytes(data: bytes, *, where: str = "<sh chunk>") -> ShBands:
    """Decode one bundled SH-band chunk (CPU work: run it in a thread from async code)."""
    return decode_sh_bands(read_bundle(data, where=where), where=where)
