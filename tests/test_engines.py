"""The local process pool engine: what its workers start with."""

from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing
import os
import pickle
import signal
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import cast

import numpy as np
import pytest

from helpers import heap_holes_left, reporting_job, resident_here
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


def test_a_worker_s_job_starts_on_the_heap_the_last_one_freed_handed_back() -> None:
    """A worker kept ~100 MiB its last 500k window had freed (heap holes glibc does not
    return by itself) under its next window's peak: each job starts after they are handed
    back to the system."""
    with engines.engine(1, None) as running:
        kept = running.submit(1, heap_holes_left, 120).result(timeout=60)
        after = running.submit(2, resident_here).result(timeout=60)
    assert after < kept - 80  # measured: 120 MiB less (without the release: none)


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


def _arenas_after_threads(threads: int = 4) -> int:
    """Run in a fresh process: glibc's arenas once ``threads`` threads have each allocated
    small arrays at the same time (``malloc_info`` writes one <heap> per arena)."""
    ready = threading.Barrier(threads)

    def allocate() -> None:
        held = [np.ones(2048) for _ in range(64)]  # 16 KiB each: from an arena, not mmap
        ready.wait(timeout=30)
        del held

    started = [threading.Thread(target=allocate) for _ in range(threads)]
    for thread in started:
        thread.start()
    for thread in started:
        thread.join()
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    libc.fopen.restype = ctypes.c_void_p
    libc.fopen.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    libc.fclose.argtypes = [ctypes.c_void_p]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "malloc.xml"
        stream = libc.fopen(str(path).encode(), b"w")
        libc.malloc_info(0, stream)
        libc.fclose(stream)
        return path.read_text().count("<heap nr=")


def test_pool_workers_keep_freed_memory_in_one_arena(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each thread of a worker (the job's, the codec's pools) kept freed memory in an arena
    of its own that the others could not reuse (the 1M scene's largest job: 382 against 338
    MiB): pool workers start with one arena, which a plain spawned process does not have.
    (A Dask nanny leaves its workers' variables in the environment of the process that
    started it, MALLOC_ARENA_MAX among them.)"""
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    plain = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    with plain:
        assert plain.submit(_arenas_after_threads).result(timeout=60) > 1
    with engines.engine(1, None) as running:
        assert running.executor.submit(_arenas_after_threads).result(timeout=60) == 1
