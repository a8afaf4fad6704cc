"""The encoding meter: ETA by work, parallel jobs credited with the time they have run."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

from tsog_stream.segment.meter import (
    BEFORE_PALETTE,
    TICK_S,
    Meter,
    encode_work,
    palette_progress,
    palette_share,
    report_progress,
    reporting_to,
    share_of,
)


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_sh_bands_weigh_by_their_coefficients() -> None:
    assert encode_work(1000, 0) == 1000
    sh3 = encode_work(1000, 15) / encode_work(1000, 0)
    assert 4.5 <= sh3 <= 6.1  # SH3 against SH0: measured 4.5x (400k) to 6.1x (833k), random
    assert encode_work(1000, 0) < encode_work(1000, 3) < encode_work(1000, 8) < sh3 * 1000


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
    meter.ends_with(meter.start(1.0), future)
    clock.now = 4.0
    assert meter.eta_s() is None
    future.set_result(1)
    assert meter.eta_s() == pytest.approx(4.0)  # one unit left at 0.25 units/s, one slot
    with meter.job(1.0):
        clock.now = 8.0
    assert meter.eta_s() == pytest.approx(0.0)


def test_running_jobs_reports_give_an_eta_before_any_job_ends() -> None:
    """The first ETA of a 5M scene came with its first finished job, ~40 s in: a running
    job's report (its SH palette's progress) gives the rate from the first seconds."""
    clock = Clock()
    meter = Meter(8.0, clock=clock)
    meter.slots = 2
    first, second = meter.start(2.0), meter.start(2.0)
    clock.now = 3.0  # sent, but waiting in the engine's queue until now
    meter.advance(first, 0.0)
    meter.advance(second, 0.0)
    assert meter.eta_s() is None  # nothing done yet: no rate
    clock.now = 5.0
    meter.advance(first, 0.25)  # half a unit in 2 s of running (the queue's 3 s not counted)
    meter.advance(second, 0.1)
    meter.advance(second, 0.05)  # an older report arriving late never moves a job back
    rate = (0.5 + 0.2) / (2.0 + 2.0)
    credit = 2 * min(2.0, rate * 2.0)
    assert meter.eta_s() == pytest.approx((8.0 - credit) / (2 * rate))
    meter.finish(first)
    meter.advance(first, 0.9)  # a report heard after the job ended is ignored
    assert meter.eta_s() is not None


def test_ticks_come_every_tick_period_and_after_drawing_none_is_due() -> None:
    clock = Clock()
    meter = Meter(1.0, clock=clock)
    ticks: list[float] = []
    meter.on_tick = lambda: ticks.append(clock.now)
    meter.tick()
    clock.now = TICK_S - 0.1
    meter.tick()
    assert ticks == []
    clock.now = TICK_S
    meter.tick()
    assert ticks == [TICK_S]
    clock.now = 2 * TICK_S - 0.5
    meter.ticked()  # a chunk was just drawn
    clock.now = 2 * TICK_S
    meter.tick()
    assert ticks == [TICK_S]


def test_the_first_eta_is_drawn_as_soon_as_it_is_known() -> None:
    """Ticks wait TICK_S between draws, except for the first ETA: drawn at the first tick
    after a job's report gives a rate (it waited up to TICK_S more), then every TICK_S."""
    clock = Clock()
    meter = Meter(4.0, clock=clock)
    ticks: list[tuple[float, float | None]] = []
    meter.on_tick = lambda: ticks.append((clock.now, meter.eta_s()))
    token = meter.start(4.0)
    meter.advance(token, 0.0)
    clock.now = 1.0
    meter.tick()
    assert ticks == []  # no rate yet, no draw due
    meter.advance(token, 0.25)
    meter.tick()
    assert len(ticks) == 1 and ticks[0][0] == 1.0
    assert ticks[0][1] == pytest.approx(3.0)  # one unit a second, three left
    clock.now = 2.0
    meter.advance(token, 0.5)
    meter.tick()
    assert len(ticks) == 1  # the next draw is TICK_S after the first
    clock.now = 1.0 + TICK_S
    meter.tick()
    assert [when for when, _ in ticks] == [1.0, 1.0 + TICK_S]


def test_a_job_in_this_process_reports_to_its_meter_and_ticks() -> None:
    clock = Clock()
    meter = Meter(4.0, clock=clock)
    ticks: list[float | None] = []
    meter.on_tick = lambda: ticks.append(meter.eta_s())
    with meter.job(4.0):
        clock.now = TICK_S
        report_progress(0.5)  # two units in TICK_S seconds
    assert ticks == [pytest.approx(TICK_S)]
    report_progress(0.7)  # outside any job: nobody hears it, nothing breaks


def test_shares_map_a_parts_progress_into_its_window_job() -> None:
    heard: list[float] = []
    with reporting_to(heard.append):
        with share_of(0.25, 0.5):
            report_progress(0.5)
            report_progress(2.0)  # clamped to the part's end
        report_progress(-1.0)
    assert heard == [0.5, 0.75, 0.0]


def test_the_palette_share_follows_the_cost_model() -> None:
    assert palette_share(0) == 0.0
    sh3 = encode_work(1, 15) / encode_work(1, 0)
    assert palette_share(15) == pytest.approx(1 - 1 / sh3)  # the rest costs what SH0 does


def test_a_job_s_progress_puts_part_of_the_rest_before_and_part_after_its_palette() -> None:
    """The images are encoded after the palette: a job whose palette is done has not done
    all its work (its first reports ran ahead of its time when it had)."""
    rest = 1 - palette_share(15)
    assert palette_progress(15, 0.0) == pytest.approx(rest * BEFORE_PALETTE)
    assert palette_progress(15, 1.0) == pytest.approx(1 - rest * (1 - BEFORE_PALETTE))
    assert 0 < BEFORE_PALETTE < 1
    steps = [palette_progress(15, f) for f in np.linspace(0, 1, 11)]
    assert steps == sorted(steps)


def test_reports_are_plain_floats() -> None:
    """Dask sends reports as msgpack, which refuses numpy scalars (the job would fail)."""
    heard: list[float] = []
    with reporting_to(heard.append):
        report_progress(np.float64(0.25))
    assert heard == [0.25] and type(heard[0]) is float
