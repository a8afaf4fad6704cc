"""Tracks: the 14 channels of a Gaussian that may follow a polynomial in time (spec §6).

Position, log-scales, f_dc, opacity as a logit (TSOG's temporal opacity space) and the
sign-aligned quaternion; SH rest coefficients never move.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from ..constants import ALPHA_EPS
from ..opacity import logit_to_alpha
from .features import ALPHA, MEANS, SCALES, SH0, Steps, Tolerance, quat_tolerance, tolerances

F64 = npt.NDArray[np.float64]
TRACK_GROUPS: Final = {
    "means": slice(0, 3),
    "scales": slice(3, 6),
    "sh0": slice(6, 9),
    "opacity": slice(9, 10),
    "quats": slice(10, 14),
}
"""Track channels of each dynamic attribute (the names of ``Scene.temporal``)."""
TRACK_WIDTH: Final = 14
QUATS: Final = TRACK_GROUPS["quats"]
LOGIT: Final = 9
COLUMN_OF: Final = {"means": MEANS, "scales": SCALES, "sh0": SH0, "opacity": ALPHA}
"""The column slice holding each attribute but the quaternion (opacity as alpha)."""


def _logit(alpha: F64) -> F64:
    a = np.clip(alpha, ALPHA_EPS, 1.0 - ALPHA_EPS)
    return np.asarray(np.log(a) - np.log1p(-a), np.float64)


def track_values(cols: F64, quats: F64) -> F64:
    """(M, 14) track values of rows of columns and (sign-aligned) unit quaternions."""
    out = np.empty((cols.shape[0], TRACK_WIDTH))
    out[:, :LOGIT] = cols[:, :LOGIT]
    out[:, LOGIT] = _logit(cols[:, ALPHA][:, 0])
    out[:, QUATS] = quats
    return out


def track_tolerance(cols: F64, steps: Steps, tol: Tolerance) -> F64:
    """(M, 14) tolerances of the track channels of rows of columns (the alpha tolerance
    widened by 1 / (alpha (1 - alpha)) in logit space)."""
    per_column = tolerances(cols, steps, tol)
    out = np.empty((cols.shape[0], TRACK_WIDTH))
    out[:, :LOGIT] = per_column[:, :LOGIT]
    alpha = np.clip(cols[:, ALPHA][:, 0], ALPHA_EPS, 1.0 - ALPHA_EPS)
    out[:, LOGIT] = per_column[:, ALPHA][:, 0] / (alpha * (1.0 - alpha))
    out[:, QUATS] = quat_tolerance(tol)
    return out


def apply_track(cols: F64, track: F64) -> tuple[F64, F64]:
    """Columns with the track's values written in (alpha from the logit), and its quaternions."""
    out = cols.copy()
    out[:, :LOGIT] = track[:, :LOGIT]
    out[:, ALPHA] = logit_to_alpha(track[:, LOGIT])[:, None]
    return out, track[:, QUATS].copy()


def static_groups(lo: F64, hi: F64, tol: F64) -> dict[str, npt.NDArray[np.bool_]]:
    """Per attribute, which rows stayed within twice the tolerance over the whole track."""
    return {
        name: np.all(hi[:, part] - lo[:, part] <= 2 * tol[:, part], axis=1)
        for name, part in TRACK_GROUPS.items()
    }


def predict(history: F64, count: npt.NDArray[np.int64]) -> F64:
    """Each track's next value: the last plus the last step (the last alone after one frame)."""
    rows = np.arange(history.shape[0])
    last = history[rows, count - 1]
    prev = history[rows, np.maximum(count - 2, 0)]
    return np.asarray(2 * last - prev, np.float64)
