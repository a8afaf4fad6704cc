"""The local process pool engine: what its workers start with."""

from __future__ import annotations

import os
import pickle
from typing import cast

import pytest

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
