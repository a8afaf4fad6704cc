"""Frames -> few Gaussians: a run of frames in which a Gaussian stays within tolerance becomes
one Gaussian with a lifespan (timeline type 1); with ``fit``, a run in which it changes
smoothly gets polynomial coefficients on the track channels (:mod:`.tracks`) that change.

Frames arrive one at a time (memory: the result plus one frame). A run stays static while each
column's range is at most twice the tolerance (its midrange then within tolerance of every
frame); a moving run stays open for at most ``max_frames`` frames while a polynomial of order
<= 3 keeps every channel within tolerance and its SH rest stays static.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import TypeAlias

import numpy as np
import numpy.typing as npt

from ..columns import down
from ..model import Gaussians, Scene, Timeline, TimelineType
from .features import (
    ALPHA,
    COLUMN_GROUPS,
    MEANS,
    SH_REST,
    Steps,
    Tolerance,
    align_signs,
    columns,
    gaussians_from,
    quat_tolerance,
    tolerances,
    unit_quats,
)
from .fit import MAX_ORDER, fit_tracks, highest_order, per_second
from .match import I64, Side, correspond, in_rounds
from .tracks import (
    COLUMN_OF,
    TRACK_GROUPS,
    TRACK_WIDTH,
    apply_track,
    predict,
    static_groups,
    track_tolerance,
    track_values,
)

F64 = npt.NDArray[np.float64]
DEFAULT_TRACK_FRAMES = 32
"""Longest run a fitted polynomial covers (a longer motion is cut into several Gaussians)."""
DEFAULT_REACH = 0.02
"""Largest per-frame move matched, as a fraction of the reference frame's extent."""
NEAR_REACH = 0.25
"""The first, cheap search around a predicted position: this fraction of the full reach."""
ATTRIBUTE_REACH = 32.0
"""The second search lets attributes differ from the prediction by this many tolerances (one
frame gives no rate of change); the fit over the run decides."""


@dataclass
class _Runs:
    """Open runs: per-column range, quaternion range and reference, first frame, index in the
    previous frame, frames so far, and the track of the first ``max_frames`` frames."""

    lo: F64
    hi: F64
    qlo: F64
    qhi: F64
    qref: F64
    start: I64
    last: I64
    count: I64
    history: F64

    def take(self, index: I64) -> _Runs:
        return _Runs(*(getattr(self, f.name)[index] for f in fields(self)))

    @staticmethod
    def join(parts: list[_Runs]) -> _Runs:
        width = max(p.history.shape[1] for p in parts)
        parts = [
            p if p.history.shape[1] == width else replace(p, history=_widened(p.history, width))
            for p in parts
        ]
        return _Runs(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(_Runs)))

    def __len__(self) -> int:
        return int(self.start.shape[0])


_Closed: TypeAlias = tuple[F64, F64, I64, I64, F64]
"""Gaussians of closed runs: columns, quaternions, start, length, and motion per frame**k
(orders 1..MAX_ORDER x the 14 track channels)."""


@dataclass
class MergeStats:
    """What merging did: frames, Gaussians in and out, how many out carry motion."""

    frames: int = 0
    gaussians_in: int = 0
    gaussians_out: int = 0
    moving_out: int = 0
    pairs: int = 0
    """Gaussians that continued a run from the frame before (static or moving)."""
    worst: dict[str, float] = field(default_factory=dict)
    note: str = ""
    """Set when the result is not what was asked for, and why."""


