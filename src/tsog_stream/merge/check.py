"""How far a decoded frame is from its source frame, attribute by attribute.

The two sets come in different orders (the encoder sorts by Morton code, merging reorders),
so Gaussians are paired first: candidates within a small reach of each other's position, each
pair scored by its position difference plus, much more weakly, its other differences (so two
Gaussians at one place pair by their other attributes), mutual best
pairs kept, repeated on the leftovers. Used by ``tsog segment --temporal`` to report the error
after encoding, by the tests and by the benchmark.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..model import Gaussians
from .features import COLUMN_GROUPS, MEANS, align_signs, columns, robust_extent, unit_quats
from .match import I64, candidate_pairs, cell_keys, mutual_best

F64 = npt.NDArray[np.float64]
PAIRING_REACH = 1e-3
"""Pairing distance as a fraction of the source frame's extent (far above position errors)."""
PAIRING_ROUNDS = 8
TIE_WEIGHT = 30.0
"""Attribute differences count as position differences this many times smaller (in units of
the column's spread against the reach): position decides, attributes only break ties."""


def _pairs(a: F64, b: F64, reach: float, scale: F64) -> tuple[I64, I64]:
    """Mutual best pairs of rows of ``a`` and ``b`` within ``reach`` in position."""
    found_a, found_b = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for _ in range(PAIRING_ROUNDS):
        rest_a = np.setdiff1d(np.arange(len(a), dtype=np.int64), np.concatenate(found_a))
        rest_b = np.setdiff1d(np.arange(len(b), dtype=np.int64), np.concatenate(found_b))
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
            break
        pa, pb = mutual_best(np.concatenate(got_a), np.concatenate(got_b), np.concatenate(got_cost))
        if pa.size == 0:
            break
        found_a.append(rest_a[pa])
        found_b.append(rest_b[pb])
    return np.concatenate(found_a), np.concatenate(found_b)


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
