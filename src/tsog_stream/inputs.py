"""Any input opened as a scene at time t, for rendering and evaluation.

Files the readers know (PLY, SOG/TSOG chunks, FreeTimeGS, ``.splatv``, ``.4dgs``, frame
sequences) are loaded whole; ``.tsogs`` containers, unpacked folders and stream URLs are read
chunk by chunk through the one stream reader (:func:`tsog_stream.client.open_stream`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from .client import open_stream
from .io.readers import ReadOptions, detect_format, load_scene
from .render.evaluate import Source, Span, scene_source
from .schemas.manifest import SceneInfo

URL_SCHEMES = ("http://", "https://", "file://")
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

    def keep(name: str) -> Any:
        return getattr(options, name) if kind in OPTION_KINDS[name] else None

    return ReadOptions(
        fps=keep("fps"),
        duration_s=keep("duration_s"),
        scene_length_s=keep("scene_length_s"),
        duration_mode=options.duration_mode,
    )


def _stream_span(info: SceneInfo) -> Span | None:
    """The time range a container declares (None when it holds a static scene)."""
    return None if info.timeline_type is None else (info.start_s, info.end_s)


def open_source(
    target: str | os.PathLike[str],
    *,
    format: str | None = None,
    options: ReadOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> Source:
    """Open any input as a :class:`Source`; containers and URLs are read chunk by chunk."""
    text = os.fspath(target)
    kind = input_kind(text, format)
    if kind in STREAM_KINDS:
        stream = open_stream(text)
        info = stream.index.manifest.scene
        return Source(text, kind, _stream_span(info), stream.frame_at, stream.close, fps=info.fps)
    loaded = load_scene(text, format=kind, options=options, progress=progress)
    source = scene_source(loaded.scene, text)
    return replace(source, kind=loaded.format, notes=list(loaded.notes))
