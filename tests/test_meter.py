"""The encoding meter: ETA by work, parallel jobs credited with the time they have run."""

from __future__ import annotations

from concurrent.futures import Future

import pytest

from tsog_stream.segment.meter import Meter, encode_work


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_sh_bands_weigh_by_their_coefficients() -> None:
    assert encode_work(1000, 0) == 1000
    assert encode_work(1000, 15) == 16 * 1000  # SH3: measured 14.6x on 1M Gaussians
    assert encode_work(1000, 3) == 4 * encode_work(1000, 0)


def test_no_eta_before_a_job_has_finished() -> None:
    clock = Clock()
    meter = Meter(100.0, clock=clock)
    meter.start(50.0)
    clock.now = 30.0
    assert meter.eta_s() is None


def test_jobs_finishing_in_pairs_give_the_time_of_the_work_left() -> None:
    """Five equal jobs on two slots, 10 s each: the old chunk-count ETA said 40 s after the
    first result (4 chunks x 10 s), the time the work takes on two slots is 15 s."""
    clock = Clock()
    meter = Meter(5.0, clock=clock)
    meter.slots = 2
    first, second = meter.start(1.0), meter.start(1.0)
    clock.now = 10.0
    meter.finish(first)
    # the second job has run as long as the first took: credited as done
    assert meter.eta_s() == pytest.approx(15.0)
    meter.finish(second)
    assert meter.eta_s() == pytest.approx(15.0)
    third = meter.start(1.0)
    meter.start(1.0)
    clock.now = 15.0  # both half done
    assert meter.eta_s() == pytest.approx(10.0)
    meter.finish(third)
    meter.finish(third)  # a second report of one job is ignored
    rate = 3.0 / (10.0 + 10.0 + 5.0)  # one slot's units per second, from the finished jobs
    credit = rate * 5.0  # the fourth job has run 5 s
    assert meter.eta_s() == pytest.approx((5.0 - 3.0 - credit) / (2 * rate))


def test_a_long_running_job_is_never_credited_past_its_work() -> None:
    clock = Clock()
    meter = Meter(10.0, clock=clock)
    meter.slots = 2
    quick = meter.start(1.0)
    slow = meter.start(9.0)
    clock.now = 1.0
    meter.finish(quick)  # 1 unit/s on one slot
    clock.now = 5.0  # the slow job: 5 of its 9 units done at that rate
    assert meter.eta_s() == pytest.approx(4.0)  # its rest, alone: no other work is left
    clock.now = 20.0  # slower than measured: credited at most its work, ETA cannot go < 0
    assert meter.eta_s() == pytest.approx(0.0)
    meter.finish(slow)
    assert meter.eta_s() == pytest.approx(0.0)


def test_futures_are_counted_until_they_complete() -> None:
    clock = Clock()
    meter = Meter(2.0, clock=clock)
    future: Future[int] = Future()
    meter.track(future, 1.0)
    clock.now = 4.0
    assert meter.eta_s() is None
    future.set_result(1)
    assert meter.eta_s() == pytest.approx(4.0)  # one unit left at 0.25 units/s, one slot
    with meter.job(1.0):
        clock.now = 8.0
    assert meter.eta_s() == pytest.approx(0.0)
