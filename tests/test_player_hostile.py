"""A foreign manifest given to the page (/play/?manifest=URL) is checked before the page uses
any of it (issue 55): a chunk file that is not chunks/NNNNNN.sog beside the manifest (another
host, another path, a javascript: or data: URL) and numbers the page would turn into sizes,
loop bounds or URLs out of range are refused with a message on the page, and the page asks for
nothing but the manifest. The manifest is served through Playwright routing (a static origin
the test controls); every request the page makes is logged by Playwright."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from browser import VIEWPORT, chromium, served
from helpers import free_port
from tsog_stream.client import open_stream
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CLOSED = free_port()  # nothing listens there
Manifest = dict[str, Any]


def chunk_file(value: str) -> Callable[[Manifest], None]:
    def change(m: Manifest) -> None:
        m["chunks"][0]["file"] = value

    return change


def field(path: str, value: Any) -> Callable[[Manifest], None]:
    """Set the field at a dotted path (list indexes as numbers)."""

    def change(m: Manifest) -> None:
        *parents, last = path.split(".")
        node: Any = m
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        node[int(last) if isinstance(node, list) else last] = value

    return change


HOSTILE: dict[str, tuple[Callable[[Manifest], None], str]] = {
    "absolute URL": (chunk_file(f"http://127.0.0.1:{CLOSED}/chunks/000000.sog"), "chunks[0].file"),
    "scheme-relative": (chunk_file(f"//127.0.0.1:{CLOSED}/x.sog"), "chunks[0].file"),
    "parent path": (chunk_file("../chunks/000000.sog"), "chunks[0].file"),
    "root path": (chunk_file("/chunks/000000.sog"), "chunks[0].file"),
    "short number": (chunk_file("chunks/1.sog"), "chunks[0].file"),
    "query": (chunk_file(f"chunks/000000.sog?//127.0.0.1:{CLOSED}"), "chunks[0].file"),
    "javascript": (chunk_file("javascript:alert(1)"), "chunks[0].file"),
    "data URL": (chunk_file("data:application/octet-stream;base64,AAAA"), "chunks[0].file"),
    "not text": (chunk_file({"href": "x"}), "chunks[0].file"),  # type: ignore[arg-type]
    "huge length": (field("chunks.0.length", 1e300), "chunks[0].length"),
    "length past the cap": (field("chunks.0.length", 2**31), "chunks[0].length"),
    "huge offset": (field("chunks.0.offset", 2**80), "chunks[0].offset"),
    "negative count": (field("chunks.0.count", -1), "chunks[0].count"),
    "fractional count": (field("chunks.0.count", 1.5), "chunks[0].count"),
    "chunk id": (field("chunks.0.id", 7), "chunks[0].id"),
    "layer past the layers": (field("chunks.0.layer", 9), "chunks[0].layer"),
    "sha256 path": (field("chunks.0.sha256", "../" * 21 + "x"), "chunks[0].sha256"),
    "node names no chunk": (field("nodes.0.chunks", [10**9]), "nodes[0].chunks[0]"),
    "node level": (field("nodes.0.level", 100_000), "nodes[0].level"),
    "no window": (field("window_s", 0), "window_s"),
    "time as text": (field("scene.start_s", "0"), "scene.start_s"),
    "end before start": (field("scene.end_s", -5.0), "scene.end_s"),
    "chunks not a list": (field("chunks", {"0": {}}), "chunks"),
    "camera": (
        field("view", {"position": [0, 0, 0], "rotation": [[1]], "fy": 1, "height": 1}),
        "view.rotation",
    ),
}


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small two-window stream, unpacked."""
    root = tmp_path_factory.mktemp("hostile")
    spec = SceneSpec(TimelineType.CENTER_SCALE, background=300, objects=2, per_object=100, seed=9)
    segment_scene(
        generate_scene(spec), root / "small.tsogs", SegmentOptions(window_s=1.0, layers=1)
    )
    with open_stream(root / "small.tsogs") as reader:
        reader.unpack(root / "unpacked")
    return root


@pytest.fixture(scope="module")
def base(root: Path) -> Iterator[str]:
    with served(make_app(root)) as url:
        yield url


@pytest.fixture(scope="module")
def browser(root: Path) -> Iterator[Any]:
    with chromium() as b:
        yield b


