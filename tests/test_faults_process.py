"""Faults of real processes (issue 6, "Faults"): a server killed mid-transfer and restarted,
and ``tsog segment`` interrupted by SIGINT / SIGKILL or a full disk.

Every wait is bounded (polling with a deadline); every process started here is killed in a
``finally``.
"""

from __future__ import annotations

import asyncio
import errno
import hashlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import pytest

from helpers import free_port, live_processes, wait_until
from tsog_stream.cli.main import main
from tsog_stream.client import StreamClient, open_stream
from tsog_stream.client.http_options import HttpOptions
from tsog_stream.client.http_source import HttpSource
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.container import writer
from tsog_stream.container.header import PREFIX_SIZE
from tsog_stream.errors import SourceError
from tsog_stream.io import files
from tsog_stream.io.chunks import write_chunk_files
from tsog_stream.model import Gaussians
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene

TSOG = [sys.executable, "-m", "tsog_stream.cli.main"]
NAMES = ("means", "scales", "quats", "opacities", "sh0", "shN")


def same(a: Gaussians, b: Gaussians) -> bool:
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in NAMES)


def listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
    except OSError:
        return False
    return True


def stop(proc: subprocess.Popen[bytes]) -> None:
    """Kill a process this test started (if still running) and reap it."""
    if proc.poll() is None:
        proc.kill()
    proc.wait(10)


# ---------------------------------------------------------------- server killed mid-transfer


