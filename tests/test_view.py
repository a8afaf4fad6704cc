"""``tsog view``: any input to a served player page in one step, segmented once and reused."""

from __future__ import annotations

import argparse
import errno
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from fixtures_4d import freetime_npz, freetime_truth
from helpers import ThreadedServer
from tsog_stream import inputs
from tsog_stream.cli import view_cache, view_command
from tsog_stream.cli.main import build_parser, main
from tsog_stream.cli.progress import Progress
from tsog_stream.container.header import Header
from tsog_stream.io.ply import write_ply
from tsog_stream.model import Gaussians, Scene, evaluate_all
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians

FRAMES = "4d/tztechno_fireworks_frames"
START_TIMEOUT_S = 120


@contextmanager
def tsog_view(
    *argv: str, cache: Path, errors: list[str] | None = None
) -> Iterator[tuple[str, list[str]]]:
    """Run ``tsog view`` until it prints its URL; yields the URL and the lines before it, then
    stops it with Ctrl-C (SIGINT), which must end it without a traceback (``errors``, if
    given, receives the lines it wrote on stderr)."""
    env = {**os.environ, "TSOG_CACHE_DIR": str(cache)}
    command = [sys.executable, "-m", "tsog_stream.cli.main", "view", *argv, "-q"]
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True
    ) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        try:
            yield _url_of(proc)
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                code = proc.wait(timeout=20)
            finally:
                if proc.poll() is None:
                    proc.kill()
        said = proc.stderr.read()
        assert code in (0, 130) and "Traceback" not in said
        if errors is not None:
            errors.extend(said.splitlines())


def _url_of(proc: subprocess.Popen[str]) -> tuple[str, list[str]]:
    """The player URL ``tsog view`` prints, and the lines it printed before."""
    assert proc.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            err = proc.stderr.read() if proc.stderr else ""
            pytest.fail(f"tsog view exited with {proc.wait()}: {err}")
        if line.startswith("playing at "):
            return line.split()[2], lines
        lines.append(line)
    pytest.fail("tsog view printed no URL in time")


def get(url: str) -> tuple[int, bytes, str]:
    with urllib.request.urlopen(url, timeout=10) as response:  # loopback only
        return response.status, response.read(), response.geturl()


def test_view_segments_once_serves_the_player_and_reuses_the_copy(
    samples: Path, tmp_path: Path
) -> None:
    frames = tmp_path / "fireworks"
    shutil.copytree(samples / FRAMES, frames)
    cache = tmp_path / "cache"
    with tsog_view(str(frames), "--fps", "6", cache=cache) as (url, before):
        assert url.startswith("http://127.0.0.1:") and url.endswith("/play/fireworks")
        assert before[0].startswith("segmented ") and "/fireworks.tsogs (" in before[0]
        status, page, _ = get(url)
        assert status == 200 and b"tsog-config" in page
        base = url.split("/play/")[0]
        _, body, _ = get(f"{base}/v1/scenes/fireworks/manifest")
        manifest = json.loads(body)
        assert manifest["scene"]["fps"] == 6 and len(manifest["chunks"]) >= 1
        assert get(f"{base}/")[2] == f"{base}/play/"  # / redirects to the scene list
    copies = list(cache.glob("*/fireworks.tsogs"))
    assert len(copies) == 1
    # Unchanged: reused, not segmented again.
    with tsog_view(str(frames), "--fps", "6", cache=cache) as (_, before):
        assert any("reusing the copy segmented earlier" in line for line in before)
    # Another frame rate or a changed frame: a new copy.
    with tsog_view(str(frames), "--fps", "12", cache=cache):
        pass
    (frames / "frame_005.ply").unlink()
    with tsog_view(str(frames), "--fps", "6", cache=cache) as (_, before):
        assert not any("reusing" in line for line in before)
        # the copy of the frames as they were can never be used again: removed
        assert any("cache: removed 1 older" in line for line in before)
    assert len(list(cache.glob("*/fireworks.tsogs"))) == 2


