"""Live streams (issue 57): frames written into a folder, published window by window as an
unpacked stream whose index is republished; the server's blocking reload and cache rules;
the client following the live edge; ends, restarts and object storage.

Frames are small generated ones so that every test encodes in well under a second per window;
latency and keeping up are measured by benchmarks/bench_live.py, not here.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import ThreadedServer, loopback_s3
from tsog_stream.cli.main import main
from tsog_stream.client import StreamClient, follow_live, open_stream
from tsog_stream.errors import InputError, MetaError, SourceError
from tsog_stream.io import arrivals as arrivals_module
from tsog_stream.io.arrivals import SETTLE_S, FrameArrivals
from tsog_stream.io.ply import ply_bytes
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Gaussians
from tsog_stream.schemas.manifest import Live, Manifest, dump_manifest, parse_manifest
from tsog_stream.segment import SegmentOptions, segment_sequence
from tsog_stream.segment import live as live_module
from tsog_stream.segment.live import LiveOptions, LiveReport, run_live
from tsog_stream.server import make_app
from tsog_stream.server.live import RELOAD_POLL_S
from tsog_stream.synthetic import static_gaussians

FPS = 10.0
PER_FRAME = 600
WAIT_S = 60.0
"""The longest any test waits for a live run to do what it is asked (a bound, not a figure)."""


def frames_of(count: int, first: int = 0) -> list[Gaussians]:
    """``count`` distinct small frames (SH degree 1)."""
    return [static_gaussians(PER_FRAME, sh_bands=1, seed=k) for k in range(first, first + count)]


def put_frame(folder: Path, k: int, frame: Gaussians) -> Path:
    """Write frame ``k`` as a capture should: under a hidden name, then renamed in."""
    hidden = folder / f".frame_{k:05d}.partial"
    hidden.write_bytes(ply_bytes(frame))
    target = folder / f"frame_{k:05d}.ply"
    os.replace(hidden, target)
    return target


def write_event(folder: Path, frames: list[Gaussians], *, end: bool = True) -> None:
    """Every frame, then (``end``) the end marker."""
    folder.mkdir(exist_ok=True)
    for k, frame in enumerate(frames):
        put_frame(folder, k, frame)
    if end:
        (folder / "END").write_bytes(b"")


def live(
    source: Path, out: Path | str, *, fps: float = FPS, window_s: float = 1.0, idle_s: float = 5.0
) -> LiveReport:
    """run_live in this process, one worker, short idle."""
    options = LiveOptions(fps=fps, window_s=window_s, idle_s=idle_s, workers=1)
    return run_live(source, str(out), options)


def wait_for(check: Callable[[], bool], what: str) -> None:
    """Poll ``check()`` until it is true, at most WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def published(out: Path) -> Any:
    """The live fields of the index published at ``out`` (parsed JSON)."""
    return json.loads((out / "manifest.json").read_bytes())["live"]


def live_of(manifest: Manifest) -> Live:
    """A live index's live fields (refused if it has none)."""
    assert manifest.live is not None
    return manifest.live


def unfinish(out: Path) -> None:
    """Mark the ended stream at ``out`` as still going (a writer killed before its end)."""
    manifest = parse_manifest((out / "manifest.json").read_bytes())
    fields = live_of(manifest).model_copy(update={"ended": False})
    (out / "manifest.json").write_bytes(dump_manifest(manifest.model_copy(update={"live": fields})))


# --- the frames' arrival -------------------------------------------------------------------


def test_a_frame_counts_once_it_stays_unchanged(tmp_path: Path) -> None:
    put_frame(tmp_path, 0, frames_of(1)[0])
    watch = FrameArrivals(tmp_path)
    assert watch.poll() == []  # seen once: it may still change
    time.sleep(SETTLE_S + 0.05)
    [first] = watch.poll()
    assert (first.index, first.path.name) == (0, "frame_00000.ply")
    assert abs(first.arrived_s - (tmp_path / "frame_00000.ply").stat().st_mtime) < 1e-6


