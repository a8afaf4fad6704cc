"""The tsog command line: real files in, real files out, friendly errors, no tracebacks."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from test_cli_hostile import HOSTILE_FILE_RUNS
from tsog_stream import TimelineType
from tsog_stream.cli import interrupt, view_command
from tsog_stream.cli import progress as progress_module
from tsog_stream.cli.main import _print_demo, build_parser, main
from tsog_stream.cli.progress import Progress
from tsog_stream.cli.stream_commands import check_segment_args
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.inputs import open_source
from tsog_stream.io.chunks import read_chunk
from tsog_stream.io.ply import read_ply, write_ply
from tsog_stream.model import Gaussians
from tsog_stream.schemas.manifest import dump_manifest
from tsog_stream.synthetic import small_scene
from tsog_stream.temporal import time_range

DONUT = "3dgs/v3dg_donut_fused.ply"


@pytest.fixture(scope="module")
def dynamic_chunk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "dynamic.sog"
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=("means",))
    path.write_bytes(bundle_bytes(encode_chunk(scene)))
    return path


def test_encode_decode_round_trip(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "donut.sog"
    assert main(["encode", str(samples / DONUT), str(out), "-q"]) == 0
    # of its 45624, four are too faint at the default quality (alpha 0.002 or less)
    assert "45620 Gaussians" in (said := capsys.readouterr().out)
    assert "(4 too faint at quality 90 left out)" in said
    assert main(["decode", str(out), str(tmp_path / "back.ply"), "-q"]) == 0
    back = read_ply(tmp_path / "back.ply").gaussians
    assert len(back) == 45620
    folder = tmp_path / "donut"
    assert main(["encode", str(out), str(folder), "-q"]) == 0
    assert (folder / "meta.json").is_file()
    again = read_chunk(folder).gaussians.means  # re-encoded: texel order may differ on ties
    np.testing.assert_allclose(np.sort(again, axis=0), np.sort(back.means, axis=0), atol=1e-4)


def test_encode_refuses_to_overwrite_without_force(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.sog"
    out.write_bytes(b"keep me")
    assert main(["encode", str(samples / DONUT), str(out), "-q"]) == 1
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"


def test_info_json(dynamic_chunk: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(dynamic_chunk), "--json", "-q"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "sog" and info["count"] > 0
    assert info["timeline"]["type"] == 2 and info["temporal"] == {"means": 2}
    assert set(info["bytes_per_attribute"]) >= {
        "means",
        "timeline",
        "temporal.means",
        "sh0+opacity",
    }
    w, h = info["images"]["means_l.webp"]
    assert w * h >= info["count"]


def test_frame_export(dynamic_chunk: Path, tmp_path: Path) -> None:
    scene = read_chunk(dynamic_chunk)
    out = tmp_path / "f.ply"
    assert main(["frame", str(dynamic_chunk), "--t", "0.8", "-o", str(out), "-q"]) == 0
    frame = read_ply(out).gaussians
    expected = scene.at(0.8)
    assert len(frame) == len(expected) > 0
    np.testing.assert_allclose(frame.means, expected.means, rtol=1e-6)
    assert (
        main(["frame", str(dynamic_chunk), "--t", "0.8", "-o", str(tmp_path / "f.sog"), "-q"]) == 0
    )
    assert read_chunk(tmp_path / "f.sog").timeline is None


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["info", "/nonexistent/file.ply"], "no such file"),
        (["encode", "{bad}", "{tmp}/o.sog"], "unknown magic"),
        (["decode", "{trunc}", "{tmp}/o.ply"], "zip"),
    ],
)
def test_bad_inputs_give_one_line_errors(args: list[str], message: str, tmp_path: Path) -> None:
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"\x00garbage" * 10)
    trunc = tmp_path / "trunc.sog"
    trunc.write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    argv = [a.format(bad=bad, tmp=tmp_path, trunc=trunc) for a in args]
    proc = subprocess.run(
        [sys.executable, "-m", "tsog_stream.cli.main", *argv, "-q"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 1
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_help_teaches() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "tsog_stream.cli.main", "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0
    for word in ("encode", "decode", "info", "frame", "demo", "examples:", "seconds"):
        assert word in proc.stdout


def test_demo_reports_a_faithful_stream(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--out", str(tmp_path), "--json", "-q"]) == 0
    report = json.loads(capsys.readouterr().out)
    stream = report["stream"]
    assert stream["frames"] > 5 and stream["mismatches"] == 0 and stream["bytes_fetched"] > 0
    assert (tmp_path / "demo.tsogs").stat().st_size == stream["bytes"]
    assert (tmp_path / "demo.sog").stat().st_size == report["tsog_bytes"]
    assert report["tsog_bytes"] < report["extended_ply_bytes"]
    for row in report["errors"]:
        assert row["means_max"] < 1e-3 and row["visibility_flips"] == 0
    _print_demo(report)  # as text, it closes with how to watch what it made
    hint = f"watch it in the web player: tsog view {tmp_path / 'demo.tsogs'}"
    assert capsys.readouterr().out.splitlines()[-1] == hint


def test_encode_to_4dgs_refuses_unrepresentable_motion_unless_lossy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "curved.sog"
    scene = small_scene(TimelineType.CENTER_SCALE, motion_order=2, dynamic=("means",))
    source.write_bytes(bundle_bytes(encode_chunk(scene)))
    out = tmp_path / "x.4dgs"
    assert main(["encode", str(source), str(out), "-q"]) == 1
    assert "tsog: error:" in capsys.readouterr().err and not out.exists()
    assert main(["encode", str(source), str(out), "--lossy", "-q"]) == 0
    assert out.stat().st_size > 0
    assert "note:" in capsys.readouterr().err


def test_a_swallowed_ctrl_c_is_raised_again_at_the_next_progress_report() -> None:
    """Python may swallow the KeyboardInterrupt of a SIGINT (raised inside a callback): the
    latch makes the next progress report raise it, and its "Exception ignored" report is quiet."""
    seen: list[object] = []
    previous_hook = sys.unraisablehook
    sys.unraisablehook = seen.append
    try:
        with pytest.raises(KeyboardInterrupt), interrupt.latched():
            with contextlib.suppress(KeyboardInterrupt):  # as a weakref or import-lock callback
                signal.raise_signal(signal.SIGINT)
            sys.unraisablehook(SimpleNamespace(exc_value=KeyboardInterrupt()))  # kept quiet
            sys.unraisablehook(SimpleNamespace(exc_value=ValueError()))  # passed on
            Progress(quiet=True)("next stage")
        with interrupt.latched():
            Progress(quiet=True)("the next command starts unlatched")
    finally:
        sys.unraisablehook = previous_hook
    assert len(seen) == 1


def test_a_long_first_stage_is_logged_from_the_first_seconds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Without a terminal, stages shorter than QUIET_SECONDS stay unlogged, but one still
    running then is printed then (a 5M-Gaussian read was silent for 16 s); a command that
    ends first prints nothing later."""
    monkeypatch.setattr(progress_module, "QUIET_SECONDS", 0.2)
    log = io.StringIO()
    progress = Progress(stream=log)
    progress("reading a big file")
    time.sleep(0.6)
    assert "reading a big file" in log.getvalue()
    quick = io.StringIO()
    progress = Progress(stream=quick)
    progress("a quick command")
    progress.close()
    time.sleep(0.4)
    assert quick.getvalue() == ""