class Origin:
    """A page whose /hostile/ requests are answered by the test: the manifest given, the
    unpacked chunks (with `extra` bytes after each); every request the page makes is kept."""

    def __init__(self, browser: Any, root: Path, manifest: Manifest, extra: int = 0) -> None:
        self.page = browser.new_page(viewport=VIEWPORT)
        self.requests: list[str] = []
        self.page.on("request", lambda r: self.requests.append(r.url))
        body = json.dumps(manifest)

        def handle(route: Any) -> None:
            path = urlsplit(route.request.url).path.removeprefix("/hostile/")
            if path == "manifest.json":
                route.fulfill(status=200, content_type="application/json", body=body)
            else:
                data = (root / "unpacked" / path).read_bytes()
                route.fulfill(status=200, body=data + b"\0" * extra)

        self.page.route(lambda url: urlsplit(url).path.startswith("/hostile/"), handle)

    def open(self, base: str) -> None:
        self.page.goto(f"{base}/play/?manifest=/hostile/manifest.json&t=0.5&paused")

    def outside(self, base: str) -> list[str]:
        """Requests other than the page, its modules, the manifest and chunks/NNNNNN.sog."""
        page = r"play/\?manifest=.*|player/[\w./-]+"
        stream = r"hostile/manifest\.json|hostile/chunks/[0-9]{6}\.sog"
        allowed = re.compile(f"{re.escape(base)}/({page}|{stream})")
        return [u for u in self.requests if not allowed.fullmatch(u) and u != "data:,"]


def manifest_of(root: Path) -> Manifest:
    data: Manifest = json.loads((root / "unpacked" / "manifest.json").read_text())
    return data


@pytest.mark.parametrize("shape", HOSTILE)
def test_a_hostile_manifest_is_refused_before_any_request(
    root: Path, base: str, browser: Any, shape: str
) -> None:
    change, where = HOSTILE[shape]
    manifest = manifest_of(root)
    change(manifest)
    origin = Origin(browser, root, manifest)
    try:
        origin.open(base)
        origin.page.wait_for_function("window.tsogPlayer?.error", timeout=20_000)
        assert origin.page.is_visible("#error")
        message = origin.page.text_content("#error") or ""
        assert message.startswith(f"player error: manifest refused: {where} "), message
        assert origin.outside(base) == []
        assert not [u for u in origin.requests if "/chunks/" in u], "a chunk was asked for"
        assert origin.page.evaluate("window.tsogPlayer.stream === undefined")
    finally:
        origin.page.close()


def test_the_unchanged_manifest_plays_from_its_own_chunks(
    root: Path, base: str, browser: Any
) -> None:
    """The control: the same route with the manifest untouched fetches its chunks, only
    there (so the request log above would have seen a chunk request)."""
    origin = Origin(browser, root, manifest_of(root))
    try:
        origin.open(base)
        origin.page.wait_for_function(
            "window.tsogPlayer?.error || window.tsogPlayer?.stream?.covered(0.5)", timeout=30_000
        )
        assert origin.page.evaluate("window.tsogPlayer.error ?? null") is None
        assert [u for u in origin.requests if "/hostile/chunks/" in u]
        assert origin.outside(base) == []
    finally:
        origin.page.close()


def test_a_chunk_longer_than_its_manifest_says_is_cut_off(
    root: Path, base: str, browser: Any
) -> None:
    """The page reads a chunk's body up to the manifest's length, no further: a server that
    sends more fails that chunk (reported), it does not make the page hold it."""
    origin = Origin(browser, root, manifest_of(root), extra=4096)
    try:
        origin.open(base)
        origin.page.wait_for_function(
            "window.tsogPlayer?.stream?.stats().failed > 0", timeout=30_000
        )
        error = origin.page.evaluate("window.tsogPlayer.stream.error")
        assert re.fullmatch(r"chunk \d+: more than the manifest's \d+ bytes", error), error
    finally:
        origin.page.close()


@pytest.mark.parametrize(("fy", "fov"), [(1e-30, 175.0), (1e30, 1.1)])
def test_a_stored_view_s_field_of_view_is_held_to_the_renderer_s_range(
    root: Path, base: str, browser: Any, fy: float, fov: float
) -> None:
    """A stored opening view whose focal length gives a field of view of ~180 or ~0 degrees
    opens the scene at the CPU renderer's limit (render/camera.py FOCAL_PER_SIDE), not with a
    degenerate projection."""
    manifest = manifest_of(root)
    assert manifest["view"] is not None
    manifest["view"]["fy"] = fy
    origin = Origin(browser, root, manifest)
    try:
        origin.open(base)
        origin.page.wait_for_function(
            "window.tsogPlayer?.error || window.tsogPlayer?.stream?.covered(0.5)", timeout=30_000
        )
        assert origin.page.evaluate("window.tsogPlayer.error ?? null") is None
        shown = origin.page.evaluate("window.tsogPlayer.camera.camera.fov")
        assert shown == pytest.approx(fov)
    finally:
        origin.page.close()
