"""The web player while a scene plays (issue 55): a flipbook of one chunk per frame keeps its
last picture while the next is on its way and plays at 1x once started; the controls bar fades
while playing untouched and comes back on any activity; a static scene shows no time controls;
an assumed duration is marked. Headless Chromium, the real server on loopback, and Playwright
routing for hand-made manifests (a static origin the test controls)."""

from __future__ import annotations

import base64
import io
import json
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np
import pytest
from PIL import Image

from browser import HIDE_UI, VIEWPORT, chromium, served
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.io.sequence import open_sequence
from tsog_stream.segment import SegmentOptions, segment_sequence
from tsog_stream.server import make_app

pytestmark = [pytest.mark.browser, pytest.mark.slow]

DATA = Path(__file__).parent / "data" / "real"
MONKEY = DATA / "4d" / "pc_flipbook_monkey"
STATIC_PLY = DATA / "3dgs" / "v3dg_donut_fused.ply"
FPS = 30.0
FRAMES = 30
"""The three in-repo monkey frames in turn, 1 s at 30 fps: a SOG flipbook of one chunk per
frame (the segmenter's defaults store it a window per frame, in quality layers)."""
BACKGROUND = np.array([18, 18, 18])  # the page's clear colour (0.07 grey)
PLAY_S = 5.0
SHOT_EVERY_S = 0.1
MIN_DRAWN = 0.01
"""Share of the page's pixels away from the background in a picture with the monkey in it
(it covers 8-60 % of the opening view); an empty canvas has none."""
MIN_RATE = 0.85
START_TIMEOUT_MS = 60_000
IDLE_S = 3.0  # idle.js IDLE_MS
TIME_CONTROLS = ("#play", "#back", "#forward", "#scrub", "#time", "#duration", "#speed", "#loop")

WATCH_PLAYHEAD = """(() => {
    const w = window.__pb = { played: 0, buffering: 0, frames: 0, last: null, elapsed: 0 };
    w.begun = performance.now();
    (function tick() {
        const p = window.tsogPlayer.playback;
        w.frames++;
        if (p.buffering) w.buffering++;
        const step = p.t - w.last;
        if (w.last !== null) w.played += step >= 0 ? step : step + (p.end - p.start);
        w.last = p.t;
        w.elapsed = (performance.now() - w.begun) / 1000;
        requestAnimationFrame(tick);
    })();
})()"""
"""Page expression: media seconds played (loops counted) against the page's own wall clock."""
STARTED = "window.tsogPlayer?.stream?.adapt.startedAt != null && !tsogPlayer.playback.buffering"
"""True once the player object exists, began to play and is not buffering (false, not an
exception, while the page is still building the player)."""
BAR = """() => { const s = getComputedStyle(document.getElementById('controls'));
    return [s.opacity, s.visibility]; }"""


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """flipbook.tsogs (the monkey frames in turn), still.tsogs (a static PLY, if the segmenter
    takes one), and the flipbook unpacked for hand-made manifests."""
    root = tmp_path_factory.mktemp("playback")
    frames = root / "frames"
    frames.mkdir()
    sources = sorted(MONKEY.glob("*.sog"))
    for k in range(FRAMES):
        shutil.copyfile(sources[k % len(sources)], frames / f"monkey_{k + 1:04d}.sog")
    sequence = open_sequence(frames, fps=FPS, kind="sog")
    segment_sequence(sequence, root / "flipbook.tsogs", SegmentOptions(workers=1))
    with open_stream(root / "flipbook.tsogs") as reader:
        reader.unpack(root / "unpacked")
    out = str(root / "still.tsogs")
    assert main(["segment", str(STATIC_PLY), "-o", out, "-q"]) == 0
    return root


@pytest.fixture(scope="module")
def base(root: Path) -> Iterator[str]:
    with served(make_app(root)) as url:
        yield url


@pytest.fixture(scope="module")
def browser(root: Path) -> Iterator[Any]:
    with chromium() as b:
        yield b


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    page = browser.new_page(viewport=VIEWPORT)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    yield page
    page.close()
    assert errors == []


def drawn_share(png: bytes) -> float:
    """Share of pixels away from the page's background."""
    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)
    return float((np.abs(image - BACKGROUND).max(axis=2) > 24).mean())


class Screencast:
    """Every picture the browser composites (CDP screencast), with its arrival time: the
    picture on screen at any moment is the last one that arrived before it."""

    def __init__(self, page: Any) -> None:
        self.frames: list[tuple[float, str]] = []
        self.cdp = page.context.new_cdp_session(page)
        self.cdp.on("Page.screencastFrame", self._frame)
        self.cdp.send("Page.startScreencast", {"format": "png", "maxWidth": 320})

    def _frame(self, event: dict[str, Any]) -> None:
        self.frames.append((time.monotonic(), event["data"]))
        self.cdp.send("Page.screencastFrameAck", {"sessionId": event["sessionId"]})

    def stop(self) -> None:
        self.cdp.send("Page.stopScreencast")

    def shown_at(self, when: float) -> bytes | None:
        """The picture on screen at ``when`` (time.monotonic), None before the first."""
        before = [data for at, data in self.frames if at <= when]
        return base64.b64decode(before[-1]) if before else None


