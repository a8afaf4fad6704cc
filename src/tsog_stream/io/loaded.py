"""The result of reading a dynamic (4D) source format: a scene and the reader's notes.

Shared by the 4D readers (:mod:`~tsog_stream.io.splatv`, :mod:`~tsog_stream.io.freetimegs`, and
others) so callers handle every 4D input the same way. ``notes`` say what a reader dropped,
clamped or assumed (time unit, defaults), one short sentence each.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..model import Scene
from ..schemas.cameras import CaptureCamera


@dataclass(frozen=True)
class Loaded4D:
    """A 4D scene read from a source format, with the reader's notes."""

    scene: Scene
    notes: list[str] = field(default_factory=list)
    cameras: list[CaptureCamera] = field(default_factory=list)
    """Capture cameras the file carries (``.splatv`` headers), in file order."""
    duration_assumed: bool = False
    """The scene's length was assumed, not read (a ``.splatv`` read without ``duration_s``)."""
