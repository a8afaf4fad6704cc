"""Where chunks are encoded: one process, a local process pool, or a Dask cluster.

Every engine is a :class:`concurrent.futures.Executor` with a number of jobs to keep in flight;
the segmenter writes the results in its own order, so the container is byte-identical whichever
engine made it. Dask (the ``tsog-stream[cluster]`` extra) is imported only when asked for
(docs/design/segmenter.md, "Parallel encoding").
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import threading
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any, Final, Generic, TypeVar

from ..codec.webp import use_cores
from ..errors import InputError
from ..machine import available_memory, usable_cores
from .meter import reporting_to
from .scheduler import parse_address, probe_scheduler

LOCAL_CLUSTER = "local"
"""``--cluster local``: a Dask LocalCluster on this machine, one single-threaded worker process
per ``--workers``."""
LISTEN_POLL_S = 0.2
"""How often the thread hearing the pool's job reports looks whether the pool has ended."""
CONNECT_TIMEOUT_S = 10.0
"""How long reaching a scheduler may take (its handshake probe, then Dask's connection)."""
JOB_RETRIES = 2
"""Times Dask runs a job again when the worker running it is lost."""
PROGRESS_TOPIC = "tsog-stream-job-progress"
"""The Dask event topic a job's progress goes to the client on: [token, fraction]."""
QUIET_DASK: dict[str, object] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.nanny.pre-spawn-environ.MALLOC_ARENA_MAX": 1,
    "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": 4 << 20,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 64 << 20,
}
"""Dask settings of the clusters tsog starts (``--cluster local``): no profiler, slower ticks
and monitors (each takes the GIL from the encoding thread), and glibc's allocator set by
environment in its workers (why, measured: docs/design/cluster.md)."""
WORKER_MEMORY: Final = 5 << 28
"""Memory (1.25 GiB) a local encoder process is allowed for when choosing how many to start (it
holds one job of at most MAX_CHUNK_GAUSSIANS Gaussians at a time)."""
REPLACE_AFTER_GAUSSIANS: Final = 1 << 20
"""A local worker process is replaced once the jobs it ran held about this many Gaussians, so
the system takes back all they held (smaller jobs share a process: its start costs more)."""