def test_view_serves_a_container_as_it_is(samples: Path, tmp_path: Path) -> None:
    container = tmp_path / "clip.tsogs"
    argv = ["segment", str(samples / FRAMES), "-o", str(container), "-q"]
    subprocess.run([sys.executable, "-m", "tsog_stream.cli.main", *argv], check=True)
    with tsog_view(str(container), cache=tmp_path / "cache") as (url, before):
        assert url.endswith("/play/clip") and before == []
        assert get(url)[0] == 200
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize("given", ["container", "frames"])
def test_view_shows_the_thumbnail_of_what_it_serves(
    samples: Path, tmp_path: Path, given: str
) -> None:
    """tsog view serves one container (as given, or segmented into its cache): the list page's
    thumbnail URL answers with that container's PNG, as image/png (it was a 404)."""
    container = tmp_path / "clip.tsogs"
    argv = ["segment", str(samples / FRAMES), "--fps", "6", "-o", str(container), "-q"]
    subprocess.run([sys.executable, "-m", "tsog_stream.cli.main", *argv], check=True)
    target = str(container) if given == "container" else str(samples / FRAMES)
    extra = [] if given == "container" else ["--fps", "6"]
    with tsog_view(target, *extra, cache=tmp_path / "cache") as (url, _):
        base = url.split("/play/")[0]
        page = get(f"{base}/play/")[1].decode()
        images = re.findall(r'<img src="([^"]*)"', page)
        name = "clip" if given == "container" else "tztechno_fireworks_frames"
        assert images == [f"/v1/scenes/{name}/thumbnail"]
        with urllib.request.urlopen(base + images[0], timeout=10) as answer:
            status, png, kind = answer.status, answer.read(), answer.headers["Content-Type"]
    assert (status, kind) == (200, "image/png")
    served = container if given == "container" else next((tmp_path / "cache").glob("*/*.tsogs"))
    assert png == Path(f"{served}.thumb.png").read_bytes()
    with Image.open(io.BytesIO(png)) as image:
        assert image.size == (320, 180)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["http://127.0.0.1:9/clip.tsogs"], "tsog view opens local inputs"),
        (["{tmp}/missing.ply"], "missing.ply"),
        (["{tmp}", "--port", "70000"], "--port"),
    ],
)
def test_view_errors_are_one_line(tmp_path: Path, argv: list[str], message: str) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    command = [sys.executable, "-m", "tsog_stream.cli.main", "view", *args]
    env = {**os.environ, "TSOG_CACHE_DIR": str(tmp_path / "cache")}
    done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode in (1, 2) and "Traceback" not in done.stderr
    assert message in done.stderr.splitlines()[-1]


def test_the_scene_list_shows_thumbnail_duration_and_count(samples: Path, tmp_path: Path) -> None:
    root = tmp_path / "root"
    root.mkdir()
    segment = [sys.executable, "-m", "tsog_stream.cli.main", "segment", "--fps", "6", "-q"]
    frames = str(samples / FRAMES)
    done = subprocess.run(
        [*segment, frames, "-o", str(root / "fire.tsogs")],
        check=True,
        capture_output=True,
        text=True,
    )
    assert f"thumbnail: {root / 'fire.tsogs.thumb.png'}" in done.stdout
    shutil.copy(root / "fire.tsogs", root / "bare.tsogs")  # no thumbnail beside it
    server = ThreadedServer(make_app(root))
    try:
        base = f"http://127.0.0.1:{server.port}"
        listed = {s["id"]: s for s in json.loads(get(f"{base}/v1/scenes")[1])["scenes"]}
        assert listed["fire"]["thumbnail"] == "/v1/scenes/fire/thumbnail"
        assert listed["bare"]["thumbnail"] is None
        assert listed["fire"]["gaussians"] == 24000 and listed["fire"]["duration_s"] == 1.0
        assert listed["fire"]["gaussians_per_frame"] == 4000  # six frames of 4000
        page = get(f"{base}/play/")[1].decode()
        assert '<img src="/v1/scenes/fire/thumbnail"' in page
        assert "4,000 Gaussians per frame" in page and "24,000" not in page
        assert "1.00 s" in page and page.count("<img") == 1
        with urllib.request.urlopen(f"{base}/v1/scenes/fire/thumbnail", timeout=10) as answer:
            status, png, kind = answer.status, answer.read(), answer.headers["Content-Type"]
        with Image.open(io.BytesIO(png)) as image:
            pixels = np.asarray(image.convert("RGB"))
        assert status == 200 and kind == "image/png" and pixels.shape == (180, 320, 3)
        assert (np.abs(pixels.astype(int) - 18).max(axis=2) > 40).mean() > 0.01  # not blank
        with pytest.raises(urllib.error.HTTPError) as missing:
            get(f"{base}/v1/scenes/bare/thumbnail")
        missing.value.close()  # the error holds the response and its socket
        assert missing.value.code == 404
    finally:
        server.stop()


