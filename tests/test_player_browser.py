"""The web player in headless Chromium: GPU time evaluation, scrubbing, playing, origins.

The page is served by a real ``tsog serve`` app on loopback (and, for the static-origin case,
by nginx); the browser is Debian's chromium on SwiftShader. Frames are compared as screenshots
of the 640x480 page with the controls hidden.
"""

from __future__ import annotations

import base64
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pytest

from browser import VIEWPORT, PlayerPage, chromium, image_difference, near, page_opener, served
from helpers import nginx_origin
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Scene, TimelineType, evaluate_all
from tsog_stream.schemas.manifest import ChunkEntry
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.server import Privacy, make_app
from tsog_stream.signing import sign_url
from tsog_stream.synthetic import SceneSpec, generate_scene

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SECRET = b"browser-test-secret-0123456789abcdef"
VIEW = "yaw=20&pitch=-20&distance=9"


def all_dynamic(kind: TimelineType, seed: int) -> SceneSpec:
    """Four moving objects over a background, every attribute with temporal coefficients."""
    dynamic = ("means", "scales", "quats", "sh0", "opacity")
    return SceneSpec(kind, background=2000, objects=4, per_object=400, dynamic=dynamic, seed=seed)


SCENES: dict[str, SceneSpec] = {
    "centre": all_dynamic(TimelineType.CENTER_SCALE, seed=3),
    "spans": all_dynamic(TimelineType.START_DURATION, seed=4),
    "frames": SceneSpec(TimelineType.FRAME, background=600, objects=3, per_object=150, seed=5),
    "sh": replace(all_dynamic(TimelineType.CENTER_SCALE, seed=3), sh_bands=3),
}
SH_GAIN = 6.0
LAYERED = {"sh": 3}
"""Scenes stored with quality layers: the base without its SH bands, which come in their own
chunks (the page rebuilds the base's SOG with them)."""
# The GPU-evaluated frame against the engine's render of the static SOG that `tsog frame`
# exports: the two differ only by the export's own re-quantisation (new codebooks, 8-bit alpha).
# Measured on these scenes: mean 0.01-0.09 levels, at most 0.013 % of pixels off by > 16; the
# export 0.4 s later: mean 1.8-2.9 levels, 1.9-5.7 % of pixels off.
MAX_MEAN_DIFFERENCE = 0.25  # colour levels (0-255), averaged over the frame
MAX_FRACTION_OFF = 0.001  # of pixels more than OFF_LEVELS apart in some channel
OFF_LEVELS = 16


def off_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels more than OFF_LEVELS apart."""
    return float((image_difference(a, b) > OFF_LEVELS).mean())


def mean_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference over pixels and channels."""
    return float(np.abs(a - b).mean())


@pytest.fixture(scope="module")
def scenes() -> dict[str, Scene]:
    out = {name: generate_scene(spec) for name, spec in SCENES.items()}
    g = out["sh"].gaussians  # view-dependent colour strong enough to see: a DC-only base fails
    out["sh"] = replace(out["sh"], gaussians=replace(g, shN=SH_GAIN * g.shN))
    return out


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory, scenes: dict[str, Scene]) -> Path:
    """Each scene segmented (1 s windows), one also unpacked, one private copy."""
    root = tmp_path_factory.mktemp("browser")
    for name, scene in scenes.items():
        options = SegmentOptions(window_s=1.0, policy="hybrid", layers=LAYERED.get(name))
        segment_scene(scene, root / f"{name}.tsogs", options)
    (root / "static").mkdir()
    with open_stream(root / "centre.tsogs") as reader:
        reader.unpack(root / "static" / "centre")
    (root / "paid").mkdir()
    (root / "paid" / "show.tsogs").write_bytes((root / "centre.tsogs").read_bytes())
    frames = root / "frames-folder"
    frames.mkdir()
    for k in range(3):  # three unrelated frames: a flipbook, stored a window per frame
        still = generate_scene(replace(SCENES["centre"], seed=20 + k)).at(1.0)
        (frames / f"frame_{k:03d}.sog").write_bytes(bundle_bytes(encode_chunk(Scene(still))))
    segment_sequence(open_sequence(frames, fps=FLIPBOOK_FPS), root / "flipbook.tsogs")
    return root


