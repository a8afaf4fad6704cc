"""tsog-stream: store and stream dynamic (4D) Gaussian Splatting scenes as TSOG.

The public API is the names of ``__all__`` (pinned by a test); everything else is internal.

- Read a stream at any time: :func:`open_stream` (sync, any path or URL) or
  :class:`StreamClient` (async); ``frame_at(t)`` gives :class:`Gaussians`, ``write_ply`` saves them.
- Make a stream: :func:`segment_input` does all ``tsog segment`` does (any input to a ``.tsogs``
  with its thumbnail); or :func:`load_scene` reads any input and :func:`segment_scene` writes it.
- A live event: :func:`run_live` publishes frames as they are written into a folder (``tsog
  live``); ``Stream.follow_live`` plays one at its live edge.
- One chunk: :func:`encode_chunk` / :func:`decode_chunk` (file bytes by name), :func:`read_chunk`.
- Errors: everything raised on purpose is a :class:`TsogError` (tree in ``tsog_stream.errors``).

Names are loaded on first use, so importing one submodule (the sans-I/O format layer, say) does
not import the HTTP client or the segmenter.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import __version__

_HOMES = {
    "open_stream": "client",
    "Stream": "client",
    "StreamClient": "client",
    "HttpOptions": "client",
    "load_scene": "io.readers",
    "ReadOptions": "io.readers",
    "segment_input": "pipeline",
    "InputOptions": "pipeline",
    "InputReport": "pipeline",
    "segment_scene": "segment.segmenter",
    "SegmentOptions": "segment.segmenter",
    "SegmentReport": "segment.segmenter",
    "run_live": "segment.live",
    "LiveOptions": "segment.live",
    "LiveReport": "segment.live",
    "encode_chunk": "codec.chunk",
    "decode_chunk": "codec.chunk",
    "read_chunk": "io.chunks",
    "write_ply": "io.ply",
    "Gaussians": "model",
    "Scene": "model",
    "Timeline": "model",
    "TimelineType": "model",
    "TsogError": "errors",
    "InputError": "errors",
    "FormatError": "errors",
    "PlyError": "errors",
    "SogError": "errors",
    "MetaError": "errors",
    "UnsupportedError": "errors",
    "IntegrityError": "errors",
    "SourceError": "errors",
    "AccessError": "errors",
}
"""Each public name and the module (under tsog_stream) that defines it."""

__all__ = [
    "AccessError",
    "FormatError",
    "Gaussians",
    "HttpOptions",
    "InputError",
    "InputOptions",
    "InputReport",
    "IntegrityError",
    "LiveOptions",
    "LiveReport",
    "MetaError",
    "PlyError",
    "ReadOptions",
    "Scene",
    "SegmentOptions",
    "SegmentReport",
    "SogError",
    "SourceError",
    "Stream",
    "StreamClient",
    "Timeline",
    "TimelineType",
    "TsogError",
    "UnsupportedError",
    "__version__",
    "decode_chunk",
    "encode_chunk",
    "load_scene",
    "open_stream",
    "read_chunk",
    "run_live",
    "segment_input",
    "segment_scene",
    "write_ply",
]

if TYPE_CHECKING:
    from .client import HttpOptions, Stream, StreamClient, open_stream
    from .codec.chunk import decode_chunk, encode_chunk
    from .errors import (
        AccessError,
        FormatError,
        InputError,
        IntegrityError,
        MetaError,
        PlyError,
        SogError,
        SourceError,
        TsogError,
        UnsupportedError,
    )
    from .io.chunks import read_chunk
    from .io.ply import write_ply
    from .io.readers import ReadOptions, load_scene
    from .model import Gaussians, Scene, Timeline, TimelineType
    from .pipeline import InputOptions, InputReport, segment_input
    from .segment import SegmentOptions, SegmentReport, segment_scene
    from .segment.live import LiveOptions, LiveReport, run_live


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'tsog_stream' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
