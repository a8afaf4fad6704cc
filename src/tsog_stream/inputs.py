"""Any input opened as a scene at time t, for rendering and evaluation.

Files the readers know (PLY, SOG/TSOG chunks, FreeTimeGS, ``.splatv``, ``.4dgs``, frame
sequences) are loaded whole; ``.tsogs`` containers, unpacked folders and stream URLs are read
chunk by chunk through the one stream reader (:func:`tsog_stream.client.open_stream`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt

from .client import open_stream
from .constants import THUMBNAIL_SIZE
from .errors import InputError
from .framing import default_view
from .io.cameras import read_cameras
from .io.readers import ReadOptions, detect_format, load_scene
from .model import Gaussians, Scene, opacity_at
from .render.evaluate import Source, scene_source
from .schemas.cameras import Camera
from .schemas.manifest import SceneInfo

URL_SCHEMES = ("http://", "https://", "file://")
PAGE_BACKGROUND = (18 / 255, 18 / 255, 18 / 255)
"""The web player's clear colour (0.07 grey), so a thumbnail looks like the page."""
STREAM_KINDS = ("stream", "tsogs", "tsogs-dir")
"""Input kinds read chunk by chunk ("stream" is any URL)."""
OPTION_KINDS = {
    "fps": ("ply-sequence", "sog-sequence"),
    "duration_s": ("splatv",),
    "scene_length_s": ("freetimegs-ply", "freetimegs-npz"),
}
"""The input formats each reading option applies to (as in io.readers)."""


def is_url(target: str) -> bool:
    """True for the http(s) and file URLs the stream reader opens."""
    return target.lower().startswith(URL_SCHEMES)


def input_kind(target: str, format: str | None = None) -> str:
    """ "stream" for a URL, else ``format`` or the format detected from the content."""
    return "stream" if is_url(target) else format or detect_format(target)


def fit_options(kind: str, options: ReadOptions) -> ReadOptions:
    """``options`` without the reading options that do not apply to inputs of ``kind``."""
    unused: dict[str, Any] = {k: None for k, kinds in OPTION_KINDS.items() if kind not in kinds}
    return replace(options, **unused)


def stream_notes(info: SceneInfo) -> list[str]:
    """What a container's index says a reader should know: a length its writer assumed (a
    ``.splatv`` segmented without a duration, ``SceneInfo.duration_assumed``)."""
    if not info.duration_assumed:
        return []
    return [
        f"its length, {info.end_s - info.start_s:g} s, was assumed when it was segmented (the "
        "input did not say it): segment it again with --duration-s"
    ]


def open_source(
    target: str | os.PathLike[str],
    *,
    format: str | None = None,
    options: ReadOptions | None = None,
    progress: Callable[[str], None] | None = None,
    cameras: str | os.PathLike[str] | None = None,
) -> Source:
    """Open any input as a :class:`Source`; containers and URLs are read chunk by chunk.

    Capture cameras: ``cameras`` (a camera file) when given, else those the input carries,
    sits beside or (a container) stores."""
    text = os.fspath(target)
    kind = input_kind(text, format)
    if kind in STREAM_KINDS:
        return _stream_source(text, kind, cameras)
    loaded = load_scene(text, format=kind, options=options, progress=progress, cameras=cameras)
    source = scene_source(loaded.scene, text, loaded.cameras)
    return replace(source, kind=loaded.format, notes=list(loaded.notes))


def _stream_source(target: str, kind: str, cameras: str | os.PathLike[str] | None) -> Source:
    """A container or stream URL as a Source: its stored cameras and opening view (an index
    written before views were stored opens on a framing of its first frame)."""
    given = read_cameras(cameras).cameras if cameras is not None else None
    stream = open_stream(target)
    manifest = stream.index.manifest
    info = manifest.scene
    chosen = given if given is not None else list(manifest.cameras)

    def opening() -> Camera | None:
        if cameras is None and manifest.view is not None:
            return manifest.view
        return default_view(stream.frame_at(info.start_s), chosen)

    def pieces(t: float) -> Iterator[Scene]:
        for chunk in stream.index.chunks_for(t):
            if chunk.holds_gaussians:
                yield stream.chunk_scene(chunk.id)

    span = None if info.timeline_type is None else (info.start_s, info.end_s)
    return Source(
        target,
        kind,
        span,
        stream.frame_at,
        stream.close,
        notes=stream_notes(info),
        fps=info.fps,
        cameras=chosen,
        opening=opening,
        pieces=pieces,
    )