FLIPBOOK_FPS = 2.0  # 3 frames over 1.5 s: the negative control 0.4 s later is the next frame
FRAME_TIMES = [("centre", 1.3), ("spans", 2.45), ("frames", 1.75), ("flipbook", 0.3), ("sh", 1.3)]
OTHER_TIME = 0.4  # the negative control: the export this much later
SCRUB = (0.5, 2.5)  # the second needs one more chunk (2.0-2.94 s), not the one before it
ORIGIN_T = 2.2
GRID = [round(0.013 + 0.05 * i, 3) for i in range(80)]  # never on a chunk or window edge


@dataclass(frozen=True)
class Facts:
    """What the Python library says, computed before the browser starts (playwright's sync
    API keeps an event loop running, which the library's sync facades cannot run inside)."""

    exports: dict[tuple[str, float], str]
    needed: dict[float, set[int]]
    grid: dict[float, set[int]]  # chunks_for(t) on a grid of times between chunk edges
    files: dict[float, list[str]]
    chunks: list[ChunkEntry]


@pytest.fixture(scope="module")
def facts(root: Path) -> Facts:
    exports = {}
    for scene, t in FRAME_TIMES:
        for when in (t, round(t + OTHER_TIME, 2)):
            name = f"{scene}-{when}.sog"
            args = ["frame", str(root / f"{scene}.tsogs"), "--t", str(when), "-o", str(root / name)]
            assert main([*args, "-q"]) == 0
            exports[scene, when] = f"/files/{name}"
    with open_stream(root / "centre.tsogs") as reader:
        times = (*SCRUB, ORIGIN_T)
        needed = {t: {c.id for c in reader.index.chunks_for(t)} for t in times}
        grid = {t: {c.id for c in reader.index.chunks_for(t)} for t in GRID}
        files = {t: sorted(c.file for c in reader.index.chunks_for(t)) for t in times}
        chunks = list(reader.index.manifest.chunks)
    return Facts(exports, needed, grid, files, chunks)


@pytest.fixture(scope="module")
def base(root: Path) -> Iterator[str]:
    with served(make_app(root, privacy=Privacy(("paid",), SECRET))) as url:
        yield url


@pytest.fixture(scope="module")
def browser(facts: Facts) -> Iterator[Any]:
    with chromium() as b:
        yield b


@pytest.fixture
def open_page(browser: Any) -> Iterator[Any]:
    with page_opener(browser) as open_:
        yield open_


@pytest.mark.parametrize(("scene", "t"), FRAME_TIMES)
def test_frame_at_t_matches_the_engine_render_of_tsog_frame(
    facts: Facts, base: str, open_page: Any, scene: str, t: float
) -> None:
    page = open_page(f"{base}/play/{scene}?t={t}&paused&{VIEW}")
    page.wait_all_layers()
    gpu = page.frame()
    static = page.show_static(facts.exports[scene, t])
    assert (static.sum(axis=2) > 60).mean() > 0.02, "the reference frame is nearly empty"
    assert mean_difference(gpu, static) <= MAX_MEAN_DIFFERENCE
    assert off_fraction(gpu, static) <= MAX_FRACTION_OFF
    # The tolerance has teeth: the export at another time is far outside it.
    other = page.show_static(facts.exports[scene, round(t + OTHER_TIME, 2)])
    assert off_fraction(gpu, other) > 10 * MAX_FRACTION_OFF
    assert mean_difference(gpu, other) > 4 * MAX_MEAN_DIFFERENCE


READY_LAYOUTS = (
    "[...window.tsogPlayer.stream.chunks.values()].filter((c) => c.state === 'ready')"
    ".map((c) => Boolean(c.layout || c.textures))"
)
"""Page expression: per loaded chunk, whether its time is evaluated (timeline textures)."""


