"""Every tsog command against hostile files and hostile option values, measured as a person
would see it: each command line runs in its own process (forked by tests/cli_probe.py), and
must end with an exit code, no traceback, a bounded peak RSS and, on failure, one
``tsog: error:`` line or argparse's usage, with nothing half-written.

The option values are not a hand-picked list: every option the parser declares with a number
type (and every free-text option) gets each of :data:`HOSTILE_NUMBERS`, so an option added
later is covered without touching this file.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tsog_stream import TimelineType, open_stream
from tsog_stream.cli.main import build_parser
from tsog_stream.codec.bundle import bundle_bytes, read_bundle
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.segment.segmenter import SegmentOptions, segment_scene
from tsog_stream.synthetic import small_scene

PROBE = Path(__file__).with_name("cli_probe.py")
MiB = 1 << 20
RSS_BUDGET = 256 * MiB
"""Peak resident memory a command may add to an interpreter with every module loaded. The
bombs this guards against cost gigabytes; honest runs on the test's small files use up to
125 MiB (render's numba compilation)."""
REFUSAL_RSS_BUDGET = 32 * MiB
"""Peak a hostile file may cost before it is refused (measured: at most 5 MiB)."""
RUN_TIMEOUT_S = 60.0

HOSTILE_FILE_RUNS = {
    "encode": ["{input}", "{out}/o.sog"],
    "decode": ["{input}", "{out}/o.ply"],
    "info": ["{input}"],
    "frame": ["{input}", "--t", "0.5", "-o", "{out}/f.ply"],
    "segment": ["{input}", "-o", "{out}/s.tsogs"],
    "verify": ["{input}"],
    "extract": ["{input}", "0", "-o", "{out}/c.sog"],
    "unpack": ["{input}", "-o", "{out}/u"],
    "pack": ["{input}", "-o", "{out}/p.tsogs"],
    "fetch": ["{input}", "--t", "0.5", "-o", "{out}/f.ply"],
    "play": ["{input}", "--duration", "0.1"],
    "render": ["{input}", "-o", "{out}/r.png", "--width", "32", "--height", "24"],
    "eval": ["{input}", "{input}", "--width", "32", "--height", "24"],
    "view": ["{input}", "--port", "0"],
}
"""Every command that reads an input, with the input replaced by something hostile (serve,
sign and demo take no input file)."""

GOOD_RUNS = {
    **HOSTILE_FILE_RUNS,
    "frame": ["{chunk}", "--t", "0.5", "-o", "{out}/f.ply"],
    "fetch": ["{stream}", "--t", "0.5", "-o", "{out}/f.ply"],
    "play": ["{stream}", "--duration", "0.1"],
    "extract": ["{stream}", "0", "-o", "{out}/c.sog"],
    "unpack": ["{stream}", "-o", "{out}/u"],
    "pack": ["{unpacked}", "-o", "{out}/p.tsogs"],
    "verify": ["{stream}"],
    "serve": ["{root}", "--port", "0"],
    "sign": ["http://127.0.0.1:1/files/clip.tsogs", "--secret-file", "{secret}"],
    "demo": ["--out", "{out}/demo"],
    "view": ["{stream}", "--port", "0"],
}
"""A command line per command that works on the test's small files: each option is then
replaced by hostile values one at a time."""
INPUT_OF = {"info": "{chunk}", "decode": "{chunk}", "encode": "{chunk}", "segment": "{chunk}"}
LONG_RUNNING = {"serve", "view"}
"""Commands that run until stopped: alive at the deadline means the values were accepted."""
HOSTILE_NUMBERS = ("nan", "-inf", "1e308", "-1", "0", "99999999999999999999")
SKIPPED_OPTIONS = {"--host", "--private", "--secret-file", "--cameras", "--out", "--plot"}
"""Options naming a network interface (only loopback is ever bound here) or a file (a path
option given ``-1`` just names a file called -1)."""


@dataclass(frozen=True)
class Outcome:
    code: int | None
    stderr: str
    rss_growth: int
    seconds: float
    timed_out: bool


def probe(runs: list[dict[str, Any]]) -> list[Outcome]:
    """Run command lines through tests/cli_probe.py and return what each did."""
    with tempfile.TemporaryDirectory(prefix="tsog-cli-probe-") as scratch:
        done = subprocess.run(  # tsog view's copies go to the scratch folder, never ~/.cache
            [sys.executable, str(PROBE)],
            env={**os.environ, "TSOG_CACHE_DIR": scratch, "TMPDIR": scratch},
            input=json.dumps(runs),
            capture_output=True,
            text=True,
            check=True,
            timeout=60 + sum(r["timeout_s"] + 10 for r in runs),
        )
    return [Outcome(**r) for r in json.loads(done.stdout)]


def hostile_inputs(folder: Path, bomb_meta: bytes) -> dict[str, Path]:
    """Garbage, a truncated zip, an empty file, a folder, a FIFO and a zip declaring 36 M
    Gaussians: every one must end in a one-line error."""
    folder.mkdir()
    made = {
        "garbage": b"\x00garbage" * 64,
        "truncated.sog": b"PK\x03\x04" + bytes(40),
        "empty.ply": b"",
        "container-magic.tsogs": b"TSOGS\x00\r\n" + bytes(200),
        "bomb.sog": bundle_bytes({"meta.json": bomb_meta}),
    }
    for name, data in made.items():
        (folder / name).write_bytes(data)
    (folder / "folder").mkdir()
    os.mkfifo(folder / "fifo.ply")
    return {name: folder / name for name in [*made, "folder", "fifo.ply"]}


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A small dynamic chunk, its stream (packed and unpacked), a serve root and a secret."""
    root = tmp_path_factory.mktemp("hostile-cli")
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=("means",))
    chunk = root / "dynamic.sog"
    chunk.write_bytes(bundle_bytes(encode_chunk(scene)))
    streams = root / "streams"
    streams.mkdir()
    stream = streams / "clip.tsogs"
    segment_scene(scene, stream, SegmentOptions(window_s=0.5, workers=1))
    unpacked = root / "unpacked"
    with open_stream(stream) as opened:
        opened.unpack(unpacked)
    secret = root / "url.key"
    secret.write_bytes(os.urandom(32))
    secret.chmod(0o600)
    meta = json.loads(read_bundle(chunk.read_bytes())["meta.json"])
    meta["count"] = 36_000_000
    bombs = hostile_inputs(root / "hostile", json.dumps(meta).encode())
    named = {"chunk": chunk, "stream": stream, "unpacked": unpacked, "root": streams}
    return {**named, "secret": secret, **{f"hostile:{k}": v for k, v in bombs.items()}}


def fill(argv: list[str], files: dict[str, Path], out: Path) -> list[str]:
    """A command line's placeholders replaced by the test's paths."""
    names = {k: str(v) for k, v in files.items() if ":" not in k}
    return [a.format(out=out, **names) for a in argv]


def assert_ended_cleanly(
    outcome: Outcome, what: object, *, accepted_ok: bool, budget: int = RSS_BUDGET
) -> None:
    """No traceback, bounded memory, an exit; a failure is one error line or usage."""
    err = outcome.stderr
    assert "Traceback" not in err, (what, err)
    assert outcome.rss_growth < budget, (what, outcome.rss_growth // MiB, "MiB")
    if outcome.timed_out:
        assert accepted_ok, (what, "still running after", RUN_TIMEOUT_S, "s", err)
        return
    assert outcome.code is not None and outcome.code != 99, (what, err)
    if outcome.code == 0:
        assert accepted_ok, (what, "accepted")
        return
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert last.startswith("tsog: error:") or "usage: tsog" in err, (what, outcome.code, err)


def test_every_command_ends_every_hostile_file_in_one_line(
    files: dict[str, Path], tmp_path: Path
) -> None:
    runs, whats, outs = [], [], []
    for command, argv in HOSTILE_FILE_RUNS.items():
        for name, path in files.items():
            if not name.startswith("hostile:"):
                continue
            out = tmp_path / f"{command}-{name[8:]}"
            out.mkdir()
            line = [command, *fill(argv, {**files, "input": path}, out), "-q"]
            runs.append({"argv": line, "cwd": str(out), "timeout_s": RUN_TIMEOUT_S})
            whats.append((command, name))
            outs.append(out)
    for what, out, outcome in zip(whats, outs, probe(runs), strict=True):
        assert_ended_cleanly(outcome, what, accepted_ok=False, budget=REFUSAL_RSS_BUDGET)
        assert outcome.code == 1, (what, outcome.stderr)
        assert not any(out.iterdir()), what  # nothing half-written


def hostile_option_runs(files: dict[str, Path], tmp_path: Path) -> Iterator[tuple[Any, ...]]:
    """(what, run) for each command's working line with one option's value made hostile."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for command, sub in commands.choices.items():
        good = GOOD_RUNS[command]
        for action in sub._actions:
            flag = action.option_strings[-1] if action.option_strings else ""
            if not flag or action.nargs == 0 or flag in SKIPPED_OPTIONS:
                continue
            if action.choices is not None or action.type is Path:
                continue  # argparse checks choices; paths are just names
            for value in HOSTILE_NUMBERS:
                out = tmp_path / f"{command}{flag}{value}"
                out.mkdir()
                argv = [command, *fill(_with_input(command, good), files, out), flag, value]
                if command not in LONG_RUNNING:
                    argv.append("-q")
                timeout = 2.5 if command in LONG_RUNNING else RUN_TIMEOUT_S
                yield (command, flag, value), {"argv": argv, "cwd": str(out), "timeout_s": timeout}


def _with_input(command: str, argv: list[str]) -> list[str]:
    """The working line of ``command``, reading the small chunk where it reads one input."""
    first = INPUT_OF.get(command)
    if first is None:
        return [a.replace("{input}", "{chunk}") for a in argv]
    return [first if a == "{input}" else a for a in argv]


def test_no_option_value_makes_any_command_crash_hang_or_balloon(
    files: dict[str, Path], tmp_path: Path
) -> None:
    planned = list(hostile_option_runs(files, tmp_path))
    assert len(planned) > 150  # every numeric and free-text option of every command
    outcomes = probe([run for _, run in planned])
    for (what, _), outcome in zip(planned, outcomes, strict=True):
        assert_ended_cleanly(outcome, what, accepted_ok=True)


def test_every_integer_option_declares_its_range() -> None:
    """A bare ``type=int`` takes 10**20 and overflows (or loops) later: each integer option
    uses cli.common.Integer, whose range argparse reports."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    bare = [
        (command, action.dest)
        for command, sub in commands.choices.items()
        for action in sub._actions
        if action.type is int
    ]
    assert bare == []


def test_the_probe_sees_memory_numpy_allocates(files: dict[str, Path], tmp_path: Path) -> None:
    """Negative control: an honest render of a large image must show up as RSS growth beyond
    the budget (tracemalloc, used before, missed allocations made outside Python)."""
    line = ["render", str(files["chunk"]), "-o", str(tmp_path / "big.png"), "-q"]
    line += ["--width", "4000", "--height", "4000"]
    (outcome,) = probe([{"argv": line, "cwd": str(tmp_path), "timeout_s": RUN_TIMEOUT_S}])
    assert outcome.code == 0, outcome.stderr
    assert outcome.rss_growth > RSS_BUDGET, outcome.rss_growth // MiB
