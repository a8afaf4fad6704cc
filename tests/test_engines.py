"""The local process pool engine: what its workers start with."""

from __future__ import annotations

import os
import pickle
import signal
import threading
import time
from typing import cast

import numpy as np
import pytest

from helpers import reporting_job, resident_here
from tsog_stream.segment import engines


def _threads_environ() -> dict[str, str | None]:
    """Run in a pool worker: the thread-count variables it started with."""
    return {name: os.environ.get(name) for name in engines.ONE_BLAS_THREAD}


def test_pool_workers_start_with_one_blas_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two workers with two BLAS threads each on two cores spin-waited for each other (a 1M
    SH3 scene 13 % slower): workers start with one BLAS thread, as Dask's do, unless the user
    chose a count; this process's environment is left as it was."""
    for name in engines.ONE_BLAS_THREAD:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    with engines.engine(2, None) as running:
        found = [running.executor.submit(_threads_environ) for _ in range(4)]
        seen = [future.result(timeout=60) for future in found]
    expected = {"OMP_NUM_THREADS": "3", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    assert all(s == expected for s in seen), seen
    assert "OPENBLAS_NUM_THREADS" not in os.environ and "MKL_NUM_THREADS" not in os.environ
    assert os.environ["OMP_NUM_THREADS"] == "3"


def _length(values: list[int]) -> int:
    """Run in a pool worker: what it received."""
    return len(values)


def test_a_handed_over_argument_is_dropped_here_once_sent() -> None:
    """The pool keeps a job's arguments until it ends: a part in flight was held twice. A
    HandOver is dropped when sent, the worker gets the value, and a second send is an error."""
    with engines.engine(2, None) as running:
        handed = engines.HandOver(list(range(1000)))
        assert not handed.sent
        sent = cast(list[int], handed)  # what the worker receives
        assert running.executor.submit(_length, sent).result(timeout=60) == 1000
        assert handed.sent
    with pytest.raises(RuntimeError, match="sent again"):
        pickle.dumps(handed)
    assert pickle.loads(pickle.dumps(engines.HandOver([1, 2]))) == [1, 2]


def test_pool_jobs_reports_reach_the_listener_with_their_tokens() -> None:
    """A 5M scene's first ETA came ~40 s in, with its first finished job: a job's progress
    (its SH palette's) goes back to the parent as it runs, tagged with the job's token."""
    heard: list[tuple[int, float]] = []
    with engines.engine(2, None, lambda token, done: heard.append((token, done))) as running:
        futures = [running.submit(token, reporting_job, 4) for token in (7, 8, 9)]
        pids = {future.result(timeout=60) for future in futures}
    assert os.getpid() not in pids
    for token in (7, 8, 9):  # each job: its start, then its reports in order
        assert [done for t, done in heard if t == token] == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert len(heard) == 15


_HELD: list[np.ndarray] = []


def _holding(mib: int) -> float:
    """Run on a worker: hold ``mib`` MiB (touched) past the job's end; the resident MiB."""
    _HELD.append(np.ones(mib << 17))
    return resident_here()


def test_each_job_runs_in_a_process_of_its_own_that_leaves_with_its_memory() -> None:
    """Memory by process: a worker is replaced after its job, so what a job held (here 120
    MiB it never let go) goes back to the system with it, and the next job starts in another
    process on a fresh heap."""
    with engines.engine(1, None) as running:
        kept = running.submit(1, _holding, 120).result(timeout=60)
        after = running.submit(2, resident_here).result(timeout=60)
        pids = {running.submit(3 + n, reporting_job, 1).result(timeout=60) for n in range(3)}
    assert after < kept - 80
    assert len(pids) == 3 and os.getpid() not in pids


def test_small_jobs_share_a_process_until_they_held_enough() -> None:
    """A process start costs about a second of a core: jobs much smaller than
    REPLACE_AFTER_GAUSSIANS share a worker until together they held about that many."""
    assert engines.jobs_per_process(engines.REPLACE_AFTER_GAUSSIANS * 3) == 1
    assert engines.jobs_per_process(engines.REPLACE_AFTER_GAUSSIANS) == 1
    assert engines.jobs_per_process(engines.REPLACE_AFTER_GAUSSIANS // 4) == 4
    assert engines.jobs_per_process(0) == engines.REPLACE_AFTER_GAUSSIANS
    largest = engines.REPLACE_AFTER_GAUSSIANS // 2  # two jobs per process
    with engines.engine(1, None, largest_job=largest) as running:
        pids = [running.submit(n, reporting_job, 1).result(timeout=60) for n in range(4)]
    assert pids[0] == pids[1] != pids[2] == pids[3]


def test_jobs_run_here_report_nothing_without_a_listener() -> None:
    """Outside a pool worker (a Dask worker, this process) a job runs as it is."""
    assert engines.run_reported(3, reporting_job, 2) == os.getpid()


def test_a_sigint_while_workers_may_start_is_delivered_after_the_start() -> None:
    """Ctrl-C taken by another thread while this one spawned a worker ran the handler here,
    mid-spawn: the half-started worker printed "EOFError: Ran out of input". The section now
    notes the signal and delivers it once the start is over."""
    seen: list[str] = []
    go = threading.Event()

    def press_ctrl_c() -> None:  # a thread started before the section: SIGINT not blocked
        go.wait(10)
        os.kill(os.getpid(), signal.SIGINT)

    previous = signal.signal(signal.SIGINT, lambda _signum, _frame: seen.append("handler"))
    presser = threading.Thread(target=press_ctrl_c)
    presser.start()
    try:
        with engines.sigint_blocked():
            go.set()
            presser.join(10)
            time.sleep(0.2)  # time for a handler to run here, were it to
            seen.append("start over")
        seen.append("after")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert seen == ["start over", "handler", "after"]


def test_workers_are_one_per_core_as_far_as_memory_holds_them() -> None:
    gib = engines.WORKER_MEMORY
    assert engines.workers_for(8, None) == 8  # memory unknown: the cores alone
    assert engines.workers_for(8, 100 * gib) == 8
    assert engines.workers_for(8, 3 * gib + gib // 2) == 3  # three workers fit, not four
    assert engines.workers_for(8, 0) == 1  # one at least, to do the work at all
    assert engines.workers_for(1, 100 * gib) == 1