def test_a_frame_being_written_holds_back_the_ones_after_it(tmp_path: Path) -> None:
    frames = frames_of(3)
    put_frame(tmp_path, 0, frames[0])
    growing = tmp_path / "frame_00001.ply"
    growing.write_bytes(ply_bytes(frames[1])[:100])
    put_frame(tmp_path, 2, frames[2])
    watch = FrameArrivals(tmp_path)
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert [a.index for a in watch.poll()] == [0]
    growing.write_bytes(ply_bytes(frames[1]))  # done: the first look after it sees the change
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert [a.path.name for a in watch.poll()] == ["frame_00001.ply", "frame_00002.ply"]
    assert watch.taken == 3


def test_a_frame_short_of_its_size_for_long_is_left_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(arrivals_module, "GIVE_UP_S", 0.4)
    frames = frames_of(2)
    (tmp_path / "frame_00000.ply").write_bytes(ply_bytes(frames[0])[:-1])  # one byte short
    put_frame(tmp_path, 1, frames[1])
    watch = FrameArrivals(tmp_path)
    deadline = time.monotonic() + WAIT_S
    taken: list[str] = []
    while not taken and time.monotonic() < deadline:
        taken = [a.path.name for a in watch.poll()]
        time.sleep(0.05)
    assert taken == ["frame_00001.ply"] and watch.taken == 1
    assert watch.left_out == [
        "left out frame_00000.ply: it stayed short of its declared size for 0.4 s"
    ]


def test_hidden_unnumbered_and_other_files_are_not_frames(tmp_path: Path) -> None:
    for name in (".frame_00000.ply", "notes.txt", "frame_00000.ply.tmp", "cover.ply", "END"):
        (tmp_path / name).write_bytes(b"x")
    watch = FrameArrivals(tmp_path)
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert watch.poll() == [] and watch.ended()


def test_a_late_frame_is_left_out_and_named(tmp_path: Path) -> None:
    frames = frames_of(3)
    put_frame(tmp_path, 1, frames[1])
    watch = FrameArrivals(tmp_path)
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert [a.path.name for a in watch.poll()] == ["frame_00001.ply"]
    put_frame(tmp_path, 0, frames[0])
    put_frame(tmp_path, 2, frames[2])
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert [a.path.name for a in watch.poll()] == ["frame_00002.ply"]
    assert watch.left_out == [
        "left out frame_00000.ply: it arrived after a frame that sorts after it"
    ]


def test_a_restart_skips_the_frames_published(tmp_path: Path) -> None:
    write_event(tmp_path, frames_of(3), end=False)
    watch = FrameArrivals(tmp_path, skip=2)
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    assert [(a.index, a.path.name) for a in watch.poll()] == [(2, "frame_00002.ply")]
    with pytest.raises(InputError, match="fewer than the 5 already published"):
        FrameArrivals(tmp_path, skip=5).poll()


def test_a_frame_of_another_kind_is_refused(tmp_path: Path) -> None:
    put_frame(tmp_path, 0, frames_of(1)[0])
    with zipfile.ZipFile(tmp_path / "frame_00001.sog", "w") as archive:
        archive.writestr("meta.json", "{}")
    watch = FrameArrivals(tmp_path)
    watch.poll()
    time.sleep(SETTLE_S + 0.05)
    with pytest.raises(InputError, match="SOG frame in an event of PLY frames"):
        watch.poll()


def test_a_folder_listing_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(arrivals_module, "MAX_LISTED", 5)
    for k in range(6):
        (tmp_path / f"junk_{k}.bin").write_bytes(b"")
    with pytest.raises(SourceError, match="more than 5 entries"):
        FrameArrivals(tmp_path).poll()


def test_the_source_must_be_a_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="expected a folder"):
        FrameArrivals(tmp_path / "missing")


# --- publishing -----------------------------------------------------------------------------


