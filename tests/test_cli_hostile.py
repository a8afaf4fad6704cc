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
import io
import json
import os
import subprocess
import sys
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cli_probe import PRELOADED
from conftest import SAMPLES
from tsog_stream import TimelineType, open_stream
from tsog_stream.cli.main import build_parser
from tsog_stream.codec.bundle import bundle_bytes, read_bundle
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.codec.webp import encode_webp
from tsog_stream.io.ply import write_ply
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import small_scene, static_gaussians

PROBE = Path(__file__).with_name("cli_probe.py")
INVALID_CORPUS = Path(__file__).with_name("data") / "invalid"
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
    "live": ["{input}", "-o", "{out}/l", "--fps", "30", "--idle", "0.5"],
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
    "live": ["{frames}", "-o", "{out}/l", "--fps", "30", "--idle", "0.5"],
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
    frames = root / "frames"  # an event that has ended: two frames and the end marker
    frames.mkdir()
    for k in range(2):
        write_ply(frames / f"frame_{k}.ply", static_gaussians(50, seed=k))
    (frames / "END").write_bytes(b"")
    named = {"chunk": chunk, "stream": stream, "unpacked": unpacked, "root": streams}
    named |= {"frames": frames}
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


# --- the memory test: every file input of at most 10 MB stays under 1 GiB --------------------

MEMORY_LIMIT = 1 << 30
"""Peak resident memory a command may reach on any file input of at most MAX_INPUT_BYTES."""
MAX_INPUT_BYTES = 10 * MiB
EXIT_CODES = {0, 1, 2, 3, 4, 5, 6}
"""Every exit status a command documents (cli/main.py: 1 error, 2 usage; tsog verify: 3-6)."""
SCENE_RUNS: dict[str, list[str]] = {
    "info": ["{input}"],
    "decode": ["{input}", "{out}/o.ply"],
    "frame": ["{input}", "--t", "0", "-o", "{out}/f.ply"],
    "encode": ["{input}", "{out}/o.sog"],
    "segment": ["{input}", "-o", "{out}/s.tsogs"],
    "render": ["{input}", "-o", "{out}/r.png", "--width", "32", "--height", "24"],
    "eval": ["{input}", "{input}", "--width", "32", "--height", "24"],
}
"""Every command that reads a scene input (PLY, SOG, .splatv, a chunk folder, a sequence)."""
STREAM_RUNS: dict[str, list[str]] = {
    "info": ["{input}"],
    "verify": ["{input}"],
    "frame": ["{input}", "--t", "0", "-o", "{out}/f.ply"],
    "extract": ["{input}", "0", "-o", "{out}/c.sog"],
    "render": ["{input}", "-o", "{out}/r.png", "--width", "32", "--height", "24"],
}
"""Every command that reads a .tsogs container."""
CAMERA_RUNS: dict[str, list[str]] = {
    "info": ["{input}"],
    "encode": ["{input}", "{out}/o.sog"],
    "render": ["{input}", "-o", "{out}/r.png", "--width", "32", "--height", "24"],
}
"""Commands that read the cameras.json or COLMAP model beside a scene input."""
LIGHT = ("info", "decode", "verify")
"""What every real input goes through; the heavier commands take one input of each kind."""
BOMB_BYTES = 512 * MiB
"""What a generated bomb inflates to: half of the memory limit."""


