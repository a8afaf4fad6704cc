"""Segmenting on a Dask cluster (issue 20): real LocalClusters of worker processes on
loopback, the container byte-identical to the one a single process writes, and one-line errors
for a scheduler that is not there."""

from __future__ import annotations

import importlib.util
import os
import re
import signal
import socket
import threading
import time
import tracemalloc
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from distributed import Client, LocalCluster

from helpers import reporting_job, wait_until
from peers import Behaviour, Peer, claims, closes, http_error, random_bytes, silent
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.codec.webp import cores_in_use
from tsog_stream.errors import InputError
from tsog_stream.io.ply import write_ply
from tsog_stream.io.sequence import open_sequence
from tsog_stream.machine import usable_cores
from tsog_stream.model import Scene
from tsog_stream.schemas.manifest import ChunkEntry
from tsog_stream.segment import SegmentOptions, engines, segment_scene, segment_sequence
from tsog_stream.segment.scheduler import client_handshake, parse_address, probe_scheduler
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians

OPTIONS = SegmentOptions(window_s=1.0, policy="hybrid", max_pixels=64 * 64, layers=2)
"""Chunks of unequal sizes and two layers (SH-band chunks too)."""
LOOPBACK = {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"}


@pytest.fixture(scope="module")
def scene() -> Scene:
    return generate_scene(SceneSpec(background=3000, objects=4, per_object=300, sh_bands=1))


@pytest.fixture(scope="module")
def reference(scene: Scene, tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The container one process writes."""
    path = tmp_path_factory.mktemp("reference") / "one.tsogs"
    report = segment_scene(scene, path, OPTIONS)
    assert report.chunks >= 5 and any(c.sh_of is not None for c in _chunks(path))
    return path.read_bytes()


def _chunks(path: Path) -> list[ChunkEntry]:
    with open_stream(path) as reader:
        return list(reader.index.manifest.chunks)


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """A running cluster of two single-threaded worker processes, by its scheduler address."""
    with LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=2, threads_per_worker=1, processes=True, **LOOPBACK
    ) as cluster:
        yield str(cluster.scheduler_address)


def test_cli_segment_on_a_cluster_writes_the_same_container(
    scene: Scene, scheduler: str, tmp_path: Path
) -> None:
    """`--cluster ADDRESS`: the jobs run on that cluster's workers, the container is the one
    a single process writes."""
    source = tmp_path / "scene.sog"
    source.write_bytes(bundle_bytes(encode_chunk(scene)))
    argv = ["segment", str(source), "--window", "1s", "--policy", "hybrid", "-q"]
    argv += ["--max-pixels", str(64 * 64), "--layers", "2"]
    paths = {name: tmp_path / f"{name}.tsogs" for name in ("cluster", "one")}
    assert main([*argv, "-o", str(paths["cluster"]), "--cluster", scheduler]) == 0
    assert main([*argv, "-o", str(paths["one"]), "--workers", "1"]) == 0
    assert paths["cluster"].read_bytes() == paths["one"].read_bytes()


def test_a_local_cluster_is_started_for_the_run(
    scene: Scene, reference: bytes, tmp_path: Path
) -> None:
    """``local``: a LocalCluster of --workers processes (one here: the cheapest start)."""
    path = tmp_path / "local.tsogs"
    segment_scene(scene, path, replace(OPTIONS, cluster="local", workers=1))
    assert path.read_bytes() == reference


def _callback_ms(dask_worker: Any) -> dict[str, float]:
    return {name: pc.callback_time for name, pc in dask_worker.periodic_callbacks.items()}


def test_a_local_cluster_s_workers_leave_the_gil_to_the_encoding(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The cluster tsog starts runs its workers without the statistical profiler and with
    the event-loop tick and memory and system monitors at 1 s, 1 s and 5 s (each call takes
    the GIL from the job), and its scheduler ticks at 1 s too. Its workers start with glibc's
    allocator set by environment (one arena, blocks mapped from 4 MiB, trimmed above 64 MiB);
    the process that starts them keeps its own environment, while the cluster runs and after."""
    for name in ("MALLOC_ARENA_MAX", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_"):
        monkeypatch.delenv(name, raising=False)
    before = dict(os.environ)
    with engines.local_cluster(1) as cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        (worker,) = client.run(_callback_ms).values()
        scheduler = client.run_on_scheduler(_callback_ms_of_scheduler)
        allocator = [
            next(iter(client.run(_variable, name).values()))
            for name in ("MALLOC_ARENA_MAX", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
        ]
        assert dict(os.environ) == before
    assert dict(os.environ) == before
    assert allocator == ["1", str(4 << 20), str(64 << 20)]
    assert "profile" not in worker and "profile-cycle" not in worker
    assert (worker["tick"], worker["memory_monitor"], worker["monitor"]) == (1000, 1000, 5000)
    assert scheduler["tick"] == 1000


def _variable(name: str) -> str | None:
    """An environment variable of the process this runs in (``os.environ.get`` sent to a
    worker is a bound method: it takes the sender's environment along and reads that)."""
    return os.environ.get(name)


def _callback_ms_of_scheduler(dask_scheduler: Any) -> dict[str, float]:
    return _callback_ms(dask_scheduler)


MALFORMED = [
    "0",
    "nan",
    "http://127.0.0.1:8786",
    "udp://127.0.0.1:8786",
    "tcp://host",
    "tcp://127.0.0.1:0",
    "tcp://127.0.0.1:99999",
    "tcp://127.0.0.1:8786/path",
    "tcp://[::1:8786",
    "tcp://[not:an:ip]:8786",
    "tcp://1.2.3.256:8786",
    "tcp://-bad-:8786",
    "tcp://a..b:8786",
    "tcp://127.0.0.1:8786\n",
]
"""Addresses refused as written, before any name is looked up or any work done."""


@pytest.mark.parametrize("address", MALFORMED)
def test_a_malformed_cluster_address_is_one_line_before_any_work(
    address: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["segment", str(tmp_path / "missing.sog"), "-o", str(tmp_path / "o.tsogs")]
    assert main([*argv, "--cluster", address]) != 0
    err = capsys.readouterr().err
    assert "--cluster" in err and "scheduler address" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


CONNECT_S = 1.0
"""The connect timeout of the tests of peers that are not schedulers (10 s by default)."""
NOT_SCHEDULERS: dict[str, tuple[Behaviour, str]] = {
    "an HTTP server": (http_error, "an HTTP server answered, not a scheduler"),
    "random bytes": (random_bytes, "its first message claims "),
    "a claim of 2 GiB": (claims(2 << 30), "claims 2147483648 bytes, a handshake has 16 to 4096"),
    "a claim too small": (claims(3), "claims 3 bytes"),
    "a server that says nothing": (silent, f"no Dask handshake within {CONNECT_S:g} s"),
    "a server that hangs up": (closes, "closed the connection without a handshake"),
}
"""What may listen at a scheduler address that is not a scheduler, and what the error says."""


def _cli_segment_error(
    address: str, source: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> tuple[str, float]:
    """``tsog segment --cluster address``: its one error line and how long it took."""
    out = tmp_path / "o.tsogs"
    began = time.monotonic()
    code = main(["segment", str(source), "-o", str(out), "-q", "--cluster", address])
    took = time.monotonic() - began
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == [source.name]
    return err.strip(), took


@pytest.fixture(scope="module")
def scene_file(scene: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("input") / "scene.sog"
    path.write_bytes(bundle_bytes(encode_chunk(scene)))
    return path


@pytest.mark.parametrize("peer", list(NOT_SCHEDULERS))
def test_a_peer_that_is_not_a_scheduler_is_one_line_in_bounded_time(
    peer: str,
    scene_file: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Whatever listens at the address, the run stops with one line naming it within the
    connect timeout (Dask's own client would hang on silence or take the size a peer claims)."""
    behaviour, expected = NOT_SCHEDULERS[peer]
    monkeypatch.setattr(engines, "CONNECT_TIMEOUT_S", CONNECT_S)
    source = tmp_path / scene_file.name
    source.write_bytes(scene_file.read_bytes())
    with Peer(behaviour, lifetime_s=20) as server:
        address = server.address("tcp")
        err, took = _cli_segment_error(address, source, tmp_path, capsys)
        assert server.accepted == 1  # one probe; Dask never connected
    assert err.startswith(f"tsog: error: {address}: cannot reach the Dask scheduler: ")
    assert expected in err and took < 10 * CONNECT_S


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then closed)."""
    with socket.create_server(("127.0.0.1", 0)) as sock:
        return int(sock.getsockname()[1])


UNREACHABLE = {
    "a closed port": ("tcp", "connection refused (nothing listens there)"),
    "tls without Dask's TLS settings": ("tls", "tls:// needs Dask's TLS settings"),
    "ucx without UCX installed": ("ucx", "ucx:// needs UCX support for Dask"),
}


@pytest.mark.parametrize("case", list(UNREACHABLE))
def test_a_scheduler_that_cannot_be_reached_is_one_line_at_once(
    case: str, scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scheme, expected = UNREACHABLE[case]
    if scheme == "ucx" and any(importlib.util.find_spec(m) for m in ("ucp", "distributed_ucxx")):
        pytest.skip("UCX is installed here")
    monkeypatch.setattr(engines, "CONNECT_TIMEOUT_S", CONNECT_S)
    address = f"{scheme}://127.0.0.1:{_closed_port()}"
    began = time.monotonic()
    with pytest.raises(InputError) as caught, engines.engine(1, address):
        pass
    assert time.monotonic() - began < CONNECT_S / 2  # at once: no retrying until the timeout
    assert str(caught.value).startswith(f"{address}: ") and expected in str(caught.value)
    with pytest.raises(InputError, match=re.escape(expected)):
        segment_scene(scene, tmp_path / "o.tsogs", replace(OPTIONS, cluster=address))
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_the_probe_allocates_nothing_from_a_claimed_size() -> None:
    """A peer claiming 2 GiB is refused on its first 8 bytes: the probe's allocations stay
    in kilobytes (Dask's own handshake took the 256 MiB a peer claimed and sent)."""
    client_handshake()  # its imports are not the probe's allocations
    with Peer(claims(2 << 30), lifetime_s=10) as server:
        tracemalloc.start()
        try:
            with pytest.raises(InputError, match="claims 2147483648 bytes"):
                probe_scheduler(parse_address(server.address("tcp")), CONNECT_S)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert peak < 1 << 20


def test_the_probe_lets_a_real_scheduler_through(scheduler: str) -> None:
    """A scheduler's own handshake passes, in well under the timeout."""
    began = time.monotonic()
    probe_scheduler(parse_address(scheduler), CONNECT_S)
    assert time.monotonic() - began < 0.5


def test_window_jobs_of_a_layered_sh_sequence_write_the_same_bytes(tmp_path: Path) -> None:
    """A frame sequence with enough windows for every worker: each job is a window its
    worker reads and cuts itself (layers, SH-band chunks numbered within the window, then
    renumbered here); the container is the one a single process writes."""
    for k in range(4):  # 4 windows: 2 a worker, the least that makes windows the jobs
        write_ply(tmp_path / f"f_{k:02d}.ply", static_gaussians(1500, sh_bands=1, seed=k))
    seq = open_sequence(tmp_path, fps=10.0)
    options = SegmentOptions(window_s=0.1, layers=2, max_pixels=64 * 64)
    paths = {n: tmp_path / f"w{n}.tsogs" for n in (1, 2)}
    for n, path in paths.items():
        segment_sequence(seq, path, replace(options, workers=n))
    chunks = _chunks(paths[2])
    assert {c.node for c in chunks if c.sh_of is not None} == set(range(4))
    assert [c.sh_of for c in chunks if c.sh_of is not None] == [0, 3, 6, 9]  # container ids
    assert len(chunks) == 3 * 4  # base, bands and layer 1 of every window
    assert paths[2].read_bytes() == paths[1].read_bytes()


def _kill_a_busy_worker(address: str, done: threading.Event, killed: list[str]) -> None:
    """SIGKILL the first worker seen running a job (its Nanny starts a new one)."""
    with Client(address, timeout=10) as client:  # type: ignore[no-untyped-call]
        pids = client.run(os.getpid)
        deadline = time.monotonic() + 120
        while not done.is_set() and time.monotonic() < deadline:
            busy = {w: list(keys) for w, keys in client.processing().items() if keys}
            if busy:
                worker, keys = next(iter(busy.items()))
                os.kill(pids[worker], signal.SIGKILL)
                killed.extend(str(k) for k in keys)
                return
            time.sleep(0.01)


def test_a_lost_worker_s_jobs_run_again_and_the_bytes_do_not_change(
    scene: Scene, reference: bytes, scheduler: str, tmp_path: Path
) -> None:
    """A worker killed in the middle of a job: the job runs again elsewhere (Dask reschedules
    it; the cluster's Nanny starts a new worker), the run finishes and the container is the
    one a single process writes. The last test of the module: it kills a shared worker."""
    done, killed = threading.Event(), list[str]()
    killer = threading.Thread(target=_kill_a_busy_worker, args=(scheduler, done, killed))
    killer.start()
    try:
        path = tmp_path / "cluster.tsogs"
        segment_scene(scene, path, replace(OPTIONS, cluster=scheduler))
    finally:
        done.set()
        killer.join(30)
    assert killed, "no job was seen running: nothing was lost"
    assert path.read_bytes() == reference


def test_a_dask_worker_s_codec_threads_are_its_own_threads(scheduler: str) -> None:
    """A job on a worker of one thread encodes on one thread, whatever the machine's cores
    (the machine's count, where the codec would otherwise size its pools, is more here)."""
    if usable_cores() < 2:
        pytest.skip("one usable core: the codec's pools have one thread anyway")
    with engines.engine(2, scheduler) as running:
        futures = [running.submit(token, cores_in_use) for token in range(4)]
        assert [future.result(timeout=60) for future in futures] == [1, 1, 1, 1]


def test_dask_jobs_progress_reaches_the_listener(scheduler: str) -> None:
    """A job's progress (its SH palette's) reaches the client as it runs, as Dask events: the
    ETA of a run on a cluster need not wait for a finished job."""
    heard: list[tuple[int, float]] = []
    with engines.engine(2, scheduler, lambda token, done: heard.append((token, done))) as running:
        futures = [running.submit(token, reporting_job, 4) for token in (7, 8, 9)]
        assert os.getpid() not in {future.result(timeout=60) for future in futures}
        wait_until(lambda: len(heard) >= 15, 20, "the jobs' progress events")  # asynchronous
    for token in (7, 8, 9):  # each job: its start, then its reports in order
        assert [done for t, done in heard if t == token] == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert len(heard) == 15