def test_a_flipbook_frame_is_drawn_as_its_plain_sog(base: str, open_page: Any) -> None:
    """A frame of a sequence stored a window per frame is enabled only within its frame, so
    the page draws it without evaluating time (no timeline textures, no modifier); the
    picture is checked against the export in the test above."""
    page = open_page(f"{base}/play/flipbook?t=0.3&paused&{VIEW}")
    plain = page.js(READY_LAYOUTS)
    assert plain and not any(plain)
    timed = open_page(f"{base}/play/frames?t=1.75&paused&{VIEW}")  # several frames a window
    evaluated = timed.js(READY_LAYOUTS)
    assert evaluated and all(evaluated)


def test_two_times_differ_where_objects_moved_and_match_where_static(
    scenes: dict[str, Scene], base: str, open_page: Any
) -> None:
    t1, t2 = 1.3, 1.6
    page = open_page(f"{base}/play/centre?t={t1}&paused&{VIEW}")
    first = page.frame()
    page.seek(t2)
    second = page.frame()
    scene = scenes["centre"]
    (a, seen_a), (b, seen_b) = evaluate_all(scene, t1), evaluate_all(scene, t2)
    same = seen_a == seen_b
    for name in ("means", "scales", "quats", "sh0", "opacities"):
        values_a, values_b = getattr(a, name), getattr(b, name)
        same &= np.all(np.isclose(values_a, values_b).reshape(len(scene), -1), axis=1)
    changed = (seen_a | seen_b) & ~same
    assert changed.sum() > 100, "the scene must have moving objects at these times"
    points = np.concatenate([a.means[changed & seen_a], b.means[changed & seen_b]])
    moved = near(page.project(points.astype(np.float64)), first.shape[:2], radius=14)
    diff = image_difference(first, second)
    assert (diff[moved] > 32).sum() > 200, "objects moved, so the frames must differ there"
    assert np.all(diff[~moved] == 0), "the static background must render identically"


COUNT_RENDERS = """() => { const app = window.tsogPlayer.app, render = app.render.bind(app);
    window.__renders = 0; app.render = () => { window.__renders++; render(); }; }"""


def _renders_within(page: PlayerPage, seconds: float) -> int:
    """Pictures the page drew in the next ``seconds`` (from a count set to 0 now)."""
    page.js("window.__renders = 0")
    time.sleep(seconds)
    return int(page.js("window.__renders"))


def test_a_still_picture_is_not_redrawn_and_a_change_is(base: str, open_page: Any) -> None:
    """Paused and settled, the page draws nothing (the CPU is left to decoding); moving the
    camera or the time draws again, and playing draws every frame."""
    page = open_page(f"{base}/play/centre?t=1.3&paused&{VIEW}")
    page.frame()
    page.js(COUNT_RENDERS)
    assert _renders_within(page, 1.0) == 0
    page.js("window.tsogPlayer.controls.orbit(40, 0)")
    assert _renders_within(page, 0.5) > 0
    assert _renders_within(page, 1.5) < 3  # settled again (a sort may land just after)
    page.seek(1.6)
    page.js("window.__renders = 0")
    page.js("window.tsogPlayer.playback.playing = true")
    playing = _renders_within(page, 1.0)
    frames = page.js("window.tsogPlayer.app.frame")
    assert playing >= 5, (playing, frames)


def test_scrubbing_fetches_only_the_chunks_for_t(facts: Facts, base: str, open_page: Any) -> None:
    first, then = SCRUB
    needed = facts.needed
    assert needed[then] - needed[first] and len(needed[first] | needed[then]) < len(facts.chunks)
    page = open_page(f"{base}/play/centre?t={first}&paused")

    def chunk_ids(urls: list[str]) -> list[int]:
        prefix = f"{base}/v1/scenes/centre/chunks/"
        return [int(u[len(prefix) :].split(".")[0]) for u in urls if u.startswith(prefix)]

    assert sorted(chunk_ids(page.requests)) == sorted(needed[first])
    check_buffered(page, facts)
    before = len(page.requests)
    page.seek(then)
    fetched = chunk_ids(page.requests[before:])
    assert sorted(fetched) == sorted(needed[then] - needed[first])
    assert sorted(page.js("window.tsogPlayer.stream.stats().shown")) == sorted(needed[then])
    check_buffered(page, facts)
    total = sum(facts.chunks[i].length for i in needed[first] | needed[then])
    page.page.wait_for_function(
        f"document.getElementById('o-bytes').textContent === {f'{total:,}'!r}", timeout=5000
    )
    assert page.page.text_content("#o-chunks") == str(len(needed[then]))


