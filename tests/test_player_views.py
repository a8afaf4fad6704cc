"""The player's first view and its controls, in headless Chromium on a real capture.

The opening view of a scene with capture cameras is its first camera: the page's frame must
match the CPU renderer's image from that camera (and ``tsog render``'s default view is that
image exactly). Without cameras it is a framing of the dense core. Keyboard, mouse and touch
move the camera and the time as docs/design/player.md says.
"""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from browser import PlayerPage, chromium, page_opener, served
from conftest import missing_optional, optional_data_dir
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.framing import FRAMING_NAME
from tsog_stream.render import from_capture, render, to_uint8
from tsog_stream.render.metrics import mse, psnr_from_mse
from tsog_stream.schemas.cameras import Camera
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene, rig_cameras

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SPINACH = "4d/splatv/macaburguera_spinach_4.splatv"
T = 0.5
MIN_PSNR = 25.0  # the bar: the page's frame against the CPU render from the same camera
SIZE = (640, 480)  # browser.VIEWPORT
CLEAR = (18 / 255, 18 / 255, 18 / 255)  # the page's clear colour (0.07 grey)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return psnr_from_mse(mse(np.asarray(a, np.uint8), np.asarray(b, np.uint8)))


@dataclass(frozen=True)
class Scenes:
    root: Path
    views: dict[str, Camera]
    cameras: dict[str, list[Camera]]
    cpu: dict[str, np.ndarray]  # the CPU render of each opening view at T, 640x480


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Scenes:
    """A generated scene with rig cameras, the same scene without cameras and, when the
    optional samples are here, a real capture (spinach, its own camera), segmented; CPU
    renders of their opening views at T. (A clone without the samples still tests the rest.)"""
    root = tmp_path_factory.mktemp("views")
    spec = SceneSpec(background=3000, objects=4, per_object=300, seed=7)
    synthetic = generate_scene(spec)
    segment_scene(synthetic, root / "rig.tsogs", SegmentOptions(), cameras=rig_cameras(4))
    segment_scene(synthetic, root / "framed.tsogs", SegmentOptions())
    names = ["rig", "framed"]
    data = optional_data_dir()
    if data is not None and (data / SPINACH).is_file():
        argv = ["segment", str(data / SPINACH), "-o", str(root / "spinach.tsogs"), "-q"]
        assert main(argv) == 0
        names.append("spinach")
    views, cameras, cpu = {}, {}, {}
    for name in names:
        with open_stream(root / f"{name}.tsogs") as reader:
            manifest = reader.index.manifest
            assert manifest.view is not None
            views[name], cameras[name] = manifest.view, list(manifest.cameras)
            frame = reader.frame_at(T)
        camera = from_capture(manifest.view, *SIZE)
        cpu[name] = to_uint8(render(frame, camera, background=CLEAR))
    return Scenes(root, views, cameras, cpu)


@pytest.fixture(scope="module")
def base(scenes: Scenes) -> Iterator[str]:
    with served(make_app(scenes.root)) as url:
        yield url


@pytest.fixture(scope="module")
def browser(scenes: Scenes) -> Iterator[Any]:
    with chromium() as b:
        yield b


@pytest.fixture
def open_page(browser: Any) -> Iterator[Any]:
    with page_opener(browser) as open_:
        yield open_


@pytest.mark.parametrize("name", ["spinach", "rig", "framed"])
def test_the_page_opens_on_the_view_the_cpu_renderer_draws(
    scenes: Scenes, base: str, open_page: Any, name: str
) -> None:
    if name not in scenes.views:
        missing_optional(SPINACH)
    view = scenes.views[name]
    if name == "framed":
        assert view.name == FRAMING_NAME and scenes.cameras[name] == []
    else:
        assert view == scenes.cameras[name][0]
    frame = open_page(f"{base}/play/{name}?t={T}&paused").frame()
    reference = scenes.cpu[name]
    assert (reference.sum(axis=2) > 60).mean() > 0.05, "the reference view is nearly empty"
    assert psnr(frame, reference) >= MIN_PSNR
    # Teeth: the same page seen from 20 degrees further round is far below the bar.
    turned = open_page(f"{base}/play/{name}?t={T}&paused")
    turned.js("tsogPlayer.controls.orbit(20 / 0.3, 0)")
    assert psnr(turned.frame(), reference) < MIN_PSNR - 5


def pose(page: PlayerPage) -> dict[str, Any]:
    """The camera's world position and forward, the controls' state, and the playhead."""
    return page.js(  # type: ignore[no-any-return]
        """(() => { const p = tsogPlayer, c = p.controls, e = p.camera;
            const v = (x) => [x.x, x.y, x.z];
            return { position: v(e.getPosition()), forward: v(e.forward), target: v(c.target),
                     yaw: c.yaw, pitch: c.pitch, distance: c.distance, exact: c.exact !== null,
                     t: p.playback.t, playing: p.playback.playing }; })()"""
    )


def settle(page: PlayerPage) -> dict[str, Any]:
    """The pose after the next two animation frames (the camera is placed once per frame)."""
    page.js("new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r)))")
    return pose(page)