def jobs_per_process(largest_job: int) -> int:
    """Jobs a local worker runs before it is replaced (REPLACE_AFTER_GAUSSIANS), for jobs of
    at most ``largest_job`` Gaussians."""
    return max(1, REPLACE_AFTER_GAUSSIANS // max(1, largest_job))


def default_workers() -> int:
    """``tsog segment``'s encoder processes when ``--workers`` is not given: one per core this
    process may use, fewer when the memory it may still take holds fewer WORKER_MEMORY."""
    return workers_for(usable_cores(), available_memory())


def workers_for(cores: int, memory: int | None) -> int:
    """One worker per core, as many as ``memory`` bytes hold WORKER_MEMORY (at least one;
    unbounded by memory when it is unknown)."""
    if memory is None:
        return max(1, cores)
    return max(1, min(cores, memory // WORKER_MEMORY))


T = TypeVar("T")
ONE_BLAS_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""The environment a pool worker starts with unless the user set these (as Dask's nanny does):
workers' BLAS threads spin-wait for each other's cores."""


class HandOver(Generic[T]):
    """A job argument this process lets go of when it is sent (executors keep a job's arguments
    until it ends); the worker receives the value itself, and a second send is an error."""

    def __init__(self, value: T) -> None:
        self._value: T | None = value

    @property
    def sent(self) -> bool:
        """Whether the value has been sent (and dropped here)."""
        return self._value is None

    def __reduce__(self) -> tuple[Callable[[T], T], tuple[T]]:
        value, self._value = self._value, None
        if value is None:
            raise RuntimeError("a job argument handed over once was sent again")
        return _received, (value,)


def _received(value: T) -> T:
    """What a :class:`HandOver` becomes in the worker: its value."""
    return value


def check_cluster(value: str) -> str:
    """``local`` or a scheduler address (``tcp://host:8786``); InputError otherwise."""
    if value != LOCAL_CLUSTER:
        parse_address(value)
    return value


Listener = Callable[[int, float], None]
"""Hears a running job's report: (its token, fraction done)."""


@dataclass
class _Worker:
    """What this process knows as a pool worker."""

    reports: Connection | None = None
    """Where its jobs' progress goes back to the parent (None outside a pool worker)."""


_WORKER = _Worker()


@dataclass
class Engine:
    """An executor for encode jobs, how many to keep in flight, and how a job runs there
    (:func:`run_reported` or :func:`run_on_dask`)."""

    executor: Executor
    slots: int
    runner: Callable[..., Any]

    def submit(self, token: int, job: Callable[..., T], *args: Any) -> Future[T]:
        """Run ``job(*args)`` as the job ``token``: its :func:`meter.report_progress` calls
        reach the engine's listener."""
        with sigint_blocked():
            return self.executor.submit(self.runner, token, job, *args)


def run_reported(token: int, job: Callable[..., T], *args: Any) -> T:
    """A job in a pool worker, its progress sent back as (token, fraction) over the pool's
    report pipe (run as it is where there is none)."""
    reports = _WORKER.reports
    if reports is None:
        return job(*args)
    return _reporting(job, args, lambda fraction: reports.send((token, fraction)))


def run_on_dask(token: int, job: Callable[..., T], *args: Any) -> T:
    """A job on a Dask worker, its progress sent to the client as events of
    :data:`PROGRESS_TOPIC`; the codec's thread pools there take as many cores as the worker
    has threads (not every core of the machine in each worker)."""
    from distributed import get_worker  # noqa: PLC0415 - an optional extra

    worker = get_worker()
    use_cores(min(worker.state.nthreads, usable_cores()))
    return _reporting(
        job, args, lambda fraction: worker.log_event(PROGRESS_TOPIC, [token, fraction])
    )


def _reporting(job: Callable[..., T], args: tuple[Any, ...], send: Callable[[float], None]) -> T:
    """``job(*args)`` with its start and its reports sent by ``send``."""
    send(0.0)
    with reporting_to(send):
        return job(*args)


@contextlib.contextmanager
def engine(
    workers: int,
    cluster: str | None,
    listener: Listener | None = None,
    *,
    largest_job: int | None = REPLACE_AFTER_GAUSSIANS,
) -> Iterator[Engine]:
    """The engine for ``workers`` local processes, or for the Dask cluster ``cluster``; an
    error or Ctrl-C in the body stops it at once (queued jobs dropped, running ones
    abandoned). ``listener`` hears the jobs' progress reports (on another thread). A local
    process is replaced after :func:`jobs_per_process` jobs of at most ``largest_job``
    Gaussians, so memory is bounded by process; None keeps each process for the engine's life
    (jobs that arrive one at a time, as a live event's windows: a replacement would start
    between two of them, and Python 3.11's pool can then wait for a worker that never comes)."""
    if cluster is not None:
        with _dask_engine(workers, check_cluster(cluster), listener) as found:
            yield found
        return
    context = multiprocessing.get_context("spawn")
    reader, writer = context.Pipe(duplex=False)
    with _children_environ(ONE_BLAS_THREAD), _listening(reader, writer, listener):
        pool = ProcessPoolExecutor(
            max_workers=workers,
            mp_context=context,
            initializer=_start_worker,
            initargs=(writer,),
            max_tasks_per_child=None if largest_job is None else jobs_per_process(largest_job),
        )
        try:
            yield Engine(pool, workers, run_reported)
        except BaseException:
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)


def _start_worker(reports: Connection) -> None:
    """A pool worker's start: Ctrl-C ignored (the parent handles it), job reports written to
    ``reports`` (one pipe for all: a write under PIPE_BUF is never interleaved, so no lock),
    the codec's pools sized for the cores this process may use."""
    _ignore_interrupts()
    _WORKER.reports = reports
    use_cores(usable_cores())


@contextlib.contextmanager
def _listening(reader: Connection, writer: Connection, listener: Listener | None) -> Iterator[None]:
    """A thread handing the workers' reports to ``listener`` while the body runs (and those
    still unread when it ends); both ends of the pipe closed after."""
    stop = threading.Event()

    def listen() -> None:
        with contextlib.suppress(EOFError, OSError, pickle.UnpicklingError):
            while not stop.is_set() or reader.poll(0):  # what was sent is heard
                if reader.poll(LISTEN_POLL_S):
                    report = reader.recv()
                    if listener is not None:
                        listener(*report)

    thread = threading.Thread(target=listen, name="tsog-job-reports", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        reader.close()
        writer.close()


@contextlib.contextmanager
def _children_environ(defaults: dict[str, str]) -> Iterator[None]:
    """Processes started in the body inherit ``defaults`` for the variables not already set;
    this process's environment is restored after."""
    added = {name: value for name, value in defaults.items() if name not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


@contextlib.contextmanager
def _dask_engine(workers: int, cluster: str, listener: Listener | None) -> Iterator[Engine]:
    """A Dask client's executor (jobs retried on a lost worker), on a LocalCluster of
    ``workers`` processes or on the scheduler at ``cluster``; as many jobs in flight as the
    cluster has worker threads; ``listener`` hears the jobs' progress events."""
    try:
        from distributed import Client  # noqa: PLC0415 - an optional extra
    except ImportError:
        raise InputError(
            "needs Dask: pip install 'tsog-stream[cluster]'", where="--cluster"
        ) from None
    with contextlib.ExitStack() as stack:
        address: Any = cluster
        if cluster == LOCAL_CLUSTER:
            address = stack.enter_context(local_cluster(workers))
        else:  # Dask's client trusts the peer: only a scheduler that answers gets that far
            probe_scheduler(parse_address(cluster), CONNECT_TIMEOUT_S)
        try:
            client = stack.enter_context(
                Client(address, timeout=CONNECT_TIMEOUT_S)  # type: ignore[no-untyped-call]
            )
        except Exception as exc:  # whatever Dask raises on its way in, not a traceback
            why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
            raise InputError(f"cannot reach the Dask scheduler: {why}", where=cluster) from None
        if listener is not None:
            client.subscribe_topic(PROGRESS_TOPIC, lambda event: listener(*event[1]))
        threads = sum(client.nthreads().values()) or 1
        executor = client.get_executor(retries=JOB_RETRIES, pure=False)
        with warnings.catch_warnings():
            # a scene in memory sends each job its Gaussians: that is the design, not a mistake
            warnings.filterwarnings("ignore", "Sending large graph", UserWarning)
            try:
                yield Engine(executor, threads, run_on_dask)
            except BaseException:
                executor.shutdown(wait=False)
                raise


@contextlib.contextmanager
def local_cluster(workers: int) -> Iterator[Any]:
    """A Dask LocalCluster of ``workers`` single-threaded worker processes on loopback (its
    dashboard on any free port), started with :data:`QUIET_DASK`."""
    import dask  # noqa: PLC0415 - an optional extra
    from distributed import LocalCluster  # noqa: PLC0415

    with _environ_kept(), dask.config.set(QUIET_DASK):
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address="127.0.0.1:0",
            host="127.0.0.1",
        )
    with _environ_kept(), cluster:  # a worker started again sets them again
        yield cluster


@contextlib.contextmanager
def _environ_kept() -> Iterator[None]:
    """This process's environment as it was before the body, after it (Dask's nanny leaves its
    workers' pre-spawn variables in it, for every later child to inherit)."""
    before = dict(os.environ)
    try:
        yield
    finally:
        for name in [name for name in os.environ if name not in before]:
            del os.environ[name]
        os.environ.update(before)


def _stop_pool(pool: ProcessPoolExecutor, grace_s: float = 5.0) -> None:
    """Stop a pool after Ctrl-C or an error: queued jobs dropped, workers terminated and joined
    (waiting for running jobs after a KeyboardInterrupt can hang). The worker list is the
    executor's private ``_processes``."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        worker.terminate()
    for worker in workers:
        worker.join(grace_s)
        if worker.is_alive():
            worker.kill()
            worker.join(grace_s)


@contextlib.contextmanager
def sigint_blocked() -> Iterator[None]:
    """SIGINT held (not lost) while this thread may start worker processes, then delivered: a
    worker inherits the blocked mask until :func:`_ignore_interrupts`, and the handler only
    notes a signal another thread took (it would cut a spawn's start-up data short)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may set handlers (and handlers run only there)
        return
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: held.append(signum))
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)
        if held:
            signal.raise_signal(signal.SIGINT)


def _ignore_interrupts() -> None:
    """Workers ignore SIGINT (a terminal's Ctrl-C reaches the whole group): the parent alone
    handles it. One held since the worker started is discarded on unblocking."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