def test_a_flipbook_keeps_its_last_picture_and_plays_at_1x(base: str, page: Any) -> None:
    """The picture on screen every 100 ms over 5 s of play has the monkey in it (never the
    empty canvas of a frame whose chunk is still on its way), and the playhead moves at 1x:
    once started, playback waits for a stretch it can play through, not chunk by chunk."""
    cast = Screencast(page)
    page.goto(f"{base}/play/flipbook?t=0")
    page.wait_for_function("window.tsogPlayer?.playback !== undefined", timeout=START_TIMEOUT_MS)
    page.add_style_tag(content=HIDE_UI)
    page.wait_for_function(STARTED, timeout=START_TIMEOUT_MS, polling=50)
    began = time.monotonic()
    page.evaluate(WATCH_PLAYHEAD)
    page.wait_for_timeout(PLAY_S * 1000)
    watched = page.evaluate("window.__pb")
    cast.stop()
    ticks = [began + SHOT_EVERY_S * k for k in range(int(PLAY_S / SHOT_EVERY_S))]
    shots = [cast.shown_at(tick) for tick in ticks]
    assert len(cast.frames) > 10, "the screencast saw the page play"
    empty = [i for i, shot in enumerate(shots) if shot is None or drawn_share(shot) < MIN_DRAWN]
    assert empty == [], (
        f"pictures without splats at {[round(i * SHOT_EVERY_S, 1) for i in empty]} s"
    )
    rate = watched["played"] / watched["elapsed"]
    assert rate >= MIN_RATE, (rate, watched)
    assert watched["buffering"] == 0, watched
    assert page.evaluate("tsogPlayer.stream.stats().failed") == 0


def test_the_bar_fades_while_playing_untouched_and_comes_back(base: str, page: Any) -> None:
    page.goto(f"{base}/play/flipbook?t=0")
    page.wait_for_function(STARTED, timeout=START_TIMEOUT_MS, polling=50)
    moved = time.monotonic()
    page.mouse.move(320, 200)  # it may have faded already on a slow start: the move shows it
    page.wait_for_function(f"({BAR})().join() === '1,visible'", timeout=5000)
    page.wait_for_function(f"({BAR})().join() === '0,hidden'", timeout=15_000)
    assert time.monotonic() - moved >= IDLE_S - 0.2, "faded before the idle time"
    assert page.evaluate("tsogPlayer.playback.playing")
    assert page.evaluate("document.body.classList.contains('idle')")
    page.mouse.move(330, 210)  # a pointer move brings it back
    page.wait_for_function(f"({BAR})().join() === '1,visible'", timeout=5000)
    page.wait_for_function(f"({BAR})().join() === '0,hidden'", timeout=15_000)
    page.keyboard.press("Shift")  # so does a key
    page.wait_for_function(f"({BAR})().join() === '1,visible'", timeout=5000)
    page.keyboard.press("Space")  # paused: it stays
    assert not page.evaluate("tsogPlayer.playback.playing")
    page.wait_for_timeout((IDLE_S + 1.0) * 1000)
    assert page.evaluate(BAR) == ["1", "visible"]


def routed_origin(page: Any, unpacked: Path, manifest: dict[str, Any]) -> str:
    """Serve ``manifest`` and the unpacked chunks at /hand/ through Playwright routing; the
    page URL playing it (relative to the server)."""

    def handle(route: Any) -> None:
        path = urlsplit(route.request.url).path.removeprefix("/hand/")
        if path == "manifest.json":
            route.fulfill(status=200, content_type="application/json", body=json.dumps(manifest))
        else:
            route.fulfill(status=200, body=(unpacked / path).read_bytes())

    page.route(lambda url: urlsplit(url).path.startswith("/hand/"), handle)
    return "/play/?manifest=/hand/manifest.json"


def unpacked_manifest(root: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((root / "unpacked" / "manifest.json").read_text())
    return data


@pytest.mark.parametrize("how", ["static PLY", "end_s is start_s"])
def test_a_static_scene_shows_no_time_controls(root: Path, base: str, page: Any, how: str) -> None:
    """A stream of one moment (no timeline, or no time between start and end): no play
    button, scrubber or clock, never playing, and the scene drawn."""
    if how == "static PLY":
        page.goto(f"{base}/play/still")
    else:
        manifest = unpacked_manifest(root)
        manifest["scene"]["end_s"] = manifest["scene"]["start_s"]
        page.goto(base + routed_origin(page, root / "unpacked", manifest))
    page.wait_for_function(
        "window.tsogPlayer?.error || window.tsogPlayer?.stream?.covered(tsogPlayer.playback.t)",
        timeout=START_TIMEOUT_MS,
    )
    assert page.evaluate("window.tsogPlayer.error ?? null") is None
    for selector in TIME_CONTROLS:
        assert not page.is_visible(selector), selector
    assert page.is_visible("#reset") and page.is_visible("#link")  # the view's controls stay
    page.keyboard.press("Space")
    page.wait_for_timeout(300)
    assert not page.evaluate("tsogPlayer.playback.playing")
    assert page.text_content("#o-state") == "still"
    page.add_style_tag(content=HIDE_UI)
    page.wait_for_timeout(500)
    assert drawn_share(page.screenshot()) > MIN_DRAWN


@pytest.mark.parametrize("assumed", [True, False])
def test_an_assumed_duration_is_marked(root: Path, base: str, page: Any, assumed: bool) -> None:
    manifest = unpacked_manifest(root)
    if assumed:
        manifest["scene"]["duration_assumed"] = True
    page.goto(base + routed_origin(page, root / "unpacked", manifest) + "&paused")
    page.wait_for_function(
        "window.tsogPlayer?.playback || window.tsogPlayer?.error", timeout=START_TIMEOUT_MS
    )
    end = manifest["scene"]["end_s"]
    label = page.locator("#duration")
    if assumed:
        assert label.text_content() == f"{end:.2f} s (assumed)"
        title = label.get_attribute("title") or ""
        assert "does not carry its length" in title and "--duration-s" in title
    else:
        assert label.text_content() == f"{end:.2f} s"
        assert label.get_attribute("title") is None