def check_buffered(page: PlayerPage, facts: Facts) -> None:
    """The scrub bar's buffered ranges hold exactly the times whose chunks are all loaded."""
    ranges = page.js("window.tsogPlayer.stream.buffered()")
    ready = set(page.js("window.tsogPlayer.stream.stats().loaded"))
    for t, chunks in facts.grid.items():
        inside = any(a <= t <= b for a, b in ranges)
        assert inside == (chunks <= ready), f"t={t}: buffered {ranges}, loaded {ready}"


def test_playing_prefetches_ahead_and_drops_behind(facts: Facts, base: str, open_page: Any) -> None:
    """With nothing kept beyond what t and the horizon want (keepGaussians 0), chunks behind the
    playhead go; test_a_loop_is_played_from_chunks_kept_loaded covers the default. Played at
    1x: at 2x a loaded machine (CI beside other work) decoded the horizon's chunks only once
    the playhead had reached them."""
    page = open_page(f"{base}/play/centre?t=0&paused")
    page.js("tsogPlayer.stream.keepGaussians = 0; document.getElementById('play').click()")
    ahead_seen, held_behind = False, []
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        state = page.js("({t: tsogPlayer.playback.t, ready: tsogPlayer.stream.stats().loaded})")
        ready = [facts.chunks[i] for i in state["ready"]]
        ahead_seen |= any(c.start_s > state["t"] + 0.05 for c in ready)
        held_behind += [c.id for c in ready if c.end_s < state["t"] - 0.5 and state["t"] < 3.5]
        if state["t"] >= 3.5:
            break
        time.sleep(0.1)
    else:
        pytest.fail("playback did not reach t = 3.5 s within 20 s")
    assert ahead_seen, "chunks after the playhead must be fetched before they are needed"
    assert held_behind == [], "chunks behind the playhead must be dropped"
    assert page.page.text_content("#o-state") in ("playing", "buffering")
    # Loop (on by default): past the end, playback starts again from the beginning.
    page.page.wait_for_function("tsogPlayer.playback.t < 1", timeout=10_000)
    # Loop off: playback stops at the end.
    page.js("document.getElementById('loop').click()")
    page.page.wait_for_function(
        "!tsogPlayer.playback.playing && tsogPlayer.playback.t === tsogPlayer.playback.end",
        timeout=15_000,
    )
    page.page.wait_for_function(
        "document.getElementById('o-state').textContent === 'paused'", timeout=5000
    )


def test_a_loop_is_played_from_chunks_kept_loaded(base: str, open_page: Any) -> None:
    """Within the default budget, chunks t no longer needs stay loaded: the second pass through
    a looping clip fetches nothing again."""
    page = open_page(f"{base}/play/centre?t=0&paused")
    page.js(
        "document.getElementById('speed').value = '2';"
        "document.getElementById('speed').dispatchEvent(new Event('change'));"
        "document.getElementById('play').click();"
        "window.__passes = 0; window.__last = 0;"
        "(function watch() {"
        "  const t = tsogPlayer.playback.t;"
        "  if (t < window.__last) window.__passes++;"
        "  window.__last = t; requestAnimationFrame(watch);"
        "})()"
    )
    page.page.wait_for_function("window.__passes >= 1", timeout=30_000)
    first = page.js("tsogPlayer.stream.fetchLog.length")
    page.page.wait_for_function("window.__passes >= 2", timeout=30_000)
    log = page.js("tsogPlayer.stream.fetchLog")
    assert len(log) == first and len(set(log)) == len(log), "a loop fetched chunks again"


