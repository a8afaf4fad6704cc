"""How far encoding has got and how long it has left, measured in work, not chunks.

Chunks differ a lot in cost (a chunk with an SH palette costs ~15x one without, measured on
1M Gaussians: 36.6 s against 2.5 s) and parallel jobs finish in bursts, so counting written
chunks gave ETAs off by 2-3x (a 5M scene: 220 s announced after its first chunk, 85 s left in
fact). The meter weighs each job by :func:`encode_work`, learns the rate of one worker slot
from the jobs that finished, and credits the jobs still running with the time they have run.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from typing import Any

SH_COST_PER_COEFF = 1.0
"""A Gaussian's encode cost per SH coefficient beyond DC (an RGB triple), in units of a
Gaussian without SH: the palette's distance work grows with the vector's length (SH3, 15
coefficients: 16x; measured 14.6x)."""

Clock = Callable[[], float]


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
        self._done = 0.0
        self._busy = 0.0
        self._next = 0

    def start(self, work: float) -> int:
        """A job of ``work`` began now; returns its token for :meth:`finish`."""
        with self._lock:
            token = self._next
            self._next += 1
            self._running[token] = (work, self._clock())
            return token

    def finish(self, token: int) -> None:
        """The job ``token`` ended (a second report of it is ignored)."""
        with self._lock:
            job = self._running.pop(token, None)
            if job is not None:
                work, began = job
                self._done += work
                self._busy += max(self._clock() - began, 1e-9)

    def track(self, future: Future[Any], work: float) -> None:
        """Count ``future`` as a job of ``work`` from now until it completes."""
        token = self.start(work)
        future.add_done_callback(lambda _f: self.finish(token))

    @contextmanager
    def job(self, work: float) -> Iterator[None]:
        """Count the body as one job (encoding in this process)."""
        token = self.start(work)
        try:
            yield
        finally:
            self.finish(token)

    def eta_s(self) -> float | None:
        """Seconds left: the work not yet done at one slot's measured rate times the slots,
        the running jobs credited with what that rate did in their time so far (and never
        less than the longest running job's rest); None until a job has finished."""
        with self._lock:
            if self._done <= 0.0:
                return None
            rate = self._done / self._busy
            now = self._clock()
            credit = [min(w, rate * (now - began)) for w, began in self._running.values()]
            left = max(0.0, self.total - self._done - sum(credit))
            rest = [w - c for (w, _), c in zip(self._running.values(), credit, strict=True)]
            return max(left / (rate * max(1, self.slots)), max(rest, default=0.0) / rate)