def test_a_live_stream_shows_the_frames_as_tsog_segment_does(tmp_path: Path) -> None:
    frames = frames_of(25)  # two whole windows of 10 and a last one of 5
    write_event(tmp_path / "src", frames)
    report = live(tmp_path / "src", tmp_path / "live", window_s=1.0)
    assert (report.windows, report.frames, report.ended_by) == (3, 25, "end marker")
    recorded = tmp_path / "recorded.tsogs"
    options = SegmentOptions(window_s=1.0, layers=1, workers=1)
    segment_sequence(open_sequence(tmp_path / "src", fps=FPS), recorded, options)
    with open_stream(tmp_path / "live") as ours, open_stream(recorded) as theirs:
        m = ours.index.manifest
        assert live_of(m).ended and live_of(m).sequence == 4  # 3 windows + end
        assert (m.scene.start_s, m.scene.end_s, m.scene.fps, m.window_s) == (0.0, 2.5, FPS, 1.0)
        assert [n.chunks for n in m.nodes] == [[0], [1], [2]]
        assert m.scene.gaussians == 25 * PER_FRAME
        for k in (0, 9, 10, 19, 24):
            t = (k + 0.5) / FPS
            got, want = ours.frame_at(t), theirs.frame_at(t)
            assert len(got) == PER_FRAME
            for name in ("means", "scales", "quats", "opacities", "sh0", "shN"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
            # and against the frame written, within the codec's position step
            err = np.abs(np.sort(got.means, axis=0) - np.sort(frames[k].means, axis=0)).max()
            assert err < 0.02


def test_each_window_is_published_with_its_times(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "live"
    src.mkdir()
    frames = frames_of(20)
    sequences: list[int] = []
    runner = threading.Thread(target=lambda: live(src, out, window_s=1.0), daemon=True)
    runner.start()
    for k in range(10):
        put_frame(src, k, frames[k])
    wait_for((out / "manifest.json").exists, "the first window")
    first = published(out)
    sequences.append(first["sequence"])
    assert not first["ended"] and len(first["windows"]) == 1
    for k in range(10, 20):
        put_frame(src, k, frames[k])
    wait_for(lambda: len(published(out)["windows"]) == 2, "the second window")
    (src / "END").write_bytes(b"")
    runner.join(WAIT_S)
    final = published(out)
    assert final["ended"] and final["sequence"] > first["sequence"]
    w0, w1 = final["windows"]
    assert w0 == first["windows"][0]  # a window's times never change once published
    arrived0 = (src / "frame_00000.ply").stat().st_mtime
    assert abs(w0["arrived_s"] - arrived0) < 1e-6 and w0["published_s"] >= arrived0
    assert w1["arrived_s"] >= w0["arrived_s"] and w1["published_s"] >= w0["published_s"]
    for i in range(2):  # chunks are published before the index naming them
        assert (out / "chunks" / f"{i:06d}.sog").is_file()


def test_an_event_ends_after_idle_seconds(tmp_path: Path) -> None:
    write_event(tmp_path / "src", frames_of(4), end=False)
    report = live(tmp_path / "src", tmp_path / "live", idle_s=0.5)
    assert report.ended_by == "no frame for 0.5 s" and report.frames == 4
    assert published(tmp_path / "live")["ended"]


def test_a_frame_still_settling_is_not_idleness(tmp_path: Path) -> None:
    watch = FrameArrivals(tmp_path)
    put_frame(tmp_path, 0, frames_of(1)[0])
    watch.poll()  # seen, not yet settled
    assert live_module._ended(watch, threading.Event(), idle=99.0, idle_s=5.0) == ""
    time.sleep(SETTLE_S + 0.05)
    assert len(watch.poll()) == 1
    assert live_module._ended(watch, threading.Event(), idle=99.0, idle_s=5.0) == "no frame for 5 s"


def test_a_stop_publishes_the_last_partial_window(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "live"
    write_event(src, frames_of(13), end=False)
    stop = threading.Event()
    done: list[LiveReport] = []
    runner = threading.Thread(
        target=lambda: done.append(
            run_live(src, str(out), LiveOptions(fps=FPS, workers=1), stop=stop)
        ),
        daemon=True,
    )
    runner.start()
    wait_for((out / "manifest.json").exists, "the first window")
    time.sleep(SETTLE_S * 3)
    stop.set()
    runner.join(WAIT_S)
    [report] = done
    assert report.ended_by == "stopped" and report.frames == 13 and report.windows == 2
    with open_stream(out) as stream:
        assert stream.index.manifest.scene.end_s == 1.3 and not stream.is_live


def test_an_event_without_frames_publishes_nothing(tmp_path: Path) -> None:
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "END").write_bytes(b"")
    with pytest.raises(InputError, match="no frame arrived"):
        live(tmp_path / "src", tmp_path / "live")
    assert not (tmp_path / "live").exists()


def test_an_ended_stream_is_not_resumed_without_force(tmp_path: Path) -> None:
    write_event(tmp_path / "src", frames_of(3))
    live(tmp_path / "src", tmp_path / "live")
    with pytest.raises(SourceError, match="an ended live stream"):
        live(tmp_path / "src", tmp_path / "live")
    report = run_live(
        tmp_path / "src", str(tmp_path / "live"), LiveOptions(fps=FPS, workers=1), overwrite=True
    )
    assert report.frames == 3 and report.resumed_windows == 0


def test_an_index_to_resume_is_bounded_before_it_is_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(live_module, "MAX_INDEX_BYTES", 100)
    (tmp_path / "live").mkdir()
    (tmp_path / "live" / "manifest.json").write_bytes(b" " * 101)
    write_event(tmp_path / "src", frames_of(1))
    with pytest.raises(SourceError, match="index over 100 bytes"):
        live(tmp_path / "src", tmp_path / "live")


def test_a_resume_with_another_frame_rate_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "live"
    write_event(tmp_path / "src", frames_of(3))
    live(tmp_path / "src", out)
    unfinish(out)
    with pytest.raises(InputError, match="give the same --fps and --window"):
        live(tmp_path / "src", out, fps=FPS * 2)


def test_a_live_index_lists_one_time_entry_per_window(tmp_path: Path) -> None:
    write_event(tmp_path / "src", frames_of(3))
    live(tmp_path / "src", tmp_path / "live")
    data = json.loads((tmp_path / "live" / "manifest.json").read_bytes())
    data["live"]["windows"].append({"arrived_s": 1.0, "published_s": 2.0})
    with pytest.raises(MetaError, match=r"live\.windows has 2 entries, not 1"):
        parse_manifest(json.dumps(data).encode())
    data["live"]["windows"] = data["live"]["windows"][:1]
    data["live"]["sequence"] = -1
    with pytest.raises(MetaError, match="sequence"):
        parse_manifest(json.dumps(data).encode())


# --- the command, its signals and its restarts ----------------------------------------------


def tsog_live(src: Path, out: str, *extra: str) -> subprocess.Popen[bytes]:
    """``tsog live`` as a user runs it, in a process of its own."""
    command = [sys.executable, "-m", "tsog_stream.cli.main", "live", str(src), "-o", out]
    command += ["--fps", str(FPS), "--workers", "1", "--idle", "20", *extra]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_a_killed_live_run_resumes_without_losing_or_repeating_a_window(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "live"
    frames = frames_of(35)
    write_event(src, frames[:20], end=False)
    first = tsog_live(src, str(out))
    try:
        wait_for(
            lambda: (out / "manifest.json").exists() and len(published(out)["windows"]) == 2,
            "two windows",
        )
    finally:
        first.kill()
        first.communicate(timeout=WAIT_S)
    for k in range(20, 35):
        put_frame(src, k, frames[k])
    (src / "END").write_bytes(b"")
    second = tsog_live(src, str(out))
    stdout, stderr = second.communicate(timeout=WAIT_S)
    assert second.returncode == 0, stderr.decode()
    assert b"4 windows, 2 of them before a restart, 35 frames" in stdout
    with open_stream(out) as stream:
        m = stream.index.manifest
        assert live_of(m).ended and len(live_of(m).windows) == 4 and m.scene.end_s == 3.5
        assert [n.start_s for n in m.nodes] == [0.0, 1.0, 2.0, 3.0]
        for k in (0, 19, 20, 34):
            got = stream.frame_at((k + 0.5) / FPS)
            err = np.abs(np.sort(got.means, axis=0) - np.sort(frames[k].means, axis=0)).max()
            assert len(got) == PER_FRAME and err < 0.02, k


def test_sigterm_ends_the_event_cleanly(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "live"
    write_event(src, frames_of(14), end=False)
    proc = tsog_live(src, str(out))
    try:
        wait_for((out / "manifest.json").exists, "the first window")
        time.sleep(SETTLE_S * 3)
    finally:
        proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, stderr.decode()
    assert b"2 windows, 14 frames" in stdout and b"(ended: stopped)" in stdout
    assert published(out)["ended"]
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no temp file left


def test_pack_writes_the_ended_stream_as_one_container(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_event(tmp_path / "src", frames_of(12))
    out, packed = tmp_path / "live", tmp_path / "event.tsogs"
    argv = ["live", str(tmp_path / "src"), "-o", str(out), "--fps", "10", "--workers", "1"]
    assert main([*argv, "--pack", str(packed), "-q"]) == 0
    assert f"{packed}: {packed.stat().st_size} bytes" in capsys.readouterr().out
    with open_stream(packed) as one, open_stream(out) as folder:
        assert one.index.manifest == folder.index.manifest.model_copy(
            update={"chunks": one.index.manifest.chunks}
        )
        assert one.verify().problems == []
        for t in (0.05, 1.15):
            np.testing.assert_array_equal(one.frame_at(t).means, folder.frame_at(t).means)


def test_the_command_refuses_bad_options_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "src").mkdir()
    for args, message in (
        (["--fps", "0"], "--fps: must be a positive number up to 1000, got 0"),
        (["--fps", "30", "--window", "-1"], "--window"),
        (["--fps", "30", "--window", "61"], "--window"),
        (["--fps", "nan"], "--fps: must be a positive number"),
        (["--fps", "1e308"], "--fps: must be a positive number up to 1000"),
    ):
        try:
            status = main(["live", str(tmp_path / "src"), "-o", str(tmp_path / "o"), *args])
        except SystemExit as exc:  # a usage error
            status = int(exc.code or 0)
        err = capsys.readouterr().err
        assert status in (1, 2) and "Traceback" not in err
        assert message in err.strip().splitlines()[-1]  # one line says it (after the usage)


# --- the server: blocking reload and cache rules --------------------------------------------


@pytest.fixture
def live_scene(tmp_path: Path) -> Iterator[tuple[Path, str]]:
    """An unfinished live stream of one window (media/show) served on loopback."""
    src, out = tmp_path / "src", tmp_path / "media" / "show"
    write_event(src, frames_of(10))
    live(src, out)
    unfinish(out)
    server = ThreadedServer(make_app(tmp_path / "media"))
    try:
        yield out, f"http://127.0.0.1:{server.port}"
    finally:
        server.stop()


def republish(out: Path, **live_fields: object) -> None:
    """Rewrite the index with new live fields, as the writer does (write, then rename)."""
    manifest = parse_manifest((out / "manifest.json").read_bytes())
    fields = live_of(manifest).model_copy(update=live_fields)
    tmp = out / ".manifest.tmp"
    tmp.write_bytes(dump_manifest(manifest.model_copy(update={"live": fields})))
    os.replace(tmp, out / "manifest.json")


async def get(url: str) -> tuple[int, dict[str, str], bytes, float]:
    """Status, headers, body and seconds taken of one GET."""
    import aiohttp  # noqa: PLC0415

    began = time.monotonic()
    async with aiohttp.ClientSession() as session, session.get(url) as resp:
        body = await resp.read()
        return resp.status, dict(resp.headers), body, time.monotonic() - began


@pytest.mark.parametrize("path", ["/v1/scenes/show/manifest", "/files/show/manifest.json"])
def test_a_blocking_reload_answers_when_the_next_index_is_published(
    live_scene: tuple[Path, str], path: str
) -> None:
    out, base = live_scene
    sequence = published(out)["sequence"]
    timer = threading.Timer(0.4, lambda: republish(out, sequence=sequence + 1))
    timer.start()
    status, headers, body, took = asyncio.run(get(f"{base}{path}?after={sequence}"))
    timer.join()
    assert status == 200 and json.loads(body)["live"]["sequence"] == sequence + 1
    assert 0.4 <= took < 0.4 + 20 * RELOAD_POLL_S + 1.0
    assert headers["Cache-Control"] == "public, max-age=1"  # it names that publication


def test_a_blocking_reload_gives_the_current_index_when_none_comes(
    live_scene: tuple[Path, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out, base = live_scene
    from tsog_stream.server import live as server_live  # noqa: PLC0415

    monkeypatch.setattr(server_live, "MAX_RELOAD_WAIT_S", 0.3)
    sequence = published(out)["sequence"]
    status, headers, body, took = asyncio.run(
        get(f"{base}/v1/scenes/show/manifest?after={sequence}")
    )
    assert status == 200 and json.loads(body)["live"]["sequence"] == sequence
    assert 0.3 <= took < 5 and headers["Cache-Control"] == "no-cache"


def test_a_reload_for_a_publication_already_there_does_not_wait(
    live_scene: tuple[Path, str],
) -> None:
    _, base = live_scene
    status, _, body, took = asyncio.run(get(f"{base}/v1/scenes/show/manifest?after=0"))
    assert status == 200 and json.loads(body)["live"]["sequence"] >= 1 and took < 1.0


def test_a_live_index_is_cached_at_most_half_a_window(live_scene: tuple[Path, str]) -> None:
    out, base = live_scene
    _, headers, _, _ = asyncio.run(get(f"{base}/v1/scenes/show/manifest"))
    assert headers["Cache-Control"] == "public, max-age=0"  # half of a 1 s window, floored
    republish(out, ended=True)
    status, headers, body, took = asyncio.run(get(f"{base}/v1/scenes/show/manifest?after=999"))
    assert status == 200 and took < 1.0 and json.loads(body)["live"]["ended"]
    assert headers["Cache-Control"] == "public, max-age=0, must-revalidate"
    chunk = json.loads(asyncio.run(get(f"{base}/v1/scenes/show/chunks?t=0.5"))[2])["chunks"][0]
    _, headers, _, _ = asyncio.run(get(f"{base}{chunk['url']}"))
    assert "immutable" in headers["Cache-Control"]


def test_after_on_a_file_that_is_no_scene_index_is_ignored(live_scene: tuple[Path, str]) -> None:
    out, base = live_scene
    other = out.parent / "notes"
    other.mkdir()
    (other / "manifest.json").write_bytes(b'{"not": "a scene"}')
    status, _, body, took = asyncio.run(get(f"{base}/files/notes/manifest.json?after=5"))
    assert status == 200 and body == b'{"not": "a scene"}' and took < 1.0


@pytest.mark.parametrize("after", ["-1", "x", "1e3", "99999999999999999", "1%00"])
def test_a_bad_publication_number_is_refused(live_scene: tuple[Path, str], after: str) -> None:
    _, base = live_scene
    for path in ("/v1/scenes/show/manifest", "/files/show/manifest.json"):
        status, _, body, _ = asyncio.run(get(f"{base}{path}?after={after}"))
        assert status == 400 and b"publication number" in body


# --- the client ----------------------------------------------------------------------------


def test_the_client_follows_a_live_stream_to_its_end(tmp_path: Path) -> None:
    src, media = tmp_path / "src", tmp_path / "media"
    src.mkdir()
    frames = frames_of(30)
    for k in range(10):
        put_frame(src, k, frames[k])
    runner = threading.Thread(target=lambda: live(src, media / "show"), daemon=True)
    runner.start()
    wait_for((media / "show" / "manifest.json").exists, "the first window")
    server = ThreadedServer(make_app(media))

    def feed() -> None:
        for k in range(10, 30):
            put_frame(src, k, frames[k])
            time.sleep(1 / FPS)
        (src / "END").write_bytes(b"")

    feeder = threading.Thread(target=feed, daemon=True)
    try:
        with open_stream(f"http://127.0.0.1:{server.port}/files/show/") as stream:
            assert stream.is_live
            feeder.start()
            stats = stream.follow_live(fps=FPS)
        assert stats.ended and stats.frames >= 25  # joined a window and a half behind the edge
        assert len(stats.latencies_s) == stats.frames and min(stats.latencies_s) > 0
        report = stats.as_dict()
        assert report["latency_p95_s"] >= report["latency_p50_s"] > 0
    finally:
        feeder.join(WAIT_S)
        runner.join(WAIT_S)
        server.stop()


def test_a_refresh_on_a_static_origin_sees_the_next_index(tmp_path: Path) -> None:
    write_event(tmp_path / "src", frames_of(10))
    out = tmp_path / "live"
    live(tmp_path / "src", out)
    republish(out, ended=False)

    async def check() -> None:
        client = await StreamClient.open(out)
        try:
            assert client.is_live and not await client.refresh()
            republish(out, sequence=live_of(client.index.manifest).sequence + 1)
            assert await client.refresh() and live_of(client.index.manifest).sequence == 3
            republish(out, ended=True)
            assert await client.refresh() is False or not client.is_live
        finally:
            await client.source.aclose()

    asyncio.run(check())


def test_follow_live_plays_a_recorded_stream_to_its_end(tmp_path: Path) -> None:
    write_event(tmp_path / "src", frames_of(10))
    recorded = tmp_path / "c.tsogs"
    segment_sequence(
        open_sequence(tmp_path / "src", fps=FPS),
        recorded,
        SegmentOptions(window_s=1.0, layers=1, workers=1),
    )

    async def check() -> None:
        client = await StreamClient.open(recorded)
        try:
            stats = await follow_live(client, fps=FPS, behind_s=0.3)
        finally:
            await client.source.aclose()
        assert stats.ended and stats.frames == 3 and stats.latencies_s == []

    asyncio.run(check())


def test_play_live_json_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_event(tmp_path / "src", frames_of(10))
    live(tmp_path / "src", tmp_path / "live")
    assert main(["play", str(tmp_path / "live"), "--live", "--json", "-q", "--fps", "10"]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("first_picture_s", "stalls", "frames", "latency_p50_s", "latency_p95_s"):
        assert key in report
    # an ended stream of 1 s: played from a window and a half behind its end, clipped to 0
    assert report["ended"] and report["frames"] == 10 and report["latency_p95_s"] > 0


def test_play_json_report_of_a_recorded_stream(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_event(tmp_path / "src", frames_of(10))
    recorded = tmp_path / "c.tsogs"
    segment_sequence(
        open_sequence(tmp_path / "src", fps=FPS),
        recorded,
        SegmentOptions(window_s=1.0, layers=1, workers=1),
    )
    assert main(["play", str(recorded), "--json", "-q", "--fps", "10"]) == 0
    report = json.loads(capsys.readouterr().out)
    # t = 0.0, 0.1, ... 1.0: the end included, as every simulated playback
    assert report["frames"] == 11 and report["stalls"] == 0 and "first_picture_s" in report


# --- object storage -------------------------------------------------------------------------


def test_a_live_stream_published_to_object_storage(tmp_path: Path) -> None:
    pytest.importorskip("s3fs")
    frames = frames_of(15)
    write_event(tmp_path / "src", frames)
    with loopback_s3("live") as fs:
        report = live(tmp_path / "src", "s3://live/event/")
        assert report.windows == 2 and fs.exists("live/event/chunks/000001.sog")
        with open_stream("s3://live/event/") as stream:
            m = stream.index.manifest
            assert live_of(m).ended and m.scene.end_s == 1.5
            got = stream.frame_at(1.45)
            err = np.abs(np.sort(got.means, axis=0) - np.sort(frames[14].means, axis=0)).max()
            assert err < 0.02
        with pytest.raises(SourceError, match="an ended live stream"):
            live(tmp_path / "src", "s3://live/event/")
