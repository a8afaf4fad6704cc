"""The web player routes over HTTP: scene index, player page, static files and the engine."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import re
import subprocess
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, quote

import pytest

from helpers import ThreadedServer, fetch
from tsog_stream.client import open_stream
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import Privacy, make_app
from tsog_stream.server.player import ENGINE_ENV, PACKAGED_ENGINE, PLAYER_DIR
from tsog_stream.signing import sign_url
from tsog_stream.synthetic import small_scene

SECRET = b"player-test-secret-0123456789abcdef"
JS_MODULES = (
    "player.js",
    "stream.js",
    "manifest.js",
    "zip.js",
    "tsog.js",
    "controls.js",
    "views.js",
)
OUTSIDE = b"OUTSIDE-THE-PLAYER-FOLDER"
ENGINE = Path(__file__).resolve().parents[1] / "node_modules/playcanvas/build/playcanvas.mjs"
"""The pinned npm build (package.json) that the package's copy must equal."""


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a packed scene, its unpacked layout, a private scene and a file beside."""
    base = tmp_path_factory.mktemp("play")
    (base / "outside.js").write_bytes(OUTSIDE)
    root = base / "root"
    (root / "paid").mkdir(parents=True)
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0)
    segment_scene(scene, root / "clip.tsogs", SegmentOptions(window_s=0.5))
    with open_stream(root / "clip.tsogs") as reader:
        reader.unpack(root / "unpacked")
    (root / "paid" / "secret.tsogs").write_bytes((root / "clip.tsogs").read_bytes())
    return root


@pytest.fixture(scope="module")
def port(root: Path) -> Iterator[int]:
    """Our server on the folder, with ``paid/`` private."""
    server = ThreadedServer(make_app(root, privacy=Privacy(("paid",), SECRET)))
    try:
        yield server.port
    finally:
        server.stop()


def test_index_lists_public_scenes_with_links(port: int) -> None:
    r = fetch(port, "/play/")
    assert r.status == 200
    assert r.headers["Content-Type"] == "text/html; charset=utf-8"
    assert r.headers["Cache-Control"] == "no-cache"
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    pattern = r'<a href="([^"]+)">.*?<span class="name">([^<]+)</span>'
    links = re.findall(pattern, r.body.decode())
    assert links == [("/play/clip", "clip"), ("/play/unpacked", "unpacked")]
    assert b"secret" not in r.body and b"paid" not in r.body


@pytest.mark.parametrize("path", ["/play", "/"])
def test_play_without_slash_and_the_root_redirect(port: int, path: str) -> None:
    r = fetch(port, path)
    assert r.status == 302 and r.headers["Location"] == "/play/"


@pytest.mark.parametrize("scene", ["clip", "unpacked"])
def test_scene_page(port: int, scene: str) -> None:
    r = fetch(port, f"/play/{scene}")
    assert r.status == 200
    assert r.headers["Content-Type"] == "text/html; charset=utf-8"
    assert r.headers["Cache-Control"] == "no-cache"
    page = r.body.decode()
    assert '<script type="module" src="/player/player.js"></script>' in page
    assert '"playcanvas": "/player/engine/playcanvas.mjs"' in page
    config = page_config(r.body)
    assert config == {
        "scene": scene,
        "manifest": f"/v1/scenes/{scene}/manifest",
        "chunks": f"/v1/scenes/{scene}/chunks/",
    }
    assert fetch(port, config["manifest"]).status == 200


@pytest.mark.parametrize("path", ["/play/nothing", "/play/clip/more", "/play/..%2Fclip"])
def test_unknown_scene_is_404_json(port: int, path: str) -> None:
    r = fetch(port, path)
    assert r.status == 404
    assert r.headers["Content-Type"].startswith("application/json")
    assert json.loads(r.body)["error"]["status"] == 404


def page_config(body: bytes) -> dict[str, Any]:
    """The JSON configuration a player page carries."""
    found = re.search(rb'<script type="application/json" id="tsog-config">(.*?)</script>', body)
    assert found is not None
    return dict(json.loads(found.group(1)))


def test_private_scene_page_needs_a_signature(port: int) -> None:
    assert fetch(port, "/play/paid/secret").status == 403


def test_signed_page_gets_a_signature_for_its_scene_api(port: int) -> None:
    expires = int(time.time()) + 600
    page = fetch(port, sign_url("/play/paid/secret", SECRET, expires))
    assert page.status == 200
    config = page_config(page.body)
    query = dict(parse_qsl(config["query"]))
    assert query["expires"] == str(expires) and query["scope"] == "/v1/scenes/paid/secret/"
    manifest = fetch(port, f"{config['manifest']}?{config['query']}")
    assert manifest.status == 200 and json.loads(manifest.body)["format"] == "tsogs"
    chunk = fetch(port, f"{config['chunks']}0.sog?{config['query']}")
    assert chunk.status == 200 and chunk.body[:4] == b"PK\x03\x04"
    assert fetch(port, "/files/paid/secret.tsogs?" + config["query"]).status == 403
    assert "query" not in page_config(fetch(port, "/play/clip").body)


@pytest.mark.parametrize(
    "url", ["http://cdn.example/clip/manifest.json", "/files/unpacked/manifest.json"]
)
def test_index_plays_a_manifest_url(port: int, url: str) -> None:
    r = fetch(port, "/play/?manifest=" + quote(url, safe=""))
    assert r.status == 200 and r.headers["Content-Type"] == "text/html; charset=utf-8"
    assert page_config(r.body) == {"scene": None, "manifest": url}


@pytest.mark.parametrize(
    "url", ["javascript:alert(1)", "file:///etc/passwd", "relative/manifest.json", "http://", ""]
)
def test_index_refuses_a_manifest_that_is_no_http_url(port: int, url: str) -> None:
    r = fetch(port, "/play/?manifest=" + quote(url, safe=""))
    assert r.status == 400
    assert "manifest" in json.loads(r.body)["error"]["message"]


def test_index_offers_a_form_for_a_manifest_url(port: int) -> None:
    body = fetch(port, "/play/").body.decode()
    assert '<form class="open" action="/play/" method="get">' in body
    assert '<input type="url" name="manifest" required' in body


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        *((name, "text/javascript") for name in JS_MODULES),
        ("style.css", "text/css"),
    ],
)
def test_static_files_with_etag_and_304(port: int, name: str, kind: str) -> None:
    r = fetch(port, f"/player/{name}")
    assert r.status == 200
    assert r.body == (PLAYER_DIR / name).read_bytes()
    assert r.headers["Content-Type"].split(";")[0] == kind
    assert r.headers["Cache-Control"] == "public, max-age=0, must-revalidate"
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    etag = r.headers["ETag"]
    again = fetch(port, f"/player/{name}", headers={"If-None-Match": etag})
    assert again.status == 304 and again.body == b""
    assert again.headers["ETag"] == etag


def test_the_packaged_engine_is_the_pinned_npm_build(port: int) -> None:
    if not ENGINE.is_file():
        pytest.fail(f"{ENGINE} is missing: run scripts/setup (npm ci installs playcanvas)")
    assert PACKAGED_ENGINE.read_bytes() == ENGINE.read_bytes(), (
        "the engine the package carries is not the npm build package.json pins: copy "
        f"{ENGINE} to {PACKAGED_ENGINE} (and update its README's SHA-256)"
    )
    digest = hashlib.sha256(PACKAGED_ENGINE.read_bytes()).hexdigest()
    assert digest in (PACKAGED_ENGINE.parent / "README.md").read_text()
    version = json.loads((ENGINE.parents[1] / "package.json").read_text())["version"]
    pinned = json.loads((ENGINE.parents[3] / "package.json").read_text())["dependencies"]
    assert (
        pinned["playcanvas"] == version
        and version in (PACKAGED_ENGINE.parent / "README.md").read_text()
    )
    r = fetch(port, "/player/engine/playcanvas.mjs")
    assert r.status == 200
    assert r.headers["Content-Type"].split(";")[0] == "text/javascript"
    assert r.body == ENGINE.read_bytes()
    assert (
        fetch(
            port, "/player/engine/playcanvas.mjs", headers={"If-None-Match": r.headers["ETag"]}
        ).status
        == 304
    )


def test_engine_missing_where_the_environment_says_is_explained(
    root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(ENGINE_ENV, str(tmp_path))
    server = ThreadedServer(make_app(root))
    try:
        r = fetch(server.port, "/player/engine/playcanvas.mjs")
    finally:
        server.stop()
    assert r.status == 404
    message = json.loads(r.body)["error"]["message"]
    assert ENGINE_ENV in message and "the package carries" in message


def test_engine_from_the_environment_folder(
    root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "playcanvas.mjs").write_bytes(b"export const fake = 1;\n")
    monkeypatch.setenv(ENGINE_ENV, str(tmp_path))
    server = ThreadedServer(make_app(root))
    try:
        r = fetch(server.port, "/player/engine/playcanvas.mjs")
    finally:
        server.stop()
    assert r.status == 200 and r.body == b"export const fake = 1;\n"


@pytest.mark.parametrize(
    "path",
    [
        "/player/../outside.js",
        "/player/%2e%2e/outside.js",
        "/player/%2E%2E%2Foutside.js",
        "/player/..%2F..%2Foutside.js",
        "/player/..%5Coutside.js",
        "/player/%2e%2e",
        "/player/.",
        "/player/index.html",
        "/player/player.py",
        "/player/engine/../player.js/../../app.py",
        "/player/engine/playcanvas.js",
        "/player/nope.js",
        "/player/player.js%00",
        "/player/PLAYER.JS",
        "/player/",
    ],
)
def test_traversal_is_refused(port: int, path: str) -> None:
    r = fetch(port, path)
    assert r.status == 404, path
    assert OUTSIDE not in r.body
    assert r.headers["Content-Type"].startswith("application/json")
    assert b"import" not in r.body and b"def " not in r.body


ZIP_WRITER = """
import { readFileSync } from 'node:fs';
import { readZip, writeZip } from '%(player)s/zip.js';
const input = JSON.parse(readFileSync(0, 'utf8'));
const files = new Map(input.map(([name, text]) => [name, new TextEncoder().encode(text)]));
const buffer = writeZip(files);
const back = await readZip(buffer);
if ([...back.keys()].join() !== [...files.keys()].join()) throw new Error('readZip differs');
process.stdout.write(Buffer.from(buffer).toString('base64'));
"""


def test_the_pages_zip_writer_makes_archives_any_reader_opens() -> None:
    """The page rebuilds a base chunk with its SH bands as a zip of its own (stream.js): the
    archive is read back by the page's reader and by Python's, CRCs checked."""
    files = [("means_l.webp", "x" * 1000), ("shN_labels.webp", "é" * 7), ("meta.json", "{}")]
    done = subprocess.run(
        ["node", "--input-type=module", "-e", ZIP_WRITER % {"player": PLAYER_DIR.as_posix()}],
        input=json.dumps(files),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    with zipfile.ZipFile(io.BytesIO(base64.b64decode(done.stdout))) as archive:
        assert archive.testzip() is None
        assert [(i.filename, archive.read(i).decode()) for i in archive.infolist()] == files
