"""Headless Chromium for the web player's tests: Debian's browser driven by playwright.

The browser is Debian's ``chromium`` (installed by scripts/setup; never a browser download),
started with the flags the issue names, so WebGL2 runs on SwiftShader. Every wait is bounded.
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image
from playwright.sync_api import sync_playwright

CHROMIUM = os.environ.get("TSOG_CHROMIUM", "/usr/bin/chromium")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 640, "height": 480}
HIDE_UI = ".overlay,.controls,.error,.copied,.keys{display:none !important}"
LOAD_TIMEOUT_MS = 30_000
COVERED = "window.tsogPlayer?.stream?.covered(window.tsogPlayer.playback.t)"
"""Page expression: every chunk the playhead needs is loaded."""
STABLE_TRIES = 40
RGB = npt.NDArray[np.int16]

SHOW_STATIC = """async (url) => {
    const p = window.tsogPlayer, pc = p.pc;
    p.stream.root.enabled = false;
    for (const e of p.app.root.find((n) => n.name === 'reference')) e.destroy();
    const asset = new pc.Asset('reference', 'gsplat', { url });
    await new Promise((resolve, reject) => {
        asset.once('load', resolve);
        asset.once('error', (err) => reject(new Error(String(err))));
        p.app.assets.add(asset);
        p.app.assets.load(asset);
    });
    const entity = new pc.Entity('reference');
    entity.addComponent('gsplat', { asset });
    p.stream.root.parent.addChild(entity);
    p.redraw();
}"""


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Debian Chromium, closed on exit."""
    if not os.access(CHROMIUM, os.X_OK):
        pytest.fail(f"{CHROMIUM} is missing: run scripts/setup (installs Debian's chromium)")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            yield browser
        finally:
            browser.close()


class PlayerPage:
    """One player page: its console errors, its network requests and its frames."""

    def __init__(self, browser: Any, url: str) -> None:
        self.page = browser.new_page(viewport=VIEWPORT)
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("console", self._console)
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(url)
        self.page.add_style_tag(content=HIDE_UI)
        self.wait_covered()

    def _console(self, message: Any) -> None:
        if message.type == "error":
            self.errors.append(message.text)

    def js(self, expression: str, arg: Any = None) -> Any:
        """Evaluate in the page."""
        return self.page.evaluate(expression, arg)

    def wait_covered(self) -> None:
        """Until the player failed or every chunk the playhead needs is loaded."""
        self.page.wait_for_function(
            f"window.tsogPlayer?.error || {COVERED}", timeout=LOAD_TIMEOUT_MS
        )
        error = self.js("window.tsogPlayer.error ?? null")
        assert error is None, error

    def wait_all_layers(self) -> None:
        """Until every layer at the playhead is drawn, each base chunk with its SH bands."""
        self.page.wait_for_function(
            """() => { const s = window.tsogPlayer.stream;
                return s.error || s.stats().layers === s.index.layerCount && [...s.shown].every(
                    (id) => !s.bandsOf.has(id) || s.chunks.get(id)?.withBands); }""",
            timeout=LOAD_TIMEOUT_MS,
        )
        error = self.js("window.tsogPlayer.stream.error")
        assert error is None, error

    def seek(self, t: float) -> None:
        """Drag the scrub bar to t (an input event, as a user's drag sends) and wait."""
        self.js(
            """(t) => { const s = document.getElementById('scrub');
                s.value = String(t); s.dispatchEvent(new Event('input')); }""",
            t,
        )
        self.page.wait_for_function(f"window.tsogPlayer.playback.t === {t!r}", timeout=5000)
        self.wait_covered()

    def frame(self) -> RGB:
        """The rendered frame once two screenshots in a row agree (work buffer and sort done)."""
        last = None
        for _ in range(STABLE_TRIES):
            shot = Image.open(io.BytesIO(self.page.screenshot())).convert("RGB")
            image = np.asarray(shot).astype(np.int16)
            if last is not None and np.array_equal(image, last):
                return image
            last = image
            time.sleep(0.15)
        pytest.fail(f"the frame did not settle in {STABLE_TRIES} screenshots")

    def show_static(self, url: str) -> RGB:
        """Hide the stream and draw the static SOG at ``url`` with the same camera instead."""
        self.js(SHOW_STATIC, url)
        return self.frame()

    def project(self, points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Screen pixels (x, y) of scene points through the page's camera."""
        xy = self.js(
            """(pts) => { const p = window.tsogPlayer, pc = p.pc, out = new pc.Vec3();
                const m = p.stream.root.parent.getWorldTransform(), w = new pc.Vec3();
                return pts.map(([x, y, z]) => { m.transformPoint(new pc.Vec3(x, y, z), w);
                    p.camera.camera.worldToScreen(w, out); return [out.x, out.y]; }); }""",
            points.tolist(),
        )
        return np.asarray(xy, np.float64).reshape(-1, 2)

    def close(self) -> None:
        """Close the page."""
        self.page.close()


@contextmanager
def page_opener(browser: Any) -> Iterator[Callable[[str], PlayerPage]]:
    """A function opening player pages; on exit every page must have logged no error, and is
    closed (the ``open_page`` fixture of the browser tests)."""
    pages: list[PlayerPage] = []

    def open_(url: str) -> PlayerPage:
        pages.append(PlayerPage(browser, url))
        return pages[-1]

    yield open_
    for page in pages:
        assert page.errors == [], page.errors
        page.close()


@contextmanager
def served(app: Any) -> Iterator[str]:
    """The base URL of ``app`` served on loopback by a ThreadedServer, stopped on exit."""
    from helpers import ThreadedServer  # noqa: PLC0415 - tests/ is on the path here

    server = ThreadedServer(app)
    try:
        yield f"http://127.0.0.1:{server.port}"
    finally:
        server.stop()


def image_difference(a: RGB, b: RGB) -> npt.NDArray[np.int16]:
    """Per-pixel largest channel difference."""
    diff: npt.NDArray[np.int16] = np.abs(a - b).max(axis=2)
    return diff


def near(points: npt.NDArray[np.float64], shape: tuple[int, int], radius: int) -> np.ndarray:
    """Mask of pixels within ``radius`` of any of the screen points."""
    mask = np.zeros(shape, bool)
    for x, y in np.rint(points).astype(int):
        mask[
            max(0, y - radius) : max(0, y + radius + 1), max(0, x - radius) : max(0, x + radius + 1)
        ] = True
    return mask