def send_buffer_max() -> int:
    """The largest TCP send buffer the kernel auto-tunes to (tcp_wmem max; 4 MiB if unknown)."""
    try:
        return int(Path("/proc/sys/net/ipv4/tcp_wmem").read_text().split()[2])
    except (OSError, IndexError, ValueError):
        return 4 << 20


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A container of one chunk half again as large as a server's kernel send buffer can grow
    (a killed server's queued bytes are still delivered, and loopback auto-tunes the buffer to
    tcp_wmem's max, 4 MiB here), so a kill really cuts the body short. About 13 bytes per
    Gaussian without SH bands (2.1x the buffer in 5 s; with SH3's palette fit, 1.9x took 17 s)."""
    root = tmp_path_factory.mktemp("served")
    background = max(80_000, 2 * send_buffer_max() // 12)
    spec = SceneSpec(background=background, objects=2, per_object=500, duration=2.0, sh_bands=0)
    options = SegmentOptions(window_s=2.0, policy="duplicate", layers=1)  # one big chunk
    segment_scene(generate_scene(spec), root / "big.tsogs", options)
    return root / "big.tsogs"


def serve(root: Path, port: int) -> subprocess.Popen[bytes]:
    """``tsog serve`` as a real process on ``port``."""
    return subprocess.Popen(
        [*TSOG, "serve", str(root), "--port", str(port), "-q"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def small_window_session(log: list[dict[str, str]]) -> aiohttp.ClientSession:
    """A session whose sockets have a fixed 16 KiB receive buffer (so a killed server has
    not already pushed the whole body into the kernel) and which records request headers."""

    def make_socket(addr: Any) -> socket.socket:
        family, kind, proto, _, _ = addr
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 * 1024)
        return sock

    async def on_start(_s: Any, _c: Any, params: aiohttp.TraceRequestStartParams) -> None:
        log.append(dict(params.headers))

    trace = aiohttp.TraceConfig()
    trace.on_request_start.append(on_start)
    connector = aiohttp.TCPConnector(socket_factory=make_socket)
    return aiohttp.ClientSession(connector=connector, trace_configs=[trace], auto_decompress=False)


@pytest.mark.slow
def test_a_killed_server_is_resumed_from_its_next_instance(big: Path) -> None:
    port = free_port()
    url = f"http://127.0.0.1:{port}/files/{big.name}"
    with open_stream(big) as reader:
        times = [0.5, 1.0, 1.5]
        expected = [reader.frame_at(t) for t in times]
        first = reader.index.manifest.chunks[0]
    assert len(reader.index.manifest.chunks) == 1 and 2 * first.length > 3 * send_buffer_max()
    procs = [serve(big.parent, port)]
    log: list[dict[str, str]] = []
    options = HttpOptions(retries=10, backoff_s=0.05, max_backoff_s=0.5)

    async def kill_midway(source: HttpSource) -> int:
        """SIGKILL the server once 64 KiB of the chunk arrived, start the next instance."""
        deadline = time.monotonic() + 30
        while source.stats.bytes < PREFIX_SIZE + 64 * 1024:
            assert time.monotonic() < deadline, "the transfer never started"
            await asyncio.sleep(0.001)
        received = source.stats.bytes
        procs[0].send_signal(signal.SIGKILL)
        procs[0].wait(10)
        procs.append(serve(big.parent, port))
        return received

    async def run() -> tuple[list[Gaussians], int, str | None]:
        session = small_window_session(log)
        source = HttpSource(url, options, session=session)
        try:
            client = await StreamClient.open(source, coalesce_gap=None)
            killer = asyncio.create_task(kill_midway(source))
            frames = [await client.frame_at(t) for t in times]
            received = await killer
            await client.aclose()
            return frames, received, source.etag
        finally:
            await session.close()

    try:
        wait_until(lambda: listening(port), 30, "tsog serve to listen")
        frames, received, etag = asyncio.run(run())
    finally:
        for proc in procs:
            stop(proc)
    assert all(same(a, b) for a, b in zip(frames, expected, strict=True))
    assert received < PREFIX_SIZE + first.length // 2  # killed well before the body's end
    ranges = [h["Range"] for h in log]
    asked = f"bytes={first.offset}-{first.offset + first.length - 1}"
    assert ranges[:2] == [f"bytes=0-{PREFIX_SIZE - 1}", asked]
    resumed = [r for r in ranges[2:] if r.endswith(f"-{first.offset + first.length - 1}")]
    assert resumed, ranges
    start = int(resumed[-1].removeprefix("bytes=").split("-")[0])
    assert first.offset < start < first.offset + first.length  # only the missing bytes
    assert etag and all(h.get("If-Match") == etag for h in log[1:])


def test_a_server_that_stays_down_fails_within_the_retry_bound(big: Path) -> None:
    port = free_port()
    proc = serve(big.parent, port)
    options = HttpOptions(retries=3, backoff_s=0.05, max_backoff_s=0.1)

    async def run() -> SourceError:
        async with await StreamClient.open(
            f"http://127.0.0.1:{port}/files/{big.name}", http=options
        ) as client:
            stop(proc)
            with pytest.raises(SourceError) as err:
                await client.frame_at(0.5)
            return err.value

    try:
        wait_until(lambda: listening(port), 30, "tsog serve to listen")
        error = asyncio.run(run())
    finally:
        stop(proc)
    assert "failed after 4 attempts" in str(error) and big.name in str(error)


# ---------------------------------------------------------------- segmenter interrupted


@pytest.fixture(scope="module")
def source_chunk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4D scene as a TSOG chunk (.sog) whose segmentation takes a few seconds."""
    path = tmp_path_factory.mktemp("segsrc") / "scene.sog"
    spec = SceneSpec(background=15000, objects=4, per_object=400, duration=3.0, fps=10)
    write_chunk_files(path, encode_chunk(generate_scene(spec)), overwrite=False)
    return path


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def temp_files(folder: Path) -> list[Path]:
    """Every temp file in ``folder`` (outputs' and write probes')."""
    return sorted(folder.glob(".*.tmp"))


def temp_files_of(out: Path) -> list[Path]:
    """The temp files of the output ``out`` only (not the folder's write probe)."""
    return sorted(out.parent.glob(f".{out.name}.*.tmp"))


STREAMING_TSOG = [
    sys.executable,
    "-c",
    "import sys; from tsog_stream.container import writer; writer.COMPACT_MAX = 0; "
    "from tsog_stream.cli.main import main; sys.exit(main(sys.argv[1:]))",
]
"""``tsog`` writing every container with the 16 KiB prefix, its payloads streamed to disk as
they are encoded (a compact one is written whole at the end): the file grows, so a signal can
land at any point of the write."""


def segment_cmd(src: Path, out: Path, *, compact: bool = False) -> list[str]:
    tsog = TSOG if compact else STREAMING_TSOG
    return [*tsog, "segment", str(src), "-o", str(out), "--window", "0.25s", "--workers", "2"]


def session_members(sid: int) -> set[int]:
    """Live (non-zombie) processes of session ``sid`` (Linux /proc): after the segmenter
    exits, any left is an orphaned worker."""
    return live_processes(lambda fields: int(fields[3]) == sid)


@pytest.fixture(scope="module")
def full_size(source_chunk: Path, tmp_path_factory: pytest.TempPathFactory) -> int:
    """Bytes of the finished container (to know when a write is 'late')."""
    out = tmp_path_factory.mktemp("segref") / "ref.tsogs"
    done = subprocess.run(
        segment_cmd(source_chunk, out), capture_output=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr
    return out.stat().st_size


POINTS: dict[str, Callable[[int, int], bool]] = {
    "encoding": lambda size, full: True,  # a compact container: the temp file, still empty
    "early": lambda size, full: size >= PREFIX_SIZE,
    "mid": lambda size, full: size > full // 3,
    "late": lambda size, full: size > full * 2 // 3,
}


def interrupt_at(
    src: Path, out: Path, full: int, point: str, sig: signal.Signals
) -> tuple[subprocess.CompletedProcess[bytes], set[int]]:
    """Run ``tsog segment``, send ``sig`` to its process group once the temp file reached
    ``point``; returns the finished process and the pids of its session still alive after."""
    proc = subprocess.Popen(
        segment_cmd(src, out, compact=point == "encoding"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    with proc:  # closes the pipes whatever happens (an unclosed pipe warns in a later test)
        return _interrupt(proc, out, full, point, sig)


def _interrupt(
    proc: subprocess.Popen[bytes], out: Path, full: int, point: str, sig: signal.Signals
) -> tuple[subprocess.CompletedProcess[bytes], set[int]]:
    """The body of interrupt_at, with the process and its pipes owned by the caller."""
    try:

        def reached() -> bool:
            tmp = temp_files_of(out)
            try:
                return bool(tmp) and POINTS[point](tmp[0].stat().st_size, full)
            except FileNotFoundError:
                return False

        wait_until(reached, 120, f"the {point} point of the write")
        assert proc.poll() is None, "finished before it could be interrupted"
        os.killpg(proc.pid, sig)  # like Ctrl-C in a terminal: the whole group
        stdout, stderr = proc.communicate(timeout=60)
        deadline = time.monotonic() + 5  # a worker may take a moment to see its parent gone
        while (left := session_members(proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stop(proc)
        for pid in session_members(proc.pid):
            os.kill(pid, signal.SIGKILL)  # never leave a stray worker behind a failed test
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), left


@pytest.mark.slow
@pytest.mark.parametrize("point", ["encoding", "early", "mid", "late"])
def test_sigint_leaves_nothing_and_exits_130(
    source_chunk: Path, full_size: int, tmp_path: Path, point: str
) -> None:
    before = digest(source_chunk)
    out = tmp_path / "out.tsogs"
    done, left = interrupt_at(source_chunk, out, full_size, point, signal.SIGINT)
    assert done.returncode == 130
    assert done.stderr.decode().strip().splitlines()[-1] == "tsog: interrupted"
    assert b"Traceback" not in done.stderr
    assert not out.exists() and not temp_files(tmp_path)
    assert digest(source_chunk) == before
    assert not left  # no orphan worker processes


@pytest.mark.slow
@pytest.mark.parametrize("point", ["encoding", "early", "late"])
def test_sigkill_leaves_a_temp_file_the_next_run_removes(
    source_chunk: Path, full_size: int, tmp_path: Path, point: str
) -> None:
    before = digest(source_chunk)
    out = tmp_path / "out.tsogs"
    done, _ = interrupt_at(source_chunk, out, full_size, point, signal.SIGKILL)
    assert done.returncode == -signal.SIGKILL
    assert not out.exists()
    (stale,) = temp_files(tmp_path)
    assert digest(source_chunk) == before
    again = subprocess.run(
        segment_cmd(source_chunk, out), capture_output=True, timeout=300, check=False
    )
    assert again.returncode == 0, again.stderr
    assert f"tsog: note: removed {stale}, left by an interrupted run" in again.stderr.decode()
    assert out.stat().st_size == full_size and not temp_files(tmp_path)


def test_leftovers_of_dead_writers_are_removed_and_live_ones_kept(tmp_path: Path) -> None:
    """A writer killed mid-write leaves its temp file, or the folder's write probe when the
    kill lands between the probe's creation and removal: the next run removes both kinds, and
    only those of dead processes and of this output."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = tmp_path / "out.tsogs"
    names = {
        "dead_temp": f".out.tsogs.{dead.pid}-{'a' * 12}.tmp",
        "dead_probe": f"..tsog-write-probe.{dead.pid}-{'b' * 12}.tmp",
        "live_temp": f".out.tsogs.{os.getppid()}-{'c' * 12}.tmp",
        "other_output": f".other.tsogs.{dead.pid}-{'d' * 12}.tmp",
    }
    for name in names.values():
        (tmp_path / name).write_bytes(b"x")
    removed = files.remove_stale_temp_files(out)
    assert sorted(p.name for p in removed) == sorted([names["dead_temp"], names["dead_probe"]])
    left = {p.name for p in tmp_path.iterdir()}
    assert left == {names["live_temp"], names["other_output"]}


def test_a_full_disk_fails_cleanly_naming_the_path(
    source_chunk: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    before = digest(source_chunk)
    out = tmp_path / "out.tsogs"
    add = writer.PayloadWriter.add
    calls = iter(range(1000))

    def full_disk(self: writer.PayloadWriter, payload: bytes) -> tuple[int, int, str]:
        if next(calls) == 2:  # the third chunk: the disk fills up mid-write
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return add(self, payload)

    monkeypatch.setattr(writer.PayloadWriter, "add", full_disk)
    args = ["--window", "1s", "--policy", "hybrid", "--workers", "1", "-q"]  # several chunks
    code = main(["segment", str(source_chunk), "-o", str(out), *args])
    err = capsys.readouterr().err
    assert code == 1
    assert err.strip() == f"tsog: error: {out}: cannot write: No space left on device"
    assert not out.exists() and not temp_files(tmp_path)
    assert digest(source_chunk) == before


def test_a_full_disk_when_finishing_fails_cleanly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out.tsogs"

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", no_space)  # the writer's os
    with (
        pytest.raises(SourceError, match="No space left on device") as err,
        writer.container_file(out) as w,
    ):
        w.add(b"x" * 100)
    assert str(out) in str(err.value)
    assert not out.exists() and not temp_files(tmp_path)
