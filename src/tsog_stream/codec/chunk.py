"""A TSOG chunk as a set of files: encode a Scene to {name: bytes}, decode it back.

A chunk without a timeline is a plain SOG v2 dataset. With one, it is the same SOG v2 dataset
plus the ``timeline``/``temporal`` meta keys and their images, index-aligned (docs/spec.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import constants as C
from .._version import __version__
from ..errors import InputError, SogError
from ..model import F32, Gaussians, Scene, Timeline, TimelineType
from ..morton import morton_order
from ..schemas import ChunkMeta, ShBandsMeta, check_image_sizes, dump_meta, listed_files, parse_meta
from ..temporal import recentre
from .budgets import QUALITY_MAX, Budgets
from .bundle import read_bundle
from .layout import image_size
from .sog_decode import decode_sog
from .sog_encode import FractionDone, encode_appearance, encode_geometry
from .tsog_images import (
    TimelineCodes,
    decode_temporal,
    decode_timeline,
    encode_temporal,
    quantize_timeline,
    timeline_images,
)
from .webp import ImageDecoder, ImageEncoder
from .webp_header import webp_size

Progress = Callable[[str], None]
U8 = npt.NDArray[np.uint8]


def texel_order(scene: Scene) -> npt.NDArray[np.intp]:
    """The Morton order of the scene's base positions (splat-transform's order); for frame
    content (a type-0 timeline) frame after frame, each in its own Morton order (frames are
    scenes of their own: interleaved, they took more bytes; docs/spec.md §3)."""
    return texel_order_of(scene.gaussians.means, scene.timeline)


def texel_order_of(means: F32, timeline: Timeline | None) -> npt.NDArray[np.intp]:
    """:func:`texel_order` of Gaussians at ``means`` with ``timeline``: what a caller cutting
    a part uses to hand the encoder its rows already in order (the order of rows in that
    order is the identity, so the encoder then copies none of them)."""
    if timeline is None or timeline.type is not TimelineType.FRAME:
        return morton_order(means)
    frames = np.asarray(timeline.t0)
    by_frame = np.argsort(frames, kind="stable")
    starts = np.flatnonzero(np.diff(frames[by_frame])) + 1
    runs = np.split(by_frame, starts)
    return np.concatenate([run[morton_order(means[run])] for run in runs]).astype(np.intp)


def encode_chunk(
    scene: Scene,
    *,
    order: npt.NDArray[np.intp] | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    quality: int = QUALITY_MAX,
    on_palette: FractionDone | None = None,
) -> dict[str, bytes]:
    """Files of a SOG/TSOG chunk (images in writing order, meta.json last).

    ``quality`` 0..100 sets the error budgets of the codes (codec/budgets.py; 100 keeps every
    16-bit code as computed). Every Gaussian given is stored (callers first leave out those
    too faint, :func:`~tsog_stream.codec.precision.without_faint`). ``order`` is a full
    permutation (texel i = Gaussian order[i]), by default the Morton order. ``on_palette``
    hears how far the SH palette's fit got (0..1; it comes last and takes longest). Same scene
    and seed give byte-identical files. A scene without Gaussians is refused: a lossless WebP
    has at least one pixel.
    """
    if len(scene) == 0:
        raise InputError("the scene has no Gaussians: there is nothing to encode")
    _refuse_non_finite(scene)
    note = progress or (lambda _msg: None)
    note("ordering")
    ordered = in_order(scene, texel_order(scene) if order is None else order)
    del order  # not needed again (a Gaussian's index each)
    return _encode_ordered(ordered, quality, seed=seed, note=note, on_palette=on_palette)


def is_identity(order: npt.NDArray[np.intp]) -> bool:
    """Whether ``order`` leaves every row where it is (rows a caller handed already in order)."""
    return bool(np.array_equal(order, np.arange(len(order))))


def in_order(scene: Scene, order: npt.NDArray[np.intp]) -> Scene:
    """``scene``'s rows in ``order``: a copy, or when they are in that order already a new
    scene sharing their arrays, which the encoder replaces but never writes."""
    if is_identity(order):
        g = scene.gaussians
        same = Gaussians(g.means, g.scales, g.quats, g.opacities, g.sh0, g.shN)
        return Scene(same, scene.timeline, dict(scene.temporal))
    return scene.subset(order)


def _encode_ordered(
    ordered: Scene,
    quality: int,
    *,
    seed: int,
    note: Progress,
    on_palette: FractionDone | None,
) -> dict[str, bytes]:
    """:func:`encode_chunk` of a scene already in texel order."""
    width, height = image_size(len(ordered))
    note("positions")
    budgets = Budgets.of(ordered, quality)
    times = None
    if ordered.timeline is not None:
        times = quantize_timeline(ordered.timeline, budgets.time if budgets is not None else None)
        recentre(ordered, times.reference_units())  # stored about what a decoder reads
    with ImageEncoder() as images, ThreadPoolExecutor(1) as beside:
        # each image compressed from the moment it is made; the timeline and motion made
        # beside the codebooks (numpy and Pillow release the GIL)
        meta: dict[str, Any] = {
            "version": C.SOG_VERSION,
            "asset": {"generator": f"{C.GENERATOR} {__version__}"},
            "count": len(ordered),
        }
        meta |= encode_geometry(ordered.gaussians, width, height, images, budgets)
        slacks = budgets.slacks if budgets is not None else None
        timed = beside.submit(
            _add_time_images,
            ordered,
            times,
            width,
            height,
            quats=ordered.gaussians.quats,
            budgets=budgets if ordered.temporal else None,
            images=images,
        )
        del budgets  # what comes next needs only the slacks
        meta |= encode_appearance(
            ordered.gaussians,
            width,
            height,
            images,
            seed=seed,
            progress=note,
            slacks=slacks,
            on_palette=on_palette,
        )
        meta |= timed.result()
        parsed = parse_meta(meta, where="encoder output")
        note("WebP")
        files = _in_canonical_order(images.files(), parsed)
    files[C.META_JSON] = dump_meta(parsed)
    return files


def _add_time_images(
    ordered: Scene,
    times: TimelineCodes | None,
    width: int,
    height: int,
    *,
    quats: F32,
    budgets: Budgets | None,
    images: ImageEncoder,
) -> dict[str, Any]:
    """The ``timeline`` and ``temporal`` meta keys of a chunk, their images handed to
    ``images`` (made on a thread beside the codebooks: docs/design/chunk-codec.md)."""
    meta: dict[str, Any] = {}
    if ordered.timeline is not None and times is not None:
        made, meta["timeline"] = timeline_images(ordered.timeline, times, width, height)
        images.add(made)
    if ordered.temporal:
        temporal_images, meta["temporal"] = encode_temporal(
            ordered.temporal, quats, width, height, budgets
        )
        images.add(temporal_images)
    return meta


def _in_canonical_order(files: dict[str, bytes], meta: ChunkMeta) -> dict[str, bytes]:
    """The chunk's images in the order its meta.json lists them (the bundle's order, so its
    bytes), whatever order they were made in."""
    return {name: files[name] for _, name in listed_files(meta)}


def _refuse_non_finite(scene: Scene) -> None:
    """InputError naming what is not finite among positions, lifespans and motion
    coefficients (a 16-bit range cannot hold such a value)."""
    parts: dict[str, npt.NDArray[np.floating]] = {
        "positions: SOG cannot place them": scene.gaussians.means
    }
    if scene.timeline is not None:
        lifespans = np.stack([scene.timeline.t0, scene.timeline.t1], axis=1)
        parts["lifespans: a chunk cannot store them"] = lifespans
    for attr, coeffs in scene.temporal.items():
        parts[f"{attr} motion coefficients: a chunk cannot store them"] = coeffs
    for what, values in parts.items():
        finite = np.isfinite(values)
        if finite.all():  # the usual case, without a reduction along rows
            continue
        bad = int(np.count_nonzero(~np.all(finite.reshape(len(scene), -1), axis=1)))
        if bad:
            raise InputError(
                f"{bad} Gaussians have non-finite {what} (remove them from the input first)"
            )


def read_meta(files: Mapping[str, bytes], *, where: str) -> ChunkMeta:
    """The validated meta.json of a chunk's files."""
    if C.META_JSON not in files:
        raise SogError("no meta.json", where=where)
    return parse_meta(files[C.META_JSON], where=f"{where}/{C.META_JSON}")


