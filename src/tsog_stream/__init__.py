"""tsog-stream: store and stream dynamic (4D) Gaussian Splatting scenes as TSOG."""

from __future__ import annotations

from .errors import (
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
from .model import Gaussians, Scene, Timeline, TimelineType

__version__ = "0.1.0"

__all__ = [
    "FormatError",
    "Gaussians",
    "InputError",
    "IntegrityError",
    "MetaError",
    "PlyError",
    "Scene",
    "SogError",
    "SourceError",
    "Timeline",
    "TimelineType",
    "TsogError",
    "UnsupportedError",
    "__version__",
]
