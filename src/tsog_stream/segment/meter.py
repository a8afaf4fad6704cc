"""How far encoding has got and how long it has left, measured in work, not chunks (chunks
differ in cost and finish in bursts: docs/design/segmenter.md, "Parallel encoding").

The meter weighs each job by :func:`encode_work`, learns one worker slot's rate from the work
done (and what running jobs report through :func:`report_progress`), and credits the running
jobs with the time they have run.
"""

from __future__ import annotations

import contextvars
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from typing import Any

SH_COST_PER_COEFF = 0.3
"""A Gaussian's encode cost per SH coefficient beyond DC (an RGB triple), in units of a
Gaussian without SH (fitted to measured encodes)."""
TICK_S = 5.0
"""Seconds between two :meth:`Meter.tick` calls of its ``on_tick`` (the ETA redrawn while no
chunk is written)."""
POLL_S = 1.0
"""How often code waiting for jobs calls :meth:`Meter.tick` (a first ETA drawn at once)."""
Clock = Callable[[], float]
JobProgress = Callable[[float], None]
_reporter: contextvars.ContextVar[JobProgress | None] = contextvars.ContextVar(
    "tsog_job_progress", default=None
)


def report_progress(fraction: float) -> None:
    """The job running here has done ``fraction`` (0..1) of its work; heard by whoever runs
    it under :func:`reporting_to`, ignored elsewhere."""
    reporter = _reporter.get()
    if reporter is not None:
        reporter(min(max(float(fraction), 0.0), 1.0))  # a plain float: Dask sends msgpack


@contextmanager
def reporting_to(reporter: JobProgress) -> Iterator[None]:
    """:func:`report_progress` calls in the body go to ``reporter``."""
    reset = _reporter.set(reporter)
    try:
        yield
    finally:
        _reporter.reset(reset)


@contextmanager
def share_of(start: float, size: float) -> Iterator[None]:
    """:func:`report_progress` calls in the body cover ``start`` .. ``start + size`` of the
    enclosing job (one part of a window job)."""
    outer = _reporter.get()
    if outer is None:
        yield
        return
    with reporting_to(lambda fraction: outer(start + size * fraction)):
        yield


BEFORE_PALETTE = 0.7
"""The share of a part's other work done before its SH palette; the rest comes after it
(fitted to measured jobs)."""


def palette_share(sh_coeffs: int) -> float:
    """The share of a part's encoding its SH palette takes, by :func:`encode_work`'s model."""
    return 1.0 - encode_work(1, 0) / encode_work(1, sh_coeffs)


def palette_progress(sh_coeffs: int, fraction: float) -> float:
    """How far a part's encoding has got when its SH palette is ``fraction`` done:
    :data:`BEFORE_PALETTE` of the rest, then the palette's share of it."""
    share = palette_share(sh_coeffs)
    return (1.0 - share) * BEFORE_PALETTE + share * fraction


def encode_work(count: int, sh_coeffs: int) -> float:
    """The relative cost of encoding ``count`` Gaussians with ``sh_coeffs`` SH coefficients
    beyond DC per colour channel (0 for a part stored without its bands)."""
    return count * (1.0 + SH_COST_PER_COEFF * sh_coeffs)


class Meter:
    """Work done and left over one encoding run, fed as jobs start and finish (finishes may
    be reported from another thread: a future's callback)."""

    def __init__(self, total: float, *, clock: Clock = time.monotonic) -> None:
        self.total = max(total, 0.0)
        self.slots = 1
        self._clock = clock
        self._lock = threading.Lock()
        self._running: dict[int, tuple[float, float]] = {}
        self._reported: dict[int, tuple[float, float]] = {}
        """Running jobs' last report: (fraction done, when)."""
        self._done = 0.0
        self._busy = 0.0
        self._next = 0
        self.on_tick: Callable[[], None] | None = None
        self._ticked = clock()
        self._eta_drawn = False

    def start(self, work: float) -> int:
        """A job of ``work`` began now; returns its token for :meth:`finish`."""
        with self._lock:
            token = self._next
            self._next += 1
            self._running[token] = (work, self._clock())
            return token

    def advance(self, token: int, fraction: float) -> None:
        """The running job ``token`` reports ``fraction`` of its work done. Its first report
        says when it really began (a job may wait in an engine's queue after it was sent)."""
        with self._lock:
            job = self._running.get(token)
            if job is None:
                return
            now = self._clock()
            if token not in self._reported:
                self._running[token] = (job[0], now)
            before = self._reported.get(token, (0.0, now))[0]
            self._reported[token] = (max(before, fraction), now)

    def finish(self, token: int) -> None:
        """The job ``token`` ended (a second report of it is ignored)."""
        with self._lock:
            self._reported.pop(token, None)
            job = self._running.pop(token, None)
            if job is not None:
                work, began = job
                self._done += work
                self._busy += max(self._clock() - began, 1e-9)

    def ends_with(self, token: int, future: Future[Any]) -> None:
        """The job ``token`` ends when ``future`` completes."""
        future.add_done_callback(lambda _f: self.finish(token))

    @contextmanager
    def job(self, work: float) -> Iterator[None]:
        """Count the body as one job (encoding in this process), its reports heard here."""
        token = self.start(work)
        self.advance(token, 0.0)

        def heard(fraction: float) -> None:
            self.advance(token, fraction)
            self.tick()

        try:
            with reporting_to(heard):
                yield
        finally:
            self.finish(token)

    def tick(self) -> None:
        """Call ``on_tick`` if :data:`TICK_S` have passed since the last call, or if an ETA is
        known and none has been drawn yet (from the thread that draws the progress)."""
        if self.on_tick is None:
            return
        due = self._clock() - self._ticked >= TICK_S
        if due or (not self._eta_drawn and self.eta_s() is not None):
            self.ticked()
            self.on_tick()

    def ticked(self) -> None:
        """Progress was just drawn: the next tick is :data:`TICK_S` from now."""
        self._ticked = self._clock()
        self._eta_drawn = self._eta_drawn or self.eta_s() is not None

    def eta_s(self) -> float | None:
        """Seconds left: the work not yet done at one slot's measured rate times the slots,
        the running jobs credited with what that rate did in their time so far (and never
        less than the longest running job's rest); None until some work is done."""
        with self._lock:
            done = self._done
            busy = self._busy
            for token, (fraction, when) in self._reported.items():
                work, began = self._running[token]
                done += fraction * work
                busy += max(when - began, 0.0)
            if done <= 0.0 or busy <= 0.0:
                return None
            rate = done / busy
            now = self._clock()
            credit = [min(w, rate * (now - began)) for w, began in self._running.values()]
            left = max(0.0, self.total - self._done - sum(credit))
            rest = [w - c for (w, _), c in zip(self._running.values(), credit, strict=True)]
            return max(left / (rate * max(1, self.slots)), max(rest, default=0.0) / rate)