def checked_images(
    meta: ChunkMeta | ShBandsMeta, files: Mapping[str, bytes], *, where: str
) -> tuple[dict[str, bytes], dict[str, tuple[int, int]]]:
    """The WebP bytes of every image the meta lists, and their sizes (from the WebP headers),
    checked against the count, each other and the read budget before anything is decoded."""
    needed: dict[str, bytes] = {}
    for field, name in listed_files(meta):
        if name not in files:
            raise SogError(f"file {name!r} listed in {field} is missing", where=where)
        needed[name] = files[name]
    _check_plausible_count(meta, sum(len(data) for data in needed.values()), where)
    sizes = {name: webp_size(data, where=f"{where}/{name}") for name, data in needed.items()}
    check_image_sizes(meta, sizes, where=f"{where}/{C.META_JSON}")
    _check_budget(sizes, where)
    return needed, sizes


def _check_budget(sizes: Mapping[str, tuple[int, int]], where: str) -> None:
    """Refuse, before decoding, any image over the read budget (constants.pixel_budget)."""
    budget = C.pixel_budget()
    for name, (width, height) in sizes.items():
        if width * height > budget:
            raise SogError(
                f"image of {width}x{height} = {width * height} pixels, over the read budget of "
                f"{budget} (set {C.MAX_PIXELS_ENV} to allow more)",
                where=f"{where}/{name}",
            )