def thumbnail_png(container: str | os.PathLike[str]) -> bytes:
    """The scene list's picture: a THUMBNAIL_SIZE PNG of a container's opening view half way
    through, on the page's background grey."""
    from .render import from_capture, png_bytes, render, to_uint8  # noqa: PLC0415 - numba

    with open_source(container) as source:
        view = source.opening()
        if view is None:
            raise InputError("the scene shows nothing to aim a camera at", where=str(container))
        middle = sum(source.span) / 2 if source.span is not None else 0.0
        camera = from_capture(view, *THUMBNAIL_SIZE)
        shown = _most_opaque_at(source.scenes_at(middle), middle)
        image = render(shown, camera, background=PAGE_BACKGROUND)
    return png_bytes(to_uint8(image))


THUMBNAIL_GAUSSIANS = 1 << 20
"""Gaussians a thumbnail draws at most, the most opaque: a picture this small needs no more,
and drawing all of a huge scene would hold gigabytes."""


def _most_opaque_at(scenes: Iterable[Scene], t: float) -> Gaussians:
    """The THUMBNAIL_GAUSSIANS most opaque Gaussians shown at ``t`` by all ``scenes`` (in
    their order), evaluated at t. Reduced scene by scene, so memory holds at most twice that
    many and one scene, never the whole; a scene gives (and evaluates) only what is at least
    as opaque as the THUMBNAIL_GAUSSIANS-th so far."""
    kept: list[Gaussians] = []
    floor = -np.inf  # nothing less opaque can be among the most opaque any more
    for scene in scenes:
        kept.append(_shown_at_least(scene, t, floor))
        held = sum(map(len, kept))
        if held > THUMBNAIL_GAUSSIANS:
            floor = _kth_largest([g.opacities for g in kept], THUMBNAIL_GAUSSIANS)
        if held > 2 * THUMBNAIL_GAUSSIANS:
            kept = _most_opaque_pieces(kept)
    if sum(map(len, kept)) > THUMBNAIL_GAUSSIANS:
        kept = _most_opaque_pieces(kept)
    if len(kept) == 1:
        return kept[0]  # one piece (a scene of one chunk): drawn as it is, not copied
    return Gaussians.concat(kept) if kept else Gaussians.empty()


def _shown_at_least(scene: Scene, t: float, floor: float) -> Gaussians:
    """The Gaussians ``scene`` shows at ``t`` at least ``floor`` opaque, evaluated at t."""
    opacity = opacity_at(scene, t)
    enough = (opacity >= floor) & (opacity > -np.inf)
    return scene.at(t) if enough.all() else scene.subset(np.flatnonzero(enough)).at(t)


def _kth_largest(opacities: Sequence[npt.NDArray[np.float32]], k: int) -> float:
    """The k-th largest of the opacities taken together (k at most their count)."""
    joined = np.concatenate(opacities)
    return float(np.partition(joined, len(joined) - k)[len(joined) - k])


def _most_opaque_pieces(pieces: Sequence[Gaussians]) -> list[Gaussians]:
    """The THUMBNAIL_GAUSSIANS most opaque of ``pieces`` taken together, as the part of each
    piece kept (in order; a piece kept whole is not copied)."""
    opacity = np.concatenate([g.opacities for g in pieces])
    keep = np.zeros(len(opacity), bool)
    keep[np.argpartition(-opacity, THUMBNAIL_GAUSSIANS - 1)[:THUMBNAIL_GAUSSIANS]] = True
    bounds = np.cumsum([0, *map(len, pieces)])
    cut = []
    for g, first, end in zip(pieces, bounds[:-1], bounds[1:], strict=True):
        mine = keep[first:end]
        cut.append(g if mine.all() else g.subset(np.flatnonzero(mine)))
    return cut