@pytest.mark.parametrize("quiet", [True, False])
def test_the_resource_tracker_says_nothing_after_the_command(quiet: bool) -> None:
    """A semaphore unlinked by a pool's finalizer that Ctrl-C cut short is one the resource
    tracker finds leaked and gone: it printed two warnings after "tsog: interrupted". The CLI
    starts it with those warnings ignored (without: the very lines CI saw)."""
    code = (
        "from tsog_stream.cli import interrupt\n"
        + ("interrupt.quiet_resource_tracker()\n" if quiet else "")
        + "from multiprocessing import resource_tracker\n"
        + "resource_tracker.register('/tsog-test-unlinked', 'semaphore')\n"
    )
    argv = [sys.executable, "-c", code]
    done = subprocess.run(argv, check=True, capture_output=True, text=True, timeout=60)
    if quiet:
        assert done.stderr == ""
    else:
        assert "resource_tracker: '/tsog-test-unlinked': [Errno 2]" in done.stderr


def test_the_cli_quiets_the_resource_tracker_once_before_running_a_command(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(sys, "warnoptions", [])
    assert main(["info", "/no/such/file", "-q"]) == 1
    assert main(["info", "/no/such/file", "-q"]) == 1
    assert sys.warnoptions == [interrupt.TRACKER_QUIET]


def test_a_log_gets_a_bar_line_every_few_seconds_not_one_per_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Without a terminal a bar is logged at most every LOG_BAR_SECONDS and when full: the
    monkey flipbook's 150 chunks were 150 lines."""
    monkeypatch.setattr(progress_module, "QUIET_SECONDS", 0.0)
    for every, lines in ((progress_module.LOG_BAR_SECONDS, 2), (0.0, 150)):
        monkeypatch.setattr(progress_module, "LOG_BAR_SECONDS", every)
        log = io.StringIO()
        progress = Progress(stream=log)
        for done in range(1, 151):
            progress.bar(f"chunk {done}/150", done / 150)
        said = log.getvalue().splitlines()
        assert len(said) == lines, said[:3]
        assert said[0].endswith("chunk 1/150 [..............................]   0.7%")
        assert said[-1].endswith("chunk 150/150 [##############################] 100.0%")


@pytest.fixture(scope="module")
def dynamic_stream(dynamic_chunk: Path) -> Path:
    """The dynamic chunk's scene segmented into a container."""
    path = dynamic_chunk.with_name("dynamic.tsogs")
    assert main(["segment", str(dynamic_chunk), "-o", str(path), "--window", "0.5", "-q"]) == 0
    return path


@pytest.mark.parametrize("t", ["-1", "99", "1e308", "-1e308", "nan", "inf"])
def test_a_time_outside_the_scene_is_one_line_naming_the_range(
    t: str,
    dynamic_chunk: Path,
    dynamic_stream: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    runs = [("frame", str(dynamic_chunk))]
    runs += [
        (c, s) for c in ("frame", "fetch") for s in (str(dynamic_stream), dynamic_stream.as_uri())
    ]
    for command, source in runs:
        argv = [command, source, f"--t={t}", "-o", str(tmp_path / "f.ply"), "-q"]
        assert main(argv) == 1, argv  # a traceback would raise here instead
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1
        want = "finite number" if "n" in t else "outside the scene's time range [0,"
        assert want in err and "--t" in err
        assert not (tmp_path / "f.ply").exists()


def test_an_empty_scene_is_written_as_a_ply_and_refused_as_a_chunk(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty.ply"
    write_ply(empty, Gaussians.empty())
    assert len(read_ply(empty).gaussians) == 0
    assert main(["encode", str(empty), str(tmp_path / "e.sog"), "-q"]) == 1
    assert "no Gaussians" in capsys.readouterr().err
    assert not (tmp_path / "e.sog").exists()


@pytest.mark.parametrize(
    "option",
    [
        "--start=nan",
        "--start=inf",
        "--speed=nan",
        "--speed=0",
        "--fps=nan",
        "--fps=-1",
        "--duration=nan",
        "--duration=-1",
        "--speed=1e-300",
        "--fps=1e9",
    ],
)
def test_play_refuses_options_that_cannot_end(
    option: str, dynamic_stream: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["play", str(dynamic_stream), option, "-q"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "tsog: error:" in err


def test_files_that_are_not_regular_are_refused_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    for target in (fifo, Path("/dev/zero")):
        proc = subprocess.run(
            [sys.executable, "-m", "tsog_stream.cli.main", "info", str(target), "-q"],
            capture_output=True,
            text=True,
            timeout=30,  # reading the FIFO would block forever, /dev/zero never end
            check=False,
        )
        assert proc.returncode == 1 and "not a regular file" in proc.stderr
        assert "Traceback" not in proc.stderr


def test_a_reader_that_leaves_early_is_no_traceback(dynamic_stream: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tsog_stream.cli.main", "info", str(dynamic_stream), "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    with proc, proc.stderr:
        proc.stdout.close()  # as `| head -0` would
        err = proc.stderr.read().decode()
        assert proc.wait(60) == 1 and "Traceback" not in err and "BrokenPipe" not in err


def test_non_finite_input_values_are_notes_and_one_line_errors_never_warnings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """pytest turns every warning into an error here: numpy's must not escape."""
    rng = np.random.default_rng(0)
    g = Gaussians.from_arrays(
        rng.standard_normal((50, 3)),
        rng.standard_normal((50, 3)) - 4,
        rng.standard_normal((50, 4)),
        rng.standard_normal(50),
        rng.standard_normal((50, 3)),
    )
    g.quats[6] = np.nan  # no rotation: stored as the identity
    g.scales[4] = -np.inf  # a flat splat: SOG's codebook sentinel
    path = tmp_path / "odd.ply"
    write_ply(path, g)
    assert main(["encode", str(path), str(tmp_path / "ok.sog"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "non-finite values as read" in err and "Warning" not in err
    g.means[3] = np.nan
    write_ply(path, g)
    assert main(["encode", str(path), str(tmp_path / "bad.sog"), "-q"]) == 1
    err = capsys.readouterr().err
    assert "1 Gaussians have non-finite positions" in err and not (tmp_path / "bad.sog").exists()


@pytest.mark.parametrize("command", [*HOSTILE_FILE_RUNS, "serve", "sign"])
def test_every_command_refuses_missing_arguments_with_usage(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main([command])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "usage: tsog" in err and "Traceback" not in err


LOADED_BY = """
import sys
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
try:
    code = main(sys.argv[1:])
except SystemExit as exc:  # --help
    code = exc.code
heavy = ["aiohttp", "numba", "tsog_stream.server.app", "tsog_stream.demo"]
heavy.append("tsog_stream.throttled_play")
print("loaded:", *[name for name in heavy if name in sys.modules])
sys.exit(code)
"""


@pytest.mark.parametrize("command", ["info", "frame", "decode", "help"])
def test_local_commands_load_no_http_stack_and_no_renderer(command: str, tmp_path: Path) -> None:
    """A command on local files loads neither aiohttp (the HTTP client and server are loaded
    by the commands that use them) nor numba, the demo or the shaped-link player: each cost
    every command ~0.25-0.4 s of start-up."""
    chunk = tmp_path / "c.tsogs"
    src = tmp_path / "s.sog"
    src.write_bytes(bundle_bytes(encode_chunk(small_scene(TimelineType.CENTER_SCALE, seed=3))))
    segment = ["segment", str(src), "-o", str(chunk), "--workers", "1", "--layers", "1", "-q"]
    assert main(segment) == 0
    argv = {
        "info": ["info", str(chunk)],
        "frame": ["frame", str(chunk), "--t", "0.5", "-o", str(tmp_path / "f.ply"), "-q"],
        "decode": ["decode", str(src), str(tmp_path / "d.ply"), "-q"],
        "help": ["serve", "--help"],
    }[command]
    done = subprocess.run(
        [sys.executable, "-c", LOADED_BY, *argv],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "loaded:", done.stdout


def test_what_loads_late_is_still_there_when_asked_for() -> None:
    """The lazily loaded exports resolve: the HTTP source through the client package, the
    server's through the server package (each with aiohttp)."""
    import tsog_stream.client as client_package  # noqa: PLC0415
    import tsog_stream.server as server_package  # noqa: PLC0415

    assert client_package.HttpSource.__name__ == "HttpSource"
    assert client_package.HttpFiles.__name__ == "HttpFiles"
    for name in server_package.__all__:
        assert getattr(server_package, name).__name__ == name
    with pytest.raises(AttributeError):
        _ = server_package.nothing_of_that_name


SEGMENT_WORKERS = """
import os, sys
os.sched_setaffinity(0, {int(c) for c in sys.argv[3].split(",")})
from tsog_stream.cli.main import build_parser
from tsog_stream.cli.stream_commands import check_segment_args
args = build_parser().parse_args(["segment", sys.argv[1], "-o", sys.argv[2]])
check_segment_args(args)
print(args.workers)
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this OS")
@pytest.mark.parametrize("pinned", [True, False])
def test_segment_starts_a_worker_per_core_it_may_use(tmp_path: Path, pinned: bool) -> None:
    """Without --workers, ``tsog segment`` encodes on one process per core its process may run
    on (taskset, a cpuset): one pinned core, one process; and --workers still wins."""
    cores = sorted(os.sched_getaffinity(0))
    allowed = cores[:1] if pinned else cores
    src, out = str(tmp_path / "s.sog"), str(tmp_path / "c.tsogs")
    done = subprocess.run(
        [sys.executable, "-c", SEGMENT_WORKERS, src, out, ",".join(map(str, allowed))],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    assert int(done.stdout) == len(allowed)
    args = build_parser().parse_args(["segment", src, "-o", out, "--workers", "3"])
    check_segment_args(args)
    assert args.workers == 3


# --- output locations: checked before any work, folders made (issue 55) -----------------------

SMALL = ["--width", "32", "--height", "24"]
OUTPUT_RUNS = {
    "segment": (["{chunk}", "-o", "{out}", "--workers", "1", "--layers", "1"], "s.tsogs"),
    "encode": (["{chunk}", "{out}"], "e.sog"),
    "decode": (["{chunk}", "{out}"], "d.ply"),
    "frame": (["{chunk}", "--t", "0.5", "-o", "{out}"], "f.ply"),
    "extract": (["{stream}", "0", "-o", "{out}"], "c.sog"),
    "unpack": (["{stream}", "-o", "{out}"], "u"),
    "pack": (["{unpacked}", "-o", "{out}"], "p.tsogs"),
    "render": (["{chunk}", "--t", "0.5", "-o", "{out}", *SMALL], "r.png"),
    "eval": (
        ["{chunk}", "{chunk}", *SMALL, "--times", "1", "--views", "1", "--plot", "{out}"],
        "p.png",
    ),
    "fetch": (["{stream}", "--t", "0.5", "-o", "{out}"], "f.ply"),
}
"""Every command that writes a file or folder, its input placeholders and its output's name
(unpack writes a folder)."""
BAD_LOCATIONS = {
    "below a file": "is a file, not a folder: nothing can be written below it",
    "unwritable": "cannot create files in '/proc'",
    "a device": "is a device, FIFO or socket: refused as an output",
    "the wrong kind": "expected the name of a",
}
"""Where an output cannot go, and what the one error line says."""
NO_FORCE = {"decode"}
"""Commands without --force (they replace their output)."""
WRITER_CASES = [pytest.param(command, where) for command in OUTPUT_RUNS for where in BAD_LOCATIONS]


@pytest.fixture(scope="module")
def written_inputs(dynamic_chunk: Path, dynamic_stream: Path) -> dict[str, Path]:
    """The inputs of OUTPUT_RUNS: a chunk, its container and the container unpacked."""
    unpacked = dynamic_stream.with_name("dynamic-unpacked")
    if not unpacked.exists():
        assert main(["unpack", str(dynamic_stream), "-o", str(unpacked), "-q"]) == 0
    return {"chunk": dynamic_chunk, "stream": dynamic_stream, "unpacked": unpacked}


def _bad_output(where: str, tmp_path: Path, name: str) -> Path:
    """An output location of kind ``where`` (BAD_LOCATIONS) for an output called ``name``."""
    if where == "below a file":
        (tmp_path / "a-file").write_bytes(b"here")
        return tmp_path / "a-file" / name
    if where == "unwritable":  # root may write almost anywhere, not in /proc
        return Path("/proc") / f"tsog-test-{os.getpid()}" / name
    if where == "a device":
        return Path("/dev/null")
    taken = tmp_path / name
    if name == "u":  # a folder is wanted: a file stands there
        taken.write_bytes(b"a file")
    else:
        taken.mkdir()
    return taken


@pytest.mark.parametrize(("command", "where"), WRITER_CASES)
def test_every_writer_refuses_a_bad_output_location_before_reading_anything(
    command: str, where: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The output location is checked first: the inputs here do not exist, and the one error
    line is about the output; nothing is left anywhere."""
    argv, name = OUTPUT_RUNS[command]
    out = _bad_output(where, tmp_path, name)
    missing = {k: str(tmp_path / f"no-{k}") for k in ("chunk", "stream", "unpacked")}
    line = [command, *(a.format(out=out, **missing) for a in argv), "-q"]
    before = sorted(tmp_path.rglob("*"))
    force = [] if command in NO_FORCE else ["-f"]
    assert main(line + force) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"tsog: error: {out}: "), err
    assert BAD_LOCATIONS[where] in err
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, not even a folder
    assert not Path("/proc", f"tsog-test-{os.getpid()}").exists()


@pytest.mark.parametrize("command", list(OUTPUT_RUNS))
@pytest.mark.parametrize("spelled", ["path", "file URL"])
def test_every_writer_makes_a_missing_output_folder(
    command: str, spelled: str, written_inputs: dict[str, Path], tmp_path: Path
) -> None:
    """A path or a ``file://`` URL names the same place (a URL was once written below the
    working folder as ``./file:/...``)."""
    argv, name = OUTPUT_RUNS[command]
    out = tmp_path / "new" / "deeper" / name
    given = out.as_uri() if spelled == "file URL" else str(out)
    names = {k: str(v) for k, v in written_inputs.items()}
    assert main([command, *(a.format(out=given, **names) for a in argv), "-q"]) == 0
    assert out.is_dir() if name == "u" else out.is_file()
    assert not [p for p in out.parent.iterdir() if p.name.endswith(".tmp")]


def test_an_existing_output_is_kept_without_force_and_a_trailing_slash_is_no_file_name(
    written_inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "c.tsogs"
    out.write_bytes(b"keep")
    chunk = str(written_inputs["chunk"])
    assert main(["segment", chunk, "-o", str(out), "-q"]) == 1
    assert (
        capsys.readouterr().err
        == f"tsog: error: {out}: already exists (pass --force to replace it)\n"
    )
    assert out.read_bytes() == b"keep"
    assert main(["segment", chunk, "-o", f"{tmp_path}/newdir/", "-q"]) == 1
    assert "ends with a path separator: expected a file name" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.tsogs"]


# --- static scenes and assumed lengths (issue 55) ---------------------------------------------


def test_segment_view_info_verify_and_play_take_a_static_scene(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tsog segment`` (and tsog view's segmentation, which runs it) makes a static PLY a
    stream of one moment, with its thumbnail; info, verify and play read it."""
    sample = samples / "3dgs/gs3d_pr477_lod3_tile_0.ply"
    out = tmp_path / "streams" / "static.tsogs"
    assert main(["segment", str(sample), "-o", str(out), "--workers", "1", "-q"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{out}: ")
    assert lines[1] == "  a static scene: a stream of one moment (0 s), shown the same at any time"
    assert "  1 windows, 1 chunks" in lines
    assert not any("never visible" in line or "layout" in line for line in lines)
    assert f"  thumbnail: {out}.thumb.png" in lines
    assert Path(f"{out}.thumb.png").read_bytes().startswith(b"\x89PNG")
    assert main(["info", str(out), "--json", "-q"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["duration"] == "static (one moment)"
    assert info["scene"]["timeline_type"] is None and info["scene"]["end_s"] == 0.0
    assert main(["verify", str(out), "-q"]) == 0
    assert main(["play", str(out), "-q"]) == 0
    assert "frames:          1" in capsys.readouterr().out
    frame = tmp_path / "at-5s.ply"
    assert main(["frame", str(out), "--t", "5", "-o", str(frame), "-q"]) == 0
    assert len(read_ply(frame).gaussians) == info["scene"]["gaussians"]
    args = build_parser().parse_args(["view", str(sample), "--cache", str(tmp_path / "cache")])
    copy = view_command._segmented(args, Progress(quiet=True))
    with open_stream(copy) as stream:
        assert stream.index.manifest.scene.timeline_type is None
        assert len(stream.frame_at(3.0)) == info["scene"]["gaussians"]


HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
ASSUMED = "duration 1.00 s (assumed: pass --duration-s)"


def test_an_assumed_splatv_length_is_said_first_and_kept_in_the_index(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clip = samples / HANABI
    out = tmp_path / "clip.tsogs"
    argv = ["segment", str(clip), "-o", str(out), "--layers", "1", "--workers", "1"]
    assert main(argv) == 0
    said = capsys.readouterr()
    assert said.err.splitlines()[0] == (
        f"tsog: warning: {clip.name} does not say its length: read as 1 s; set it with --duration-s"
    )
    assert "normalised" not in said.err  # the reader's own note is not said twice
    assert said.out.splitlines()[1] == f"  {ASSUMED}"
    with open_stream(out) as stream:
        assert stream.index.manifest.scene.duration_assumed is True
    with open_source(out) as source:  # what tsog render and eval say of the container
        assert source.notes == [
            "its length, 1 s, was assumed when it was segmented (the input did not say it): "
            "segment it again with --duration-s"
        ]
    for target in (out, clip):
        assert main(["info", str(target), "-q"]) == 0
        shown = capsys.readouterr()
        assert f"duration: {ASSUMED[9:]}" in shown.out.splitlines(), target
    assert main([*argv, "-f", "--duration-s", "4"]) == 0
    said = capsys.readouterr()
    assert "does not say its length" not in said.err
    assert said.out.splitlines()[1] == "  duration 4.00 s"
    with open_stream(out) as stream:
        assert stream.index.manifest.scene.duration_assumed is False
        assert b"duration_assumed" not in dump_manifest(stream.index.manifest)
    assert main(["info", str(clip), "--duration-s", "4", "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["duration"] == "4.00 s"


# --- output for people: tsog play's summary, the demo's script and hint (issue 55) ---


def test_play_says_a_few_lines_and_a_line_per_frame_only_with_v(
    dynamic_stream: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """By default a log gets the summary (frames and first picture, stalls, bytes) and a
    progress line every few seconds; -v a line per frame and the whole report."""
    monkeypatch.setattr(progress_module, "QUIET_SECONDS", 0.0)  # a log from the first frame
    assert main(["play", str(dynamic_stream)]) == 0
    out, err = capsys.readouterr()
    summary = out.splitlines()
    assert [line.split(":")[0] for line in summary] == [
        "frames",
        "first picture",
        "stalls",
        "fetched",
    ]
    frames = int(summary[0].split()[1])
    assert frames > 5 and re.fullmatch(r"first picture: +\d+\.\d ms", summary[1])
    assert re.fullmatch(r"fetched: +\d+ bytes in \d+ requests \(\d+\.\d\d MB/s\)", summary[3])
    assert len(err.splitlines()) <= 3, err  # opening, then a frame line every LOG_BAR_SECONDS
    assert main(["play", str(dynamic_stream), "-v"]) == 0
    out, err = capsys.readouterr()
    assert len([line for line in err.splitlines() if "] t = " in line]) == frames
    assert [line.split(":")[0] for line in out.splitlines()] == [
        "frames",
        "first picture",
        "startup latency",
        "stalls",
        "fetched",
        "cache hit rate",
        "layers shown",
    ]


REPO_ROOT = Path(__file__).resolve().parents[1]
NOT_PYTHON = (
    *("apt", "apt-get", "aptitude", "dpkg", "snap", "yum", "dnf", "brew", "npm", "npx"),
    *("node", "sudo", "su", "doas", "wrk", "nginx", "chromium", "curl", "wget"),
)
"""Package managers, ways to root and the other tools scripts/setup installs or uses."""


def _stub(path: Path, body: str) -> None:
    """An executable shell script."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


@pytest.mark.parametrize("venv", ["set up", "missing"])
def test_the_demo_script_needs_nothing_but_python(tmp_path: Path, venv: str) -> None:
    """scripts/demo, run in a copy of the repository with every package manager, sudo and
    the benchmark tools on PATH recording their calls: it makes .venv with Python and pip
    when it is missing, calls none of them, and runs tsog demo with the arguments given."""
    repo, calls = tmp_path / "repo", tmp_path / "calls"
    (repo / "scripts").mkdir(parents=True)
    shutil.copy(REPO_ROOT / "scripts" / "demo", repo / "scripts" / "demo")
    shutil.copy(REPO_ROOT / "pyproject.toml", repo / "pyproject.toml")
    for name in NOT_PYTHON:
        _stub(tmp_path / "bin" / name, f'echo "{name} $*" >> {calls}; exit 1')
    venv_python = f'echo "venv-python $*" >> {calls}'
    tsog = f'echo "tsog $*" >> {calls}'
    if venv == "set up":
        stamp = hashlib.sha256((repo / "pyproject.toml").read_bytes()).hexdigest()[:16]
        _stub(repo / ".venv" / "bin" / "tsog", tsog)
        (repo / ".venv" / f".tsog-installed-{stamp}").touch()
    _stub(  # python3 -m venv DIR: a venv whose python and tsog record their calls
        tmp_path / "python",
        f'echo "python $*" >> {calls}; mkdir -p "$3/bin"\n'
        f"printf '#!/bin/sh\\n%s\\n' '{venv_python}' > \"$3/bin/python\"\n"
        f"printf '#!/bin/sh\\n%s\\n' '{tsog}' > \"$3/bin/tsog\"\n"
        'chmod +x "$3/bin/python" "$3/bin/tsog"',
    )
    env = {**os.environ, "PATH": f"{tmp_path / 'bin'}:{os.environ['PATH']}"}
    env["PYTHON"] = str(tmp_path / "python")
    for _ in range(2):  # the second run installs nothing again
        done = subprocess.run(
            ["bash", str(repo / "scripts" / "demo"), "--seed", "3"],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert done.returncode == 0, done.stderr
    said = calls.read_text().splitlines()
    install = [
        "python -m venv .venv",
        "venv-python -m pip install --quiet --disable-pip-version-check -e .",
    ]
    ran = ["tsog demo --seed 3"] * 2
    assert said == (ran if venv == "set up" else [*install, *ran])


# --- tsog info of a chunk reads its timeline only ----------------------------------------------

CONFORMANCE = Path(__file__).parent / "data" / "conformance"


@pytest.mark.parametrize("name", sorted(p.name for p in CONFORMANCE.iterdir() if p.is_dir()))
def test_info_gives_a_chunks_time_range_as_its_decode_does(
    name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tsog info`` decodes a chunk's timeline images alone: the same time range as the
    whole chunk decoded."""
    folder = CONFORMANCE / name
    scene = read_chunk(folder)
    assert scene.timeline is not None
    first, last = time_range(scene.timeline)
    assert main(["info", str(folder), "--json", "-q"]) == 0
    timeline = json.loads(capsys.readouterr().out)["timeline"]
    assert timeline["time_range_s"] == [round(first, 6), round(last, 6)]
    assert timeline["type"] == int(scene.timeline.type)
