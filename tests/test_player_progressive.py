"""The web player on a layered stream over a slow link (issue 19): the base layer is drawn as
soon as it arrives, layers are added as they land, and the overlay says which are shown.
Headless Chromium, the real server, and the shaped loopback relay in front of it: the page and
the engine come straight from the server, the stream (unpacked, as from any static origin)
through the relay."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from browser import HIDE_UI, VIEWPORT, chromium
from tsog_stream.client import open_stream
from tsog_stream.io.splatv import read_splatv
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app, start_server
from tsog_stream.server.link import LinkShape, ThrottledRelay

HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
T = 2.0
"""A time whose base layer is a small share of its bytes (the fireworks at their fullest)."""
BANDWIDTH_BPS = 100e3
"""Slow enough that the base is up well before the rest lands (about 1 s alone on screen)."""
TWO_FRAMES = "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"
"""Waits until the page has drawn twice."""
POLL_S = 0.05
TIMEOUT_S = 60.0
BACKGROUND = np.array([18, 18, 18])  # the page's clear colour (0.07 grey)


class ShapedOrigin:
    """Our server for ``root``, and a shaped relay in front of it, on a loop in a background
    thread."""

    def __init__(self, root: Path, shape: LinkShape) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.runner, self.relay = self._call(self._start(root, shape))

    def _call(self, coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(30)

    async def _start(self, root: Path, shape: LinkShape) -> tuple[Any, ThrottledRelay]:
        runner, port = await start_server(make_app(root))
        self.direct = f"http://127.0.0.1:{port}"
        return runner, await ThrottledRelay(port, shape).start()

    async def _stop(self) -> None:
        await self.relay.aclose()
        await self.runner.cleanup()

    def stop(self) -> None:
        self._call(self._stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@dataclass(frozen=True)
class LayeredPage:
    url: str
    upper_layer_files: frozenset[str]
    """The chunk files of every layer above the base (the manifest's ``file``)."""


@pytest.fixture(scope="module")
def layered_page(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[LayeredPage]:
    """The player page (from the server) of the layered clip's manifest behind the relay."""
    root = tmp_path_factory.mktemp("progressive-player")
    loaded = read_splatv(samples / HANABI, duration_s=4.0)
    options = SegmentOptions(window_s=1.0, layers=3)
    segment_scene(loaded.scene, root / "fireworks.tsogs", options, cameras=loaded.cameras)
    with open_stream(root / "fireworks.tsogs") as reader:
        reader.unpack(root / "fireworks")
    chunks = json.loads((root / "fireworks" / "manifest.json").read_text())["chunks"]
    upper = frozenset(c["file"] for c in chunks if c.get("layer", 0) > 0)
    shaped = ShapedOrigin(root, LinkShape(BANDWIDTH_BPS, 0.02))
    try:
        manifest = shaped.relay.url("/files/fireworks/manifest.json")
        yield LayeredPage(f"{shaped.direct}/play/?manifest={manifest}&t={T}&paused", upper)
    finally:
        shaped.stop()


def _shot(page: Any) -> np.ndarray:
    from io import BytesIO  # noqa: PLC0415

    from PIL import Image  # noqa: PLC0415

    return np.asarray(Image.open(BytesIO(page.screenshot())).convert("RGB")).astype(np.int16)


def _drawn(shot: np.ndarray) -> float:
    """The share of a screenshot's pixels that differ from the page's background."""
    return float((np.abs(shot - BACKGROUND).max(axis=2) > 8).mean())


def _first_picture(page: Any, timeout_s: float = 10.0) -> np.ndarray:
    """A screenshot once the canvas shows more than the background, two frames at a time
    (a loaded chunk is drawn a frame or more later on a busy machine); the last one taken when
    it never does."""
    deadline = time.monotonic() + timeout_s
    while True:
        page.evaluate(TWO_FRAMES)
        shot = _shot(page)
        if _drawn(shot) > 0.001 or time.monotonic() > deadline:
            return shot


class HeldRequests:
    """Holds the page's requests for ``files`` until released (the shot of the base alone is
    taken while the layers above it cannot land, however slow the machine is that moment)."""

    def __init__(self, files: frozenset[str]) -> None:
        self.files = files
        self.held: list[Any] = []
        self.released = False

    def route(self, route: Any) -> None:
        if not self.released and any(route.request.url.endswith(f) for f in self.files):
            self.held.append(route)
        else:
            route.continue_()

    def release(self) -> None:
        self.released = True
        for route in self.held:
            route.continue_()


def test_the_base_is_drawn_first_and_layers_are_added_as_they_land(
    layered_page: LayeredPage,
) -> None:
    assert layered_page.upper_layer_files
    seen: list[tuple[float, int, str]] = []
    with chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        upper = HeldRequests(layered_page.upper_layer_files)
        page.route("**/chunks/*", upper.route)
        began = time.monotonic()
        page.goto(layered_page.url)
        base_shot, base_alone = None, False
        while time.monotonic() - began < TIMEOUT_S:
            state = page.evaluate(
                """() => { const p = window.tsogPlayer; if (!p?.stream) return null;
                    const s = p.stream.stats();
                    return [s.layers, s.layerCount, document.getElementById('o-quality')
                        .textContent, p.stream.covered(p.playback.t)]; }"""
            )
            if state is not None and state[0] >= 1:
                layers, count, text, _ = state
                seen.append((time.monotonic() - began, layers, text))
                if layers == 1 and base_shot is None:
                    page.add_style_tag(content=HIDE_UI)
                    base_shot = _first_picture(page)  # the base alone: the rest is held
                    base_alone = page.evaluate("window.tsogPlayer.stream.stats().layers") == 1
                    upper.release()
                if layers == count:
                    break
            time.sleep(POLL_S)
        page.add_style_tag(content=HIDE_UI)
        page.wait_for_timeout(500)
        full_shot = _shot(page)
        text = page.evaluate("document.getElementById('o-quality').textContent")
        page.close()
    assert errors == []
    assert seen, "the page never drew t"
    layers_seen = [layers for _, layers, _ in seen]
    assert layers_seen[0] == 1 and layers_seen[-1] == 3, layers_seen
    assert layers_seen == sorted(layers_seen)  # added as they land, never taken back
    first_full = next(when for when, layers, _ in seen if layers == 3)
    assert first_full - seen[0][0] > 0.3  # the base was up well before the rest landed
    assert any(q.startswith("1/3 layers (") and "dB" in q for _, _, q in seen), seen
    assert text == "3/3 layers (full)"
    assert upper.held, "the layers above the base were never asked for"
    assert base_shot is not None and base_alone, "no settled frame with the base alone"
    assert _drawn(base_shot) > 0.001  # the base alone is a picture, not the empty background
    assert (np.abs(full_shot - base_shot).max(axis=2) > 8).mean() > 0.0005  # layers added