def test_keys_move_the_time_and_the_camera(base: str, open_page: Any) -> None:
    page = open_page(f"{base}/play/rig?t=1&paused")
    keyboard = page.page.keyboard
    start = settle(page)
    assert start["exact"] and not start["playing"]
    keyboard.press("ArrowRight")
    assert settle(page)["t"] == pytest.approx(1 + 1 / 30)
    keyboard.press("Shift+ArrowRight")
    assert settle(page)["t"] == pytest.approx(2 + 1 / 30)
    keyboard.press("Comma")
    keyboard.press("Comma")
    assert settle(page)["t"] == pytest.approx(2 - 1 / 30)
    keyboard.press("Space")
    assert settle(page)["playing"]
    keyboard.press("Space")
    assert not settle(page)["playing"]
    # W flies forward along the view; R returns to the opening view exactly.
    keyboard.down("KeyW")
    page.page.wait_for_timeout(400)
    keyboard.up("KeyW")
    moved = settle(page)
    step = np.subtract(moved["position"], start["position"])
    assert np.dot(step, start["forward"]) > 0.1 and not moved["exact"]
    keyboard.press("KeyR")
    back = settle(page)
    np.testing.assert_allclose(back["position"], start["position"], atol=1e-5)
    np.testing.assert_allclose(back["forward"], start["forward"], atol=1e-5)
    # Digits pick capture cameras: camera 2 of the rig is where the manifest puts it.
    keyboard.press("Digit2")
    at = settle(page)
    rig = rig_cameras(4)[2]
    np.testing.assert_allclose(at["position"], page_position(page, rig), atol=1e-4)
    assert page.page.input_value("#camera") == "2"
    keyboard.press("Slash")
    assert page.js("!document.getElementById('keys').hidden")  # (the test page hides it)


def page_position(page: PlayerPage, camera: Camera) -> list[float]:
    """Where the page's world puts a capture camera's centre (the scene is turned up)."""
    return page.js(  # type: ignore[no-any-return]
        """([x, y, z]) => { const pc = tsogPlayer.pc;
            const v = tsogPlayer.views.turn.transformVector(new pc.Vec3(x, y, z), new pc.Vec3());
            return [v.x, v.y, v.z]; }""",
        list(camera.position),
    )


def test_mouse_and_touch_orbit_pan_zoom_and_pivot(base: str, open_page: Any) -> None:
    page = open_page(f"{base}/play/rig?t=1&paused")
    mouse = page.page.mouse
    start = settle(page)
    mouse.move(320, 240)
    mouse.down()
    mouse.move(370, 240, steps=5)
    mouse.up()
    turned = settle(page)
    assert turned["yaw"] == pytest.approx(start["yaw"] - 50 * 0.3, abs=0.5)
    np.testing.assert_allclose(turned["target"], start["target"], atol=1e-6)
    mouse.wheel(0, 300)
    zoomed = settle(page)
    assert zoomed["distance"] == pytest.approx(turned["distance"] * np.exp(0.3), rel=1e-3)
    mouse.move(320, 240)
    mouse.down(button="right")
    mouse.move(320, 300, steps=4)
    mouse.up(button="right")
    panned = settle(page)
    assert panned["yaw"] == zoomed["yaw"] and panned["distance"] == zoomed["distance"]
    assert np.linalg.norm(np.subtract(panned["target"], zoomed["target"])) > 0.01
    mouse.dblclick(200, 150)
    pivoted = settle(page)
    np.testing.assert_allclose(pivoted["position"], panned["position"], atol=1e-4)
    assert np.linalg.norm(np.subtract(pivoted["target"], panned["target"])) > 0.1
    # Two fingers moving apart zoom in (pointer events as a touch screen sends them).
    page.js(PINCH)
    pinched = settle(page)
    assert pinched["distance"] < 0.8 * pivoted["distance"]


PINCH = """(() => {
    const el = document.getElementById('view');
    const send = (type, id, x) => el.dispatchEvent(new PointerEvent(type, {
        pointerId: id, pointerType: 'touch', isPrimary: id === 11, clientX: x, clientY: 240,
        bubbles: true, button: 0 }));
    send('pointerdown', 11, 300); send('pointerdown', 12, 340);
    for (let k = 1; k <= 5; k++) {
        send('pointermove', 11, 300 - 10 * k);
        send('pointermove', 12, 340 + 10 * k);
    }
    send('pointerup', 11, 250); send('pointerup', 12, 390);
})()"""


def test_a_copied_link_reopens_the_same_time_and_view(base: str, open_page: Any) -> None:
    page = open_page(f"{base}/play/rig?t=1.25&paused")
    page.page.keyboard.press("Digit1")
    page.js("document.getElementById('link').click()")
    link = page.js("tsogPlayer.link")
    assert "t=1.250" in link and "camera=1" in link and "paused" in link
    first = page.frame()
    again = open_page(link)
    assert psnr(again.frame(), first) > 40
    # A view moved by hand is written as its pivot, angles and distance.
    page.js("tsogPlayer.controls.orbit(40, 10)")
    page.js("document.getElementById('link').click()")
    moved = page.js("tsogPlayer.link")
    assert "pose=" in moved and "camera=" not in moved
    reopened = open_page(moved)
    assert psnr(reopened.frame(), page.frame()) > 40


def test_scene_json_carries_cameras_and_view(base: str, scenes: Scenes) -> None:
    with urllib.request.urlopen(f"{base}/v1/scenes/rig/manifest") as response:
        manifest = json.loads(response.read())
    assert [c["name"] for c in manifest["cameras"]] == [f"rig_{k:02d}" for k in range(4)]
    assert manifest["view"]["name"] == "rig_00" and manifest["scene"]["core"]["radius"] > 0