DRAWN_WHERE = """
import sys
from tsog_stream.pipeline import segment_input
from tsog_stream.segment import SegmentOptions
report = segment_input(sys.argv[1], sys.argv[2], SegmentOptions(workers=int(sys.argv[3])))
print(report.thumbnail, "numba" in sys.modules)
"""
"""Segment in a fresh process; print the thumbnail's path and whether numba (the renderer's
kernel) was ever loaded in that process."""


@pytest.mark.parametrize("workers", [1, 2])
def test_the_thumbnail_is_drawn_where_the_jobs_run(workers: int, tmp_path: Path) -> None:
    """With workers, the thumbnail is drawn in a process of its own (the renderer loaded on top
    of the heap segmenting left was the run's peak); with one, in this process."""
    source = tmp_path / "scene.ply"
    write_ply(source, static_gaussians(3000, seed=2))
    out = tmp_path / "scene.tsogs"
    done = subprocess.run(
        [sys.executable, "-c", DRAWN_WHERE, str(source), str(out), str(workers)],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    thumbnail, loaded = done.stdout.split()
    assert thumbnail == f"{out}.thumb.png" and loaded == str(workers == 1)
    with Image.open(thumbnail) as image:
        pixels = np.asarray(image.convert("RGB"))
    assert (np.abs(pixels.astype(int) - 18).max(axis=2) > 40).mean() > 0.01  # not blank


def test_a_thumbnail_draws_at_most_its_cap_of_the_most_opaque(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A huge scene's thumbnail draws its THUMBNAIL_GAUSSIANS most opaque Gaussians, in the
    scene's order (its render of 5M Gaussians took the process to 6 GB)."""
    monkeypatch.setattr(inputs, "THUMBNAIL_GAUSSIANS", 10)
    g = static_gaussians(50, seed=3)
    kept = inputs._most_opaque_at([Scene(g)], 0.0)
    expected = np.sort(np.argsort(-g.opacities, kind="stable")[:10])
    assert np.array_equal(kept.opacities, g.opacities[expected])
    small = g.subset(np.arange(8))
    assert inputs._most_opaque_at([Scene(small)], 0.0) is small
    # reduced piece by piece (a container chunk by chunk): the same Gaussians, same order
    pieces = [Scene(g.subset(np.arange(a, b))) for a, b in ((0, 20), (20, 35), (35, 50))]
    assert np.array_equal(inputs._most_opaque_at(pieces, 0.0).opacities, g.opacities[expected])
    assert len(inputs._most_opaque_at([], 0.0)) == 0


def test_a_thumbnail_cuts_each_piece_once_and_holds_little(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Pieces in any order (least opaque first, most opaque first, shuffled) give the cap's
    most opaque; what is held when the kept ones are re-selected stays within twice the cap
    and one piece, and most opaque first they are re-selected once."""
    cap, piece = 10, 10
    monkeypatch.setattr(inputs, "THUMBNAIL_GAUSSIANS", cap)
    g = static_gaussians(120, seed=5)
    expected = np.sort(g.opacities)[-cap:]
    rising = np.argsort(g.opacities, kind="stable")
    orders = {"rising": rising, "falling": rising[::-1]}
    orders["shuffled"] = np.random.default_rng(0).permutation(len(g))
    select = inputs._most_opaque_pieces
    for name, order in orders.items():
        held: list[int] = []

        def counted(kept: Sequence[Gaussians], held: list[int] = held) -> list[Gaussians]:
            held.append(sum(map(len, kept)))
            return select(kept)

        monkeypatch.setattr(inputs, "_most_opaque_pieces", counted)
        pieces = [Scene(g.subset(part)) for part in np.array_split(order, len(g) // piece)]
        kept = inputs._most_opaque_at(pieces, 0.0)
        assert np.array_equal(np.sort(kept.opacities), expected), name
        assert all(h <= 2 * cap + piece for h in held), (name, held)
        if name == "falling":
            assert len(held) == 1, held


def test_a_thumbnail_evaluates_the_most_opaque_at_t(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a moving scene in pieces, the thumbnail keeps the cap's most opaque Gaussians at t
    (temporal opacity included) and evaluates them as the whole frame at t does."""
    cap = 40
    monkeypatch.setattr(inputs, "THUMBNAIL_GAUSSIANS", cap)
    scene = generate_scene(SceneSpec(background=300, objects=2, per_object=60))
    t = 0.4
    whole = scene.at(t)
    shown = evaluate_all(scene, t)[1]
    pieces = [scene.subset(part) for part in np.array_split(np.arange(len(scene)), 3)]
    kept = inputs._most_opaque_at(pieces, t)
    top = np.sort(np.argsort(-whole.opacities, kind="stable")[:cap])
    assert len(kept) == cap and shown.sum() > cap
    assert np.array_equal(kept.opacities, whole.opacities[top])  # pieces in order: same order
    assert np.array_equal(kept.means, whole.means[top])
    assert np.array_equal(kept.quats, whole.quats[top])


def test_a_container_is_drawn_a_chunk_at_a_time(tmp_path: Path) -> None:
    """A container's Source gives the Gaussians at t chunk by chunk (the thumbnail never holds
    a big scene whole); together they are the frame at t."""
    scene = generate_scene(SceneSpec(background=300, objects=2, per_object=60))
    out = tmp_path / "pieces.tsogs"
    segment_scene(scene, out, SegmentOptions(window_s=1.0, max_pixels=16 * 16, layers=1))
    with inputs.open_source(out) as source:
        t = sum(source.span or (0.0, 0.0)) / 2
        pieces = [scene.at(t) for scene in source.scenes_at(t)]
        whole = source.at(t)
    assert len(pieces) > 2
    assert np.array_equal(np.concatenate([p.means for p in pieces]), whole.means)
    assert np.array_equal(np.concatenate([p.opacities for p in pieces]), whole.opacities)


def _copy(root: Path, key: str, source: dict[str, Any], size: int, used: float) -> Path:
    """A cache folder as ``tsog view`` leaves one: a container of ``size`` bytes, its record
    last used at ``used``."""
    folder = root / key
    folder.mkdir(parents=True)
    (folder / "clip.tsogs").write_bytes(b"\0" * size)
    view_cache.record(folder, source)
    os.utime(folder / view_cache.SOURCE_FILE, (used, used))
    return folder


def test_a_new_copy_removes_earlier_versions_of_its_input_read_the_same_way(
    tmp_path: Path,
) -> None:
    """The copy of an input whose files changed can never be used again: making the new one
    removes it. Copies of other inputs, or of the same input read another way, stay."""
    same = {"input": "/data/clip", "options": [None, None, 6.0], "version": "1"}
    other_fps = {**same, "options": [None, None, 12.0]}
    old = _copy(tmp_path, "a" * 24, same, 10, 1000.0)
    kept = [
        _copy(tmp_path, "b" * 24, other_fps, 10, 1001.0),
        _copy(tmp_path, "c" * 24, {**same, "input": "/data/other"}, 10, 1002.0),
    ]
    made = _copy(tmp_path, "d" * 24, same, 10, 2000.0)
    assert view_cache.evict(tmp_path, made) == [old]
    assert not old.exists() and made.exists() and all(f.exists() for f in kept)


def test_the_least_recently_used_copies_go_when_the_cache_is_over_its_limit(
    tmp_path: Path,
) -> None:
    """Over the limit, copies go oldest use first until the rest fit; the one just made stays
    even when it alone is over; folders that are not copies are left alone."""
    copies = [
        _copy(tmp_path, f"{k:x}" * 24, {"input": f"/in/{k}"}, 100, 1000.0 + k) for k in range(1, 5)
    ]
    stranger = tmp_path / "notes"  # not a copy: another name, no record
    stranger.mkdir()
    (stranger / "x").write_bytes(b"\0" * 1000)
    no_record = tmp_path / ("e" * 24)  # a copy being made (no record yet)
    no_record.mkdir()
    (no_record / "clip.tsogs").write_bytes(b"\0" * 1000)
    made = _copy(tmp_path, "f" * 24, {"input": "/in/new"}, 100, 3000.0)
    limit = sum(f.stat().st_size for c in (made, *copies[2:]) for f in c.iterdir())
    removed = view_cache.evict(tmp_path, made, limit)
    assert removed == copies[:2]
    assert [c.exists() for c in copies] == [False, False, True, True]
    assert made.exists() and stranger.exists() and no_record.exists()
    assert view_cache.evict(tmp_path, made, 0) == copies[2:]
    assert made.exists()


def test_a_copy_being_served_is_never_removed(tmp_path: Path) -> None:
    """A running tsog view holds its copy (a shared lock on its record): neither a newer
    version nor the size limit removes it; once the server stops, it can go."""
    source = {"input": "/data/clip", "options": []}
    served = _copy(tmp_path, "a" * 24, source, 10, 1000.0)
    made = _copy(tmp_path, "b" * 24, source, 10, 2000.0)
    with view_cache.serving(served):
        assert view_cache.evict(tmp_path, made, 0) == []
        assert (served / view_cache.SOURCE_FILE).is_file()
    assert view_cache.evict(tmp_path, made, 0) == [served]


# --- tsog view for people: a few lines by default, the cache's hostile shapes (issue 55) ---

SPLATV = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
WAITING = "waiting for another tsog view making the same copy"


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 200-Gaussian FreeTimeGS checkpoint: segmented in about a second."""
    path = tmp_path_factory.mktemp("tiny") / "tiny.npz"
    path.write_bytes(freetime_npz(freetime_truth(200)))
    return path


def _view_args(clip: Path, cache: Path, *more: str) -> argparse.Namespace:
    return build_parser().parse_args(["view", str(clip), "--cache", str(cache), "-q", *more])


def test_view_says_what_it_made_in_two_lines_the_assumed_length_first(
    samples: Path, tmp_path: Path
) -> None:
    """By default: what was made, where, how big, then the URL; a .splatv read without
    --duration-s is warned about first on stderr, when it is segmented and when reused."""
    clip, cache = samples / SPLATV, tmp_path / "cache"
    for run in ("made", "reused"):
        errors: list[str] = []
        with tsog_view(str(clip), cache=cache, errors=errors) as (url, before):
            (made,) = cache.glob("*/*.tsogs")
            if run == "made":
                assert before[0] == f"segmented {clip} into {made} (-v: its layout)\n"
            else:
                reused = f"{made}: reusing the copy segmented earlier (the input is unchanged)"
                assert before[0] == reused + "\n"
            assert len(before) == 2, before
            assert before[1].startswith("  24,000 Gaussians, 1.00 s (assumed")
            assert (
                before[1].rstrip().endswith(" kB (the input: 1.57 MB)" if run == "made" else " kB")
            )
            assert get(url)[0] == 200
        assert errors[0].startswith("tsog: warning: ") and "--duration-s" in errors[0], errors


def test_view_v_prints_the_segment_report(tiny_clip: Path, tmp_path: Path) -> None:
    with tsog_view(str(tiny_clip), "-v", cache=tmp_path / "cache") as (_, before):
        (made,) = (tmp_path / "cache").glob("*/tiny.tsogs")
        assert before[0].startswith(f"{made}: ") and "bytes" in before[0]
        assert any(line.startswith("  layout (") for line in before), before
        assert any(line.startswith("  bytes per window (level 0): ") for line in before)
        assert not any(line.startswith("segmented ") for line in before)


def _snapshot(root: Path) -> dict[str, object]:
    """Every path below ``root`` (links not followed) with its bytes or its link's target."""
    found: dict[str, object] = {}
    for path in sorted(root.rglob("*")):
        name = str(path.relative_to(root))
        if path.is_symlink():
            found[name] = ("link", os.readlink(path))
        elif path.is_file():
            found[name] = path.read_bytes()
        else:
            found[name] = "folder"
    return found


def _corrupt_index(container: Path) -> None:
    """Flip a byte inside the container's index (its manifest): it fails its hash."""
    data = bytearray(container.read_bytes())
    header = Header.unpack(bytes(data[: Header.STRUCT.size]))
    data[header.index_offset + header.index_length // 2] ^= 0xFF
    container.write_bytes(bytes(data))


def _relink(path: Path, target: Path) -> None:
    path.unlink()
    path.symlink_to(target)


ENTRIES = (
    "a link to a complete copy elsewhere",
    "a dangling link",
    "a link to itself",
    "a regular file",
    "a FIFO",
    "a stopped run's leftovers (no record)",
    "a container cut short",
    "a corrupt manifest",
    "a container linked from elsewhere",
    "a record linked from elsewhere",
    "links to outside among leftovers",
)
"""What can be found in a copy's place in the cache besides a copy made there."""


def _make_entry(shape: str, entry: Path, outside: Path, copy: Path) -> None:
    """Put ``shape`` in the copy's place ``entry``; ``copy`` is a complete copy ``outside``
    the cache."""
    links = {
        "a link to a complete copy elsewhere": copy,
        "a dangling link": outside / "nothing",
        "a link to itself": entry,
    }
    if shape in links:
        entry.symlink_to(links[shape])
    elif shape == "a regular file":
        entry.write_bytes(b"not a folder")
    elif shape == "a FIFO":
        os.mkfifo(entry)
    elif shape == "links to outside among leftovers":
        (entry / "sub").mkdir(parents=True)
        (entry / "sub" / "out").symlink_to(outside)
        (entry / "out").symlink_to(outside)
        (entry / "copy").symlink_to(copy)
    else:
        shutil.copytree(copy, entry)
        container, record = entry / "tiny.tsogs", entry / view_cache.SOURCE_FILE
        if shape == "a stopped run's leftovers (no record)":
            record.unlink()
            (entry / "tiny.tsogs.tmp-1234").write_bytes(b"\0" * 100)
        elif shape == "a container cut short":
            container.write_bytes(container.read_bytes()[:100])
        elif shape == "a corrupt manifest":
            _corrupt_index(container)
        elif shape == "a container linked from elsewhere":
            _relink(container, copy / container.name)
        else:
            _relink(record, copy / record.name)


@pytest.fixture(scope="module")
def complete_copy(tiny_clip: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy tsog view made of the tiny clip (its folder)."""
    cache = tmp_path_factory.mktemp("made")
    return view_command._segmented(_view_args(tiny_clip, cache), Progress(quiet=True)).parent


@pytest.mark.parametrize("shape", ENTRIES)
def test_a_copys_place_holding_anything_else_is_made_again_inside_the_cache(
    shape: str, tiny_clip: Path, complete_copy: Path, tmp_path: Path
) -> None:
    """Whatever is in a copy's place that is not a complete copy made there is removed (a
    link itself, never what it points to) and the copy made again: served, every URL 200;
    nothing outside the cache changes."""
    outside, cache = tmp_path / "outside", tmp_path / "cache"
    shutil.copytree(complete_copy, outside / "copy")
    (outside / "keep.txt").write_text("not the cache's")
    cache.mkdir()
    args = _view_args(tiny_clip, cache)
    entry = cache / view_command.fingerprint(args)
    _make_entry(shape, entry, outside, outside / "copy")
    before = _snapshot(outside)
    container = view_command._segmented(args, Progress(quiet=True))
    assert container == entry / "tiny.tsogs"
    assert view_cache.entry_kind(entry) == "folder"
    assert view_cache.entry_kind(container) == "file" and view_cache.has_record(entry)
    assert sorted(p.name for p in entry.iterdir()) == sorted(
        p.name for p in complete_copy.iterdir()
    )
    assert _snapshot(outside) == before
    server = ThreadedServer(make_app(entry))
    try:
        base = f"http://127.0.0.1:{server.port}"
        manifest = json.loads(get(f"{base}/v1/scenes/tiny/manifest")[1])
        assert manifest["scene"]["gaussians"] == 200
        chunk = manifest["chunks"][0]
        status, body, _ = get(f"{base}/v1/scenes/tiny/chunks/{chunk['id']}.sog")
        assert status == 200 and len(body) == chunk["length"]
    finally:
        server.stop()
    # made, it is reused as it is
    assert view_command._segmented(args, Progress(quiet=True)) == container


@pytest.mark.parametrize(
    ("shape", "why"),
    [
        ("{tmp}/file/cache", "a part of this path is a file, not a folder"),
        ("{tmp}/file", "it is not a folder"),
        ("{tmp}/dangling", "it is not a folder"),
        ("/proc/self/tsog-view-cache", "no folder can be made here"),
        ("/proc", "no folder can be made here"),
    ],
)
def test_a_cache_that_cannot_be_used_is_one_line_naming_it(
    shape: str, why: str, tiny_clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("a file")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    cache = shape.replace("{tmp}", str(tmp_path))
    assert main(["view", str(tiny_clip), "--cache", cache, "-q"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"tsog: error: {cache}: cannot keep segmented copies here: {why} "
        "(--cache DIR chooses another folder)"
    ]
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("first", ["makes the copy", "fails and leaves nothing"])
def test_a_second_run_of_the_same_input_waits_for_the_first(tmp_path: Path, first: str) -> None:
    """The folder is held while a copy is made: a second claim waits, then finds the copy,
    or, when the first run removed its folder, a new empty one of its own."""
    key, said, seen = "a" * 24, list[str](), list[list[str]]()

    def second() -> None:
        with view_cache.claimed(tmp_path, key, said.append) as folder:
            seen.append(sorted(os.listdir(folder)))

    with view_cache.claimed(tmp_path, key, said.append) as folder:
        waiter = threading.Thread(target=second)
        waiter.start()
        deadline = time.monotonic() + 10
        while not said and time.monotonic() < deadline:
            time.sleep(0.01)
        assert said == [WAITING] and seen == []
        if first == "makes the copy":
            (folder / "clip.tsogs").write_bytes(b"made")
        else:
            folder.rmdir()
    waiter.join(10)
    assert seen == [["clip.tsogs"] if first == "makes the copy" else []]
    assert view_cache.entry_kind(tmp_path / key) == "folder"


def test_a_copy_that_cannot_be_written_is_one_line_and_leaves_nothing(
    tiny_clip: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A write into the cache failing after the segment (the disk full) ends in one line
    naming the cache, and the half-made copy is removed."""

    def full(folder: Path, source: dict[str, Any]) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(view_command, "record", full)
    cache = tmp_path / "cache"
    assert main(["view", str(tiny_clip), "--cache", str(cache), "-q"]) == 1
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"tsog: error: {cache}: cannot keep segmented copies here: no space left on device "
        "(--cache DIR chooses another folder)"
    )
    assert list(cache.iterdir()) == []