def test_a_static_origin_plays_from_a_manifest_url(
    facts: Facts, root: Path, base: str, open_page: Any, tmp_path: Path
) -> None:
    t = ORIGIN_T
    served = open_page(f"{base}/play/centre?t={t}&paused&{VIEW}").frame()
    cors = "add_header Access-Control-Allow-Origin * always;"
    with nginx_origin(root / "static", tmp_path / "nginx", server_extra=cors) as origin:
        manifest = f"{origin}centre/manifest.json"
        page = open_page(f"{base}/play/?manifest={quote(manifest, safe='')}&t={t}&paused&{VIEW}")
        frame = page.frame()
        log = (tmp_path / "nginx" / "logs" / "access.log").read_text().splitlines()
    assert np.array_equal(frame, served)
    got = sorted(line.split('"')[1].split()[1].lstrip("/").removeprefix("centre/") for line in log)
    assert got == sorted(["manifest.json", *facts.files[t]])
    assert all('" 200 ' in line for line in log)


def test_a_private_scene_plays_from_its_signed_page_url(base: str, open_page: Any) -> None:
    url = sign_url(f"{base}/play/paid/show", SECRET, int(time.time()) + 600)
    page = open_page(f"{url}&t=1.3&paused")
    assert page.frame().sum(axis=2).max() > 100
    api = [u for u in page.requests if "/v1/" in u]
    assert api and all("signature=" in u for u in api)
    assert page.js("window.tsogPlayer.stream.stats().failed") == 0


def test_a_missing_manifest_is_a_clear_error_on_the_page(base: str, browser: Any) -> None:
    page = browser.new_page(viewport=VIEWPORT)
    try:
        missing = quote(f"{base}/files/nothing/manifest.json", safe="")
        page.goto(f"{base}/play/?manifest={missing}")
        page.wait_for_function("window.tsogPlayer?.error", timeout=10_000)
        assert page.is_visible("#error")
        message = page.text_content("#error")
        assert (
            message is not None
            and "scene not found" in message
            and "HTTP 404" in message
            and "/nothing/" in message
        )
    finally:
        page.close()


READ_ZIP = """async ([data]) => {
    const { readZip } = await import('/player/zip.js');
    const bytes = Uint8Array.from(atob(data), (c) => c.charCodeAt(0));
    try {
        const files = await readZip(bytes.buffer);
        return { files: Object.fromEntries([...files].map(([k, v]) => [k, [...v]])) };
    } catch (err) {
        return { error: err.message };
    }
}"""


def _with_meta_size(zipped: bytes, size: int) -> bytes:
    """``zipped`` with the uncompressed size of meta.json (its last central record) replaced."""
    at = zipped.rindex(b"PK\x01\x02") + 24
    return zipped[:at] + size.to_bytes(4, "little") + zipped[at + 4 :]


def test_the_page_inflates_meta_json_within_its_declared_size(base: str, browser: Any) -> None:
    """Spec 0.4's deflated meta.json is read exactly; a size that deflate cannot reach is
    refused before anything is allocated, and one smaller than the data stops inflating at
    that size: hostile chunks cannot make the page hold more than the record says."""
    meta = b'{"codebook": [' + b"0.125, " * 2000 + b"1]}"
    zipped = bundle_bytes({"means_l.webp": b"RIFF....", "meta.json": meta})
    page = browser.new_page(viewport=VIEWPORT)
    try:
        page.goto(f"{base}/play/")

        def read(data: bytes) -> dict[str, Any]:
            return page.evaluate(READ_ZIP, [base64.b64encode(data).decode()])  # type: ignore[no-any-return]

        got = read(zipped)
        assert bytes(got["files"]["meta.json"]) == meta
        assert bytes(got["files"]["means_l.webp"]) == b"RIFF...."
        assert "declares 4000000000 bytes" in read(_with_meta_size(zipped, 4_000_000_000))["error"]
        assert "inflates to more than 100 bytes" in read(_with_meta_size(zipped, 100))["error"]
        short = read(_with_meta_size(zipped, len(meta) + 5))["error"]
        assert f"inflates to {len(meta)} bytes, not {len(meta) + 5}" in short
    finally:
        page.close()