def deflated_zeros(size: int) -> tuple[bytes, int]:
    """A raw deflate stream of ``size`` zero bytes (a multiple of 8 MiB) and their CRC-32:
    one 8 MiB segment compressed and flushed to a byte boundary with its history reset,
    repeated (each segment decodes alone), then a final empty block; quick to make."""
    block = 8 * MiB
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    segment = compressor.compress(bytes(block)) + compressor.flush(zlib.Z_FULL_FLUSH)
    ending = zlib.compressobj(9, zlib.DEFLATED, -15).flush()
    crc, zeros = 0, bytes(MiB)
    for _ in range(size // MiB):
        crc = zlib.crc32(zeros, crc)
    return segment * (size // block) + ending, crc


def with_bomb_member(files: dict[str, bytes], name: str, size: int) -> bytes:
    """The bundled chunk of ``files`` with member ``name`` replaced by ``size`` deflated zero
    bytes, its sizes and CRC-32 told truthfully: stored first, then its local and central
    records say deflated."""
    raw, crc = deflated_zeros(size)
    archive = bytearray(bundle_bytes({**files, name: raw}))
    with zipfile.ZipFile(io.BytesIO(bytes(archive))) as reading:
        local = reading.getinfo(name).header_offset
    central = archive.rfind(b"PK\x05\x06")  # end of central directory: where it starts
    central = int.from_bytes(archive[central + 16 : central + 20], "little")
    while archive[central + 46 : central + 46 + len(name)] != name.encode():
        central += 46 + sum(
            int.from_bytes(archive[central + at : central + at + 2], "little")
            for at in (28, 30, 32)
        )
    for record, method, crc_at, size_at in ((local, 8, 14, 22), (central, 10, 16, 24)):
        archive[record + method : record + method + 2] = zipfile.ZIP_DEFLATED.to_bytes(2, "little")
        archive[record + crc_at : record + crc_at + 4] = crc.to_bytes(4, "little")
        archive[record + size_at : record + size_at + 4] = size.to_bytes(4, "little")
    return bytes(archive)


def with_other_byte_order(data: bytes) -> bytes:
    """A binary PLY whose header names the byte order its rows are not in."""
    little, big = b"format binary_little_endian ", b"format binary_big_endian "
    return data.replace(little, big, 1) if little in data[:4096] else data.replace(big, little, 1)


def beside_a_scene(folder: Path, cameras: dict[str, bytes]) -> Path:
    """A small PLY in ``folder`` with camera files beside it (name -> bytes); its path."""
    for name, data in cameras.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    write_ply(folder / "scene.ply", static_gaussians(64, seed=1))
    return folder / "scene.ply"


def generated_bombs(root: Path, chunk: Path, count_bomb: Path) -> dict[str, Path]:
    """One file input (at most 10 MB) of each class of issue 55 that costs gigabytes when a
    reader trusts it."""
    files = read_bundle(chunk.read_bytes())
    root.mkdir()
    made = {
        "named image inflating 512 MiB": (
            "named.sog",
            with_bomb_member(files, "means_l.webp", BOMB_BYTES),
        ),
        "meta.json inflating 512 MiB": (
            "meta.sog",
            with_bomb_member(files, "meta.json", BOMB_BYTES),
        ),
        "unnamed member inflating 512 MiB": (
            "unnamed.sog",
            with_bomb_member({**files, "padding.bin": b""}, "padding.bin", BOMB_BYTES),
        ),
        "PLY rows in the other byte order": (
            "swapped.ply",
            with_other_byte_order((SAMPLES / "3dgs" / "v3dg_donut_fused.ply").read_bytes()),
        ),
    }
    bombs = {what: root / name for what, (name, _) in made.items()}
    for name, data in made.values():
        (root / name).write_bytes(data)
    bombs["count of 36 M Gaussians"] = count_bomb
    room = MAX_INPUT_BYTES - 64 * 1024  # for the scene beside them
    empty_objects = b"[" + b"{}," * (room // 3 - 1) + b"{}]"
    (root / "json").mkdir()
    bombs["cameras.json of 10 MB of empty objects"] = beside_a_scene(
        root / "json", {"cameras.json": empty_objects}
    )
    lines = "".join(f"{i} PINHOLE 64 48 50 50 32 24\n" for i in range(room // 34))
    images = b"1 1 0 0 0 0 0 0 1 a.png\n\n"
    (root / "colmap").mkdir()
    bombs["COLMAP cameras.txt of 10 MB"] = beside_a_scene(
        root / "colmap", {"sparse/0/cameras.txt": lines.encode(), "sparse/0/images.txt": images}
    )
    return bombs


def input_bytes(path: Path) -> int:
    """Bytes of a file input, or of every file under a folder input."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def corpus_inputs(root: Path) -> dict[str, tuple[Path, dict[str, list[str]]]]:
    """Each file of tests/data/invalid/ as the input of every command that opens its kind
    (a meta.json in a chunk folder; a cameras.json beside a scene); the index and manifest
    files are parts of a container, opened through the .tsogs files."""
    inputs: dict[str, tuple[Path, dict[str, list[str]]]] = {}
    for path in sorted(INVALID_CORPUS.iterdir()):
        if path.suffix in (".ply", ".sog", ".splatv"):
            inputs[path.name] = (path, SCENE_RUNS)
        elif path.suffix == ".tsogs":
            inputs[path.name] = (path, STREAM_RUNS)
        elif path.suffix == ".json":
            (root / path.stem).mkdir(parents=True)
            (root / path.stem / "meta.json").write_bytes(path.read_bytes())
            inputs[path.name] = (root / path.stem, SCENE_RUNS)
        elif path.suffix == ".cameras":
            (root / path.stem).mkdir(parents=True)
            scene = beside_a_scene(root / path.stem, {"cameras.json": path.read_bytes()})
            inputs[path.name] = (scene, CAMERA_RUNS)
    return inputs


def real_inputs(stream: Path) -> dict[str, tuple[Path, dict[str, list[str]]]]:
    """Every real input of tests/data/real/ through the commands that read it whole, one of
    each kind (and a stream the segmenter wrote) through every command that opens it."""
    inputs: dict[str, tuple[Path, dict[str, list[str]]]] = {}
    light = {command: SCENE_RUNS[command] for command in LIGHT if command in SCENE_RUNS}
    for path in sorted(SAMPLES.rglob("*")):
        if path.suffix in (".ply", ".sog", ".splatv") or (path / "meta.json").is_file():
            inputs[path.name] = (path, light)
    for largest in (  # the most Gaussians of each reader: the most memory in every command
        "3dgs/v3dg_donut_fused.ply",
        "3dgs/pc_guitar.compressed.ply",
        "4d/splatv/tztechno_hanabi2_synthetic.splatv",
    ):
        inputs[largest] = (SAMPLES / largest, SCENE_RUNS)
    inputs["a stream"] = (stream, STREAM_RUNS)
    return inputs


@pytest.mark.slow
def test_every_file_input_of_at_most_10_mb_stays_under_1_gib_in_every_command(
    files: dict[str, Path], tmp_path: Path
) -> None:
    """Issue 55's promise, measured: every hostile file of the corpus, a generated bomb of
    each class (each inflating or parsing to gigabytes when trusted) and the real inputs,
    each at most 10 MB, through every command that opens its kind, in a process of its own:
    an exit status the commands document, no traceback, and a peak resident memory (the
    interpreter's own included) under 1 GiB."""
    bombs = generated_bombs(tmp_path / "bombs", files["chunk"], files["hostile:bomb.sog"])
    inputs = {
        **corpus_inputs(tmp_path / "corpus"),
        **{what: (path, SCENE_RUNS) for what, path in bombs.items()},
        **real_inputs(files["stream"]),
    }
    inputs["cameras.json of 10 MB of empty objects"] = (
        bombs["cameras.json of 10 MB of empty objects"],
        CAMERA_RUNS,
    )
    colmap = "COLMAP cameras.txt of 10 MB"  # 300k cameras parsed in Python: one command
    inputs[colmap] = (bombs[colmap], {"info": CAMERA_RUNS["info"]})
    runs: list[dict[str, Any]] = []
    whats: list[tuple[str, str]] = []
    for what, (path, commands) in inputs.items():
        beside = path.name == "scene.ply"  # its folder holds the camera files read
        assert input_bytes(path.parent if beside else path) <= MAX_INPUT_BYTES, what
        for command, argv in commands.items():
            out = tmp_path / "out" / f"{len(runs)}"
            out.mkdir(parents=True)
            line = [command, *(a.format(input=path, out=out) for a in argv), "-q"]
            runs.append({"argv": line, "cwd": str(out), "timeout_s": RUN_TIMEOUT_S})
            whats.append((what, command))
    base = interpreter_rss()
    for run, outcome in zip(whats, probe(runs), strict=True):
        assert not outcome.timed_out and outcome.code in EXIT_CODES, (run, outcome)
        assert "Warning" not in outcome.stderr, (run, outcome.stderr)  # numpy's, Pillow's
        assert_ended_cleanly(outcome, run, accepted_ok=True, budget=MEMORY_LIMIT - base)
    assert len(runs) > 500


def interpreter_rss() -> int:
    """Peak resident memory of an interpreter with every module the probe preloads: what
    each probed command's growth is measured beyond. Read as VmHWM, which an exec starts
    afresh: ru_maxrss keeps the high-water mark of the process that forked it (a pytest
    worker grown to 900 MiB by the test files before this one left 150 MiB of budget)."""
    script = "import importlib, re, sys\n"
    script += "for name in sys.argv[1:]: importlib.import_module(name)\n"
    script += "status = open('/proc/self/status').read()\n"
    script += "print(re.search(r'VmHWM:\\s+(\\d+) kB', status).group(1))"
    done = subprocess.run(
        [sys.executable, "-c", script, *PRELOADED],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    return int(done.stdout) * 1024


@pytest.mark.slow
def test_info_on_a_small_chunk_declaring_16m_gaussians_stays_under_1_gib(tmp_path: Path) -> None:
    """Five 4096x4096 images, constant but for a 128x128 block of noise (70 KB each), and a
    meta.json declaring one Gaussian per texel pass every bound a reader has: ``tsog info``
    says what the chunk holds from its meta and image headers, never decoding its Gaussians
    (it did, at 2.4 GB). Decoding them (decode, frame, render) costs what 16.7M Gaussians
    cost, as an honest chunk of that count does (docs/reliability.md)."""
    noise = np.random.default_rng(0).integers(0, 256, (128, 128, 4), dtype=np.uint8)
    image = np.full((4096, 4096, 4), 128, np.uint8)
    image[:128, :128] = noise
    webp = encode_webp(image)
    names = ("means_l.webp", "means_u.webp", "scales.webp", "quats.webp", "sh0.webp")
    codebook = [i / 16 - 8 for i in range(256)]
    meta = {
        "version": 2,
        "count": 4096 * 4096,
        "means": {"mins": [-1.0] * 3, "maxs": [1.0] * 3, "files": list(names[:2])},
        "scales": {"codebook": codebook, "files": [names[2]]},
        "quats": {"files": [names[3]]},
        "sh0": {"codebook": codebook, "files": [names[4]]},
    }
    path = tmp_path / "count.sog"
    path.write_bytes(
        bundle_bytes({**dict.fromkeys(names, webp), "meta.json": json.dumps(meta).encode()})
    )
    assert input_bytes(path) <= MAX_INPUT_BYTES
    (outcome,) = probe(
        [{"argv": ["info", str(path), "-q"], "cwd": str(tmp_path), "timeout_s": 120}]
    )
    assert outcome.code in EXIT_CODES and "Traceback" not in outcome.stderr
    assert outcome.rss_growth + interpreter_rss() < MEMORY_LIMIT, outcome.rss_growth // MiB