class FrameMerger:
    """Feed frames in order with :meth:`add`; :meth:`scene` gives the merged type-1 scene."""

    def __init__(
        self,
        steps: Steps,
        tolerance: Tolerance,
        fps: float,
        sh_coeffs: int,
        *,
        fit: bool = False,
        reach: F64 | None = None,
        max_frames: int = DEFAULT_TRACK_FRAMES,
    ) -> None:
        self.steps, self.tolerance, self.fps, self.sh_coeffs = steps, tolerance, fps, sh_coeffs
        self.fit, self.max_frames = fit, max_frames if fit else 1
        self.reach = np.zeros(3) if reach is None else np.asarray(reach, np.float64)
        self.stats = MergeStats()
        self._open: _Runs | None = None
        self._closed: list[_Closed] = []

    @property
    def held(self) -> int:
        """Gaussians held so far: closed runs' and open runs'."""
        open_runs = len(self._open) if self._open is not None else 0
        return sum(len(c[2]) for c in self._closed) + open_runs

    def _side(self, cols: F64, quats: F64) -> Side:
        tol = tolerances(cols, self.steps, self.tolerance)
        return Side(cols, quats, tol, quat_tolerance(self.tolerance))

    def add(self, g: Gaussians) -> None:
        """The next frame's Gaussians."""
        frame = self.stats.frames
        self.stats.frames += 1
        self.stats.gaussians_in += len(g)
        b = self._side(columns(g), unit_quats(g))
        runs = self._open
        if runs is None or len(runs) == 0:
            self._open = self._start(b, np.arange(len(b), dtype=np.int64), frame)
            return
        moving = self._moving(runs)
        ra, rb = self._static_pairs(runs, np.flatnonzero(~moving), b)
        if self.fit:
            free_runs = np.setdiff1d(np.arange(len(runs), dtype=np.int64), ra, assume_unique=True)
            free_runs = free_runs[runs.count[free_runs] < self.max_frames]
            free_b = np.setdiff1d(np.arange(len(b), dtype=np.int64), rb, assume_unique=True)
            ma, mb = self._moving_pairs(runs, free_runs, b, free_b)
            ra, rb = np.concatenate([ra, ma]), np.concatenate([rb, mb])
        self.stats.pairs += len(ra)
        extended = self._extend(runs.take(ra), b, rb)
        ended = np.setdiff1d(np.arange(len(runs), dtype=np.int64), ra, assume_unique=True)
        self._close(runs.take(ended), frame)
        full = self._moving(extended) & (extended.count >= self.max_frames)
        self._close(extended.take(np.flatnonzero(full)), frame + 1)
        fresh = np.setdiff1d(np.arange(len(b), dtype=np.int64), rb, assume_unique=True)
        started = self._start(b.take(fresh), fresh, frame)
        self._open = _Runs.join([extended.take(np.flatnonzero(~full)), started])

    def _moving(self, runs: _Runs) -> npt.NDArray[np.bool_]:
        """Runs that already changed beyond the static allowance (in any column or rotation)."""
        tol = tolerances((runs.lo + runs.hi) / 2, self.steps, self.tolerance)
        still = np.all(runs.hi - runs.lo <= 2 * tol, axis=1)
        still &= np.all(runs.qhi - runs.qlo <= 2 * quat_tolerance(self.tolerance), axis=1)
        return np.asarray(~still)

    def _static_pairs(self, runs: _Runs, idx: I64, b: Side) -> tuple[I64, I64]:
        """(run, Gaussian of b) pairs that keep a static run static."""
        sub = runs.take(idx)
        a = self._side((sub.lo + sub.hi) / 2, (sub.qlo + sub.qhi) / 2)
        reach = down(np.max, a.tol[:, MEANS], initial=0) + down(np.max, b.tol[:, MEANS], initial=0)
        ia, ib = correspond(a, b, reach)
        ok = self._within(sub, ia, b, ib)
        return idx[ia[ok]], ib[ok]

    def _within(
        self, sub: _Runs, ia: I64, b: Side, ib: I64, *, sh_rest_only: bool = False
    ) -> npt.NDArray[np.bool_]:
        """Whether adding b[ib] to runs sub[ia] keeps each column's range (and the rotation's)
        within 2 tolerances; only the SH rest columns with ``sh_rest_only`` (a moving run)."""
        lo = np.minimum(sub.lo[ia], b.cols[ib])
        hi = np.maximum(sub.hi[ia], b.cols[ib])
        excess = hi - lo - 2 * tolerances((lo + hi) / 2, self.steps, self.tolerance)
        if sh_rest_only:
            return np.asarray(np.all(excess[:, SH_REST:] <= 0, axis=1))
        q = align_signs(b.quats[ib], sub.qref[ia])
        qlo, qhi = np.minimum(sub.qlo[ia], q), np.maximum(sub.qhi[ia], q)
        ok = np.all(excess <= 0, axis=1)
        return np.asarray(ok & np.all(qhi - qlo <= 2 * quat_tolerance(self.tolerance), axis=1))

    def _moving_pairs(self, runs: _Runs, idx: I64, b: Side, bidx: I64) -> tuple[I64, I64]:
        """(run, Gaussian of b) pairs that continue a run along a polynomial path: searched
        near the predicted position first (cheap; most tracks go where they went), then the
        leftovers within the full reach."""

        def near(rest: I64, free: I64) -> tuple[I64, I64]:
            reach = self.reach * NEAR_REACH
            return self._moving_pairs_within(runs, rest, b, free, reach=reach, loose=1.0)

        def far(rest: I64, free: I64) -> tuple[I64, I64]:
            loose = ATTRIBUTE_REACH
            return self._moving_pairs_within(runs, rest, b, free, reach=self.reach, loose=loose)

        return in_rounds(idx, bidx, [near, far], until_empty=False)

    def _moving_pairs_within(
        self, runs: _Runs, idx: I64, b: Side, bidx: I64, *, reach: F64, loose: float
    ) -> tuple[I64, I64]:
        """Moving pairs (indices into ``idx`` and ``bidx``) within ``reach`` of the run's
        predicted position and ``loose`` tolerances of its predicted attributes, that a
        polynomial fits."""
        if idx.size == 0 or bidx.size == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        sub = runs.take(idx)
        cols, quats = apply_track((sub.lo + sub.hi) / 2, predict(sub.history, sub.count))
        a = self._side(cols, quats)
        a = Side(a.cols, a.quats, a.tol * loose, a.quat_tol * loose)
        bs = b.take(bidx)
        ia, ib = correspond(a, bs, reach, moving=True)
        ok = self._within(sub, ia, bs, ib, sh_rest_only=True)
        ia, ib = ia[ok], ib[ok]
        new = track_values(bs.cols[ib], align_signs(bs.quats[ib], sub.qref[ia]))
        tol = track_tolerance(bs.cols[ib], self.steps, self.tolerance)
        fits = np.zeros(ia.size, bool)
        for n in np.unique(sub.count[ia]):
            pick = np.flatnonzero(sub.count[ia] == n)
            track = np.concatenate([sub.history[ia[pick], :n], new[pick, None]], axis=1)
            fits[pick] = fit_tracks(track, tol[pick])[0] >= 0
        return ia[fits], ib[fits]

    def _extend(self, runs: _Runs, b: Side, ib: I64) -> _Runs:
        """The runs with one more frame each, b[ib]."""
        q = align_signs(b.quats[ib], runs.qref)
        longest = int(runs.count.max(initial=0)) + 1
        history = _widened(runs.history, min(self.max_frames, longest) if self.fit else 0)
        room = np.flatnonzero(runs.count < history.shape[1])
        history[room, runs.count[room]] = track_values(b.cols[ib[room]], q[room])
        return _Runs(
            np.minimum(runs.lo, b.cols[ib]),
            np.maximum(runs.hi, b.cols[ib]),
            np.minimum(runs.qlo, q),
            np.maximum(runs.qhi, q),
            runs.qref,
            runs.start,
            ib,
            runs.count + 1,
            history,
        )

    def _start(self, b: Side, index: I64, frame: int) -> _Runs:
        """New runs, one per Gaussian of ``b``."""
        n = len(b)
        history = np.zeros((n, 1 if self.fit else 0, TRACK_WIDTH))
        if self.fit:
            history[:, 0] = track_values(b.cols, b.quats)
        return _Runs(
            b.cols.copy(),
            b.cols.copy(),
            b.quats.copy(),
            b.quats.copy(),
            b.quats.copy(),
            np.full(n, frame, np.int64),
            index.astype(np.int64),
            np.ones(n, np.int64),
            history,
        )

    def _close(self, runs: _Runs, end: int) -> None:
        """Turn runs ending before frame ``end`` into Gaussians: a moving run as one Gaussian
        with motion on the attributes that changed when a polynomial of an order its length
        supports fits it, else as one Gaussian per frame."""
        if len(runs) == 0:
            return
        cols, quats = (runs.lo + runs.hi) / 2, (runs.qlo + runs.qhi) / 2
        deviation, qdev = (runs.hi - runs.lo) / 2, (runs.qhi - runs.qlo) / 2
        motion = np.zeros((len(runs), MAX_ORDER, TRACK_WIDTH))
        keep = np.ones(len(runs), bool)
        moving = np.flatnonzero(self._moving(runs))
        for n in np.unique(runs.count[moving]):
            pick = moving[runs.count[moving] == n]
            history = runs.history[pick, :n]
            tol = track_tolerance(cols[pick], self.steps, self.tolerance)
            orders, coeffs, residual = fit_tracks(history, tol, highest_order(n))
            fitted, fitted_q = apply_track(cols[pick], coeffs[:, 0])
            still = static_groups(history.min(axis=1), history.max(axis=1), tol)
            for name, part in TRACK_GROUPS.items():
                rows = np.flatnonzero(~still[name])
                motion[pick[rows], :, part] = coeffs[rows, 1:, part]
                if name == "quats":
                    quats[pick[rows]] = fitted_q[rows]
                    qdev[pick[rows]] = residual[rows, part]
                    continue
                column = COLUMN_OF[name]
                cols[pick[rows], column] = fitted[rows, column]
                scale = _alpha_slope(fitted[rows]) if name == "opacity" else 1.0
                deviation[pick[rows], column] = residual[rows, part] * scale
            unfit = pick[orders < 0]
            keep[unfit] = False
            self._unfold(runs.take(unfit), cols[unfit])
        kept = np.flatnonzero(keep)
        self._note_worst(deviation[kept], qdev[kept])
        start = runs.start[kept]
        self._closed.append((cols[kept], quats[kept], start, end - start, motion[kept]))

    def _unfold(self, runs: _Runs, cols: F64) -> None:
        """Store runs as one static Gaussian per frame (values from their track)."""
        if len(runs) == 0:
            return
        n = int(runs.count[0])
        rows = np.repeat(np.arange(len(runs)), n)
        frames = np.tile(np.arange(n), len(runs))
        out, quats = apply_track(cols[rows], runs.history[rows, frames])
        deviation = (runs.hi - runs.lo)[rows] / 2
        deviation[:, :SH_REST] = 0.0  # each frame keeps its own values but SH rest
        self._note_worst(deviation, np.zeros_like(quats))
        ones, still = np.ones(rows.size, np.int64), np.zeros((rows.size, MAX_ORDER, TRACK_WIDTH))
        self._closed.append((out, quats, runs.start[rows] + frames, ones, still))

    def _note_worst(self, deviation: F64, quats: F64) -> None:
        """Keep the largest deviation of a merged value from a frame it stands for."""
        worst = self.stats.worst
        for name, part in COLUMN_GROUPS.items():
            value = float(deviation[:, part].max(initial=0.0))
            worst[name] = max(worst.get(name, 0.0), value)
        worst["quats"] = max(worst.get("quats", 0.0), float(quats.max(initial=0.0)))

    def scene(self) -> Scene:
        """The merged scene: type-1 timeline in frames at ``fps``, motion as ``temporal``."""
        if self._open is not None:
            self._close(self._open, self.stats.frames)
            self._open = None
        none: _Closed = (
            np.zeros((0, 10 + 3 * self.sh_coeffs)),
            np.zeros((0, 4)),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros((0, MAX_ORDER, TRACK_WIDTH)),
        )
        cols, quats, start, length, motion = (
            np.concatenate([e, *(c[i] for c in self._closed)]) for i, e in enumerate(none)
        )
        order = np.lexsort((length, start))
        g = gaussians_from(cols[order], quats[order], self.sh_coeffs)
        self.stats.gaussians_out = len(g)
        timeline = Timeline(
            TimelineType.START_DURATION,
            start[order].astype(np.float64),
            length[order].astype(np.float64),
            fps=self.fps,
            scene_length=self.stats.frames / self.fps,
        )
        motion = motion[order]
        self.stats.moving_out = int(np.any(motion != 0, axis=(1, 2)).sum())
        return Scene(g, timeline, _temporal(motion, self.fps))


def _widened(history: F64, width: int) -> F64:
    """A copy of ``history`` with room for at least ``width`` frames (zeros beyond its own)."""
    out = np.zeros((history.shape[0], max(width, history.shape[1]), history.shape[2]))
    out[:, : history.shape[1]] = history
    return out


def _temporal(motion: F64, fps: float) -> dict[str, npt.NDArray[np.float32]]:
    """Per-second coefficients of each attribute that moves, up to its highest used order."""
    out = {}
    for name, part in TRACK_GROUPS.items():
        used = [k for k in range(MAX_ORDER) if np.any(motion[:, k, part] != 0)]
        if used:
            coeffs = per_second(motion[:, : used[-1] + 1, part], fps)
            out[name] = coeffs.astype(np.float32)
    return out


def _alpha_slope(cols: F64) -> F64:
    """(M, 1) d alpha / d logit at each row's alpha: turns a logit residual into an alpha one."""
    alpha = cols[:, ALPHA]
    return np.asarray(alpha * (1.0 - alpha), np.float64)
