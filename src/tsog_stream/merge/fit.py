"""Polynomial motion: the lowest-order polynomial (0-3) in frame time that keeps every frame of
a track within tolerance, for many tracks of one length at once: order 0 is the midrange,
1-3 least squares; coefficients per frame**k.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
MAX_ORDER = 3


@cache
def _projector(length: int, order: int) -> tuple[F64, F64]:
    """(Vandermonde (L, order+1) in frames 0..L-1, its pseudo-inverse)."""
    t = np.arange(length, dtype=np.float64)
    v = t[:, None] ** np.arange(order + 1)
    return v, np.asarray(np.linalg.pinv(v), np.float64)


def highest_order(length: int) -> int:
    """Highest order kept for ``length`` frames: 1 up to 5 frames, 2 for 6-7, 3 from 8 on (about
    two frames per coefficient, so a fit shows motion rather than interpolating noise)."""
    return min(MAX_ORDER, max(1, (length - 2) // 2)) if length >= 2 else 0


def fit_tracks(tracks: F64, tol: F64, max_order: int = MAX_ORDER) -> tuple[I64, F64, F64]:
    """Fit (M, L, C) tracks within per-track tolerances (M, C), orders up to ``max_order`` and
    L - 1: (order per track, -1 when none fits; coefficients (M, MAX_ORDER + 1, C) constant
    first, of the fit chosen or else the highest tried; the worst residual (M, C))."""
    m, length, c = tracks.shape
    orders = np.full(m, -1, np.int64)
    coeffs = np.zeros((m, MAX_ORDER + 1, c))
    worst = np.full((m, c), np.inf)
    lo, hi = tracks.min(axis=1), tracks.max(axis=1)
    fits = np.all(hi - lo <= 2 * tol, axis=1)
    orders[fits], coeffs[fits, 0], worst[fits] = 0, ((lo + hi) / 2)[fits], ((hi - lo) / 2)[fits]
    for order in range(1, min(max_order, MAX_ORDER, length - 1) + 1):
        todo = np.flatnonzero(orders < 0)
        if todo.size == 0:
            break
        v, pinv = _projector(length, order)
        k = np.einsum("ol,mlc->moc", pinv, tracks[todo])
        resid = np.abs(np.einsum("lo,moc->mlc", v, k) - tracks[todo]).max(axis=1)
        ok = np.all(resid <= tol[todo], axis=1)
        worst[todo] = resid
        orders[todo[ok]] = order
        coeffs[todo, : order + 1] = k  # a track no order fits keeps its highest-order fit
    return orders, coeffs, worst


def per_second(motion: F64, fps: float) -> F64:
    """Motion coefficients per frame**k (axis 1: k = 1, 2, ...) -> per second**k."""
    k = np.arange(1, motion.shape[1] + 1)
    return np.asarray(motion * (float(fps) ** k)[None, :, None], np.float64)