def _check_plausible_count(meta: ChunkMeta | ShBandsMeta, image_bytes: int, where: str) -> None:
    """Refuse a count over the read budget, or far beyond what the image bytes can describe
    (a decompression bomb)."""
    budget = C.pixel_budget()
    if meta.count > budget:
        raise SogError(
            f"meta.json declares {meta.count} Gaussians, over the read budget of {budget} "
            f"(one pixel each; set {C.MAX_PIXELS_ENV} to allow more)",
            where=where,
        )
    most = max(C.FREE_GAUSSIANS, C.MAX_GAUSSIANS_PER_IMAGE_BYTE * image_bytes)
    if meta.count > most:
        raise SogError(
            f"meta.json declares {meta.count} Gaussians but the images hold {image_bytes} "
            f"bytes: at most {most} are accepted ({C.MAX_GAUSSIANS_PER_IMAGE_BYTE} per byte)",
            where=where,
        )


def decode_chunk(files: Mapping[str, bytes], *, where: str = "<chunk>") -> Scene:
    """The Scene stored in a chunk's files, Gaussians in texel order (each attribute decoded
    as soon as its images are)."""
    meta = read_meta(files, where=where)
    needed, sizes = checked_images(meta, files, where=where)
    count = int(meta.count)
    timeline_meta, temporal_meta = meta.timeline, meta.temporal
    with ImageDecoder(needed, where=where, sizes=sizes) as decoder:
        gaussians = decode_sog(meta, decoder)
        timeline = (
            decoder.then(
                timeline_meta.files,
                lambda images: decode_timeline(timeline_meta, images, count),
            )
            if timeline_meta is not None
            else None
        )
        temporal = (
            decoder.then(
                [name for entry in temporal_meta.values() for name in entry.files],
                lambda images: decode_temporal(temporal_meta, images, count),
            )
            if temporal_meta
            else None
        )
        return Scene(
            gaussians(),
            timeline.result() if timeline is not None else None,
            temporal.result() if temporal is not None else {},
        )


def decode_chunk_timeline(files: Mapping[str, bytes], *, where: str = "<chunk>") -> Timeline | None:
    """The timeline a chunk stores (None for a static chunk), decoding its timeline images
    only: a chunk's time range without the memory of its Gaussians (``tsog info``)."""
    meta = read_meta(files, where=where)
    needed, sizes = checked_images(meta, files, where=where)
    timeline_meta, count = meta.timeline, int(meta.count)
    if timeline_meta is None:
        return None
    with ImageDecoder(needed, where=where, sizes=sizes) as decoder:
        return decoder.then(
            timeline_meta.files, lambda images: decode_timeline(timeline_meta, images, count)
        ).result()


def decode_chunk_bytes(data: bytes, *, where: str = "<chunk>") -> Scene:
    """Decode one bundled chunk (a ``.sog``'s bytes); CPU work, run it in a thread from async
    code."""
    return decode_chunk(read_bundle(data, where=where), where=where)
