"""How far a decoded frame is from its source frame, attribute by attribute.

The two sets come in different orders, so Gaussians are paired first: mutual best pairs
within a small reach, scored by position and, much more weakly, by the other attributes (so
two Gaussians at one place pair by those), repeated on the leftovers.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..model import Gaussians
from .features import COLUMN_GROUPS, MEANS, align_signs, columns, robust_extent, unit_quats
from .match import I64, candidate_pairs, cell_keys, in_rounds, mutual_best

F64 = npt.NDArray[np.float64]
PAIRING_REACH = 1e-3
"""Pairing distance as a fraction of the source frame's extent (far above position errors)."""
PAIRING_ROUNDS = 8
TIE_WEIGHT = 30.0
"""Attribute differences count as position differences this many times smaller (in units of
the column's spread against the reach): position decides, attributes only break ties."""


def _pairs(a: F64, b: F64, reach: float, scale: F64) -> tuple[I64, I64]:
    """Mutual best pairs of rows of ``a`` and ``b`` within ``reach`` in position."""

    def pair(rest_a: I64, rest_b: I64) -> tuple[I64, I64]:
        keys = cell_keys(np.floor(a[rest_a, MEANS] / reach).astype(np.int64))
        cells = np.floor(b[rest_b, MEANS] / reach).astype(np.int64)
        got_a, got_b, got_cost = [], [], []
        for ia, ib in candidate_pairs(keys, cells):
            diff = (a[rest_a[ia]] - b[rest_b[ib]]) / scale
            near = np.all(np.abs(a[rest_a[ia], MEANS] - b[rest_b[ib], MEANS]) <= reach, axis=1)
            got_a.append(ia[near])
            got_b.append(ib[near])
            got_cost.append(np.einsum("ij,ij->i", diff[near], diff[near]))
        if not got_a:
            return rest_a[:0], rest_b[:0]
        return mutual_best(np.concatenate(got_a), np.concatenate(got_b), np.concatenate(got_cost))

    rows_a, rows_b = (np.arange(len(x), dtype=np.int64) for x in (a, b))
    return in_rounds(rows_a, rows_b, [pair] * PAIRING_ROUNDS)


def frame_errors(source: Gaussians, decoded: Gaussians) -> tuple[dict[str, float], int]:
    """(largest absolute error per attribute over paired Gaussians, number left unpaired).

    Attributes: means (scene units), scales (log), sh0, alpha, shN and quats (components of
    sign-aligned unit quaternions).
    """
    if len(source) == 0 or len(decoded) == 0:
        return {}, abs(len(source) - len(decoded))
    qs, qd = unit_quats(source), unit_quats(decoded)
    a, b = np.hstack([columns(source), qs]), np.hstack([columns(decoded), qd])
    extent = float(robust_extent(a[:, MEANS]).max())
    reach = max(PAIRING_REACH * extent, 1e-9)
    scale = a.std(axis=0) * TIE_WEIGHT  # attributes only break ties between coincident points
    scale[MEANS] = reach
    scale[scale <= 0] = 1.0
    ia, ib = _pairs(a, b, reach, scale)
    a, b = a[:, : -qs.shape[1]], b[:, : -qd.shape[1]]
    unpaired = len(source) + len(decoded) - 2 * len(ia)
    diff = np.abs(a[ia] - b[ib])
    errors = {name: float(diff[:, part].max(initial=0.0)) for name, part in COLUMN_GROUPS.items()}
    qa, qb = qs[ia], qd[ib]
    errors["quats"] = float(np.abs(qa - align_signs(qb, qa)).max(initial=0.0))
    if source.shN.shape[1] == 0:
        errors.pop("shN")
    return errors, unpaired
