"""Frame sequences stored once: correspondence, lifespan merging and fitted motion (issue 7).

``features`` (columns and tolerances), ``match`` (correspondence), ``fit`` (polynomials),
``runs`` (the streaming merger) and ``sequence`` (the ``--temporal`` modes).
"""

from .features import Steps, Tolerance
from .runs import FrameMerger, MergeStats
from .sequence import TEMPORAL_MODES, TemporalMode, merge_sequence

__all__ = [
    "TEMPORAL_MODES",
    "FrameMerger",
    "MergeStats",
    "Steps",
    "TemporalMode",
    "Tolerance",
    "merge_sequence",
]
