"""What a dynamic (4D) reader returns: a scene, its notes, the file's cameras, and whether its
length was assumed; one type so callers handle every 4D input the same way."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

from ..errors import InputError
from ..model import Scene
from ..schemas.cameras import Camera

ASSUMED_LENGTH_S: Final = 1.0
"""Seconds one unit of normalised time is taken to last when the caller does not say (neither
``.splatv`` nor FreeTimeGS stores it)."""


@dataclass(frozen=True)
class Loaded4D:
    """A 4D scene read from a source format, with the reader's notes (what it dropped, clamped
    or assumed, one short sentence each)."""

    scene: Scene
    notes: list[str] = field(default_factory=list)
    cameras: list[Camera] = field(default_factory=list)
    """Capture cameras the file carries (``.splatv`` headers), in file order."""
    duration_assumed: bool = False
    """The scene's length was assumed (ASSUMED_LENGTH_S), not read or given."""


def length_s(value: float | None, option: str) -> float:
    """Seconds in one unit of normalised time: ``value``, or ASSUMED_LENGTH_S for None; an
    InputError naming ``option`` unless a positive finite number."""
    if value is None:
        return ASSUMED_LENGTH_S
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise InputError(f"must be a positive number of seconds, got {value!r}", where=option)
    return float(value)
