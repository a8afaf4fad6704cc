"""The web player routes: an index of scenes, a player page per scene and its static files.

``GET /play/`` lists the public scenes, ``GET /play/{scene}`` is the player page (its module
reads the scene through the ``/v1`` API), ``GET /player/{file}`` serves the ES modules and CSS
of the ``player/`` folder next to this module (only files directly in it, by exact name) and
``GET /player/engine/playcanvas.mjs`` the PlayCanvas engine built file from npm (docs/http.md).
"""

from __future__ import annotations

import asyncio
import hashlib
import html
import json
import os
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote, urlencode, urlsplit

from aiohttp import web

from ..errors import InputError
from ..signing import EXPIRES, signing_params
from .catalog import NotFoundError, Representation
from .private import PRIVACY, is_signed
from .respond import send_representation
from .scenes import find_scene, scene_list

PLAYER_DIR = Path(__file__).with_name("player")
ENGINE_ENV = "TSOG_PLAYCANVAS_DIR"
ENGINE_FILE = "playcanvas.mjs"
PACKAGED_ENGINE = PLAYER_DIR / "engine" / ENGINE_FILE
"""The pinned engine build the package carries (player/engine/README.md)."""
ASSET_TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".css": "text/css"}
HTML_TYPE = "text/html"
PAGE_HEADERS = {"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"}
TEMPLATE = "index.html"
INSTALL_HINT = (
    f"the PlayCanvas engine is not where {ENGINE_ENV} says: point it at the folder holding "
    f"{ENGINE_FILE} (or its build/ folder), or unset it to use the engine the package carries"
)
ETAGS = web.AppKey("player_etags", dict)


def engine_path() -> Path | None:
    """The engine's ``playcanvas.mjs``: from $TSOG_PLAYCANVAS_DIR (another build), else the
    one the package carries."""
    custom = os.environ.get(ENGINE_ENV)
    found = [Path(custom), Path(custom) / "build"] if custom else [PACKAGED_ENGINE.parent]
    return next((p / ENGINE_FILE for p in found if (p / ENGINE_FILE).is_file()), None)


def asset_path(name: str) -> Path:
    """A static file directly in the player folder, by exact name; NotFoundError otherwise."""
    path = PLAYER_DIR / name
    listed = Path(name).suffix in ASSET_TYPES and name in os.listdir(PLAYER_DIR)
    if not listed or path.is_symlink() or not path.is_file():
        raise NotFoundError("no such player file", where=name[:80])
    return path


async def _send(request: web.Request, path: Path) -> web.StreamResponse:
    """Send a static file with validators, 304 and ranges, its ETag the SHA-256 of its content
    (computed once per size, mtime and inode)."""
    st = await asyncio.to_thread(path.stat)
    version = (st.st_size, st.st_mtime_ns, st.st_ino)
    cache: dict[Path, tuple[tuple[int, int, int], str]] = request.app[ETAGS]
    if path not in cache or cache[path][0] != version:
        cache[path] = (version, await asyncio.to_thread(_etag, path))
    kind = ASSET_TYPES[path.suffix]
    rep = Representation(path, 0, st.st_size, cache[path][1], st.st_mtime_ns / 1e9, kind)
    return await send_representation(request, rep)


def _etag(path: Path) -> str:
    """The SHA-256 of a file's content as a strong ETag."""
    with open(path, "rb") as f:
        return f'"{hashlib.file_digest(f, "sha256").hexdigest()}"'


async def player_file(request: web.Request) -> web.StreamResponse:
    """GET /player/{file}: one ES module or stylesheet of the player."""
    return await _send(request, asset_path(request.match_info["file"]))


async def engine(request: web.Request) -> web.StreamResponse:
    """GET /player/engine/playcanvas.mjs: the engine's ES module build from npm."""
    path = await asyncio.to_thread(engine_path)
    if path is None:
        raise NotFoundError(INSTALL_HINT, where=ENGINE_FILE)
    return await _send(request, path)


def _page(title: str, body: str) -> web.Response:
    """An HTML response that every cache must revalidate."""
    doc = (
        '<!doctype html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n"
        '<link rel="icon" href="data:,">\n<link rel="stylesheet" href="/player/style.css">\n'
        "</head>\n"
        f"<body>\n{body}</body>\n</html>\n"
    )
    return web.Response(text=doc, content_type=HTML_TYPE, headers=PAGE_HEADERS)


async def index(request: web.Request) -> web.StreamResponse:
    """GET /play/: links to the player of every public scene; ``?manifest=URL`` plays a stream
    from any origin (an unpacked layout on a static server, CORS permitting)."""
    url = request.query.get("manifest")
    if url is not None:
        return await _player_page("stream", {"scene": None, "manifest": _manifest_url(url)})
    items = "".join(_scene_item(item) for item in await scene_list(request))
    listing = f'<ul class="scenes">\n{items}</ul>\n' if items else "<p>No scenes here.</p>\n"
    form = (
        '<form class="open" action="/play/" method="get">\n'
        "<label>Or play a manifest URL (an unpacked stream on any static origin)\n"
        '<input type="url" name="manifest" required '
        'placeholder="https://cdn.example.com/clip/manifest.json"></label>\n'
        '<button type="submit">play</button>\n</form>\n'
    )
    body = f'<main class="index">\n<h1>Scenes</h1>\n{listing}{form}</main>\n'
    return _page("tsog-stream scenes", body)


def _scene_item(item: dict[str, Any]) -> str:
    """One scene of the index: its thumbnail (when tsog segment drew one), name, duration
    ("still" for one moment, marked when assumed), the Gaussians one frame shows, and size."""
    picture = (
        f'<img src="{html.escape(item["thumbnail"])}" alt="" loading="lazy">'
        if item["thumbnail"]
        else '<span class="no-thumbnail"></span>'
    )
    assumed = " (assumed)" if item["duration_assumed"] else ""
    duration = "still" if item["static"] else f"{item['duration_s']:.2f} s{assumed}"
    most = item["gaussians_per_frame"]
    shown = f"{most:,} Gaussians" + (" per frame" if most < item["gaussians"] else "")
    facts = f"{duration} &middot; {shown} &middot; {item['bytes'] / 1e6:.1f} MB"
    return (
        f'<li><a href="/play/{quote(item["id"])}">{picture}'
        f'<span class="name">{html.escape(item["id"])}</span>'
        f'<span class="facts">{facts}</span></a></li>\n'
    )


def _manifest_url(url: str) -> str:
    """A manifest URL the page may fetch: absolute http(s) or a path on this server."""
    parts = urlsplit(url)
    relative = not parts.scheme and not parts.netloc and url.startswith("/")
    if not (relative or (parts.scheme in ("http", "https") and parts.netloc)) or len(url) > 2048:
        raise InputError("expected an http(s) URL of a manifest.json", where="manifest")
    return url


async def _player_page(title: str, config: dict[str, Any]) -> web.Response:
    """The player page with its configuration written in (as JSON with no '<', '>' or '&'
    left raw, so it cannot end its <script> element)."""
    template = await asyncio.to_thread((PLAYER_DIR / TEMPLATE).read_text, "utf-8")
    safe: dict[str, str | int | None] = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026"}
    text = json.dumps(config).translate(str.maketrans(safe))
    page = template.replace("{{TITLE}}", html.escape(title)).replace("{{CONFIG}}", text)
    return web.Response(text=page, content_type=HTML_TYPE, headers=PAGE_HEADERS)


def _scene_query(request: web.Request, api: str) -> str:
    """For a page admitted by its signed URL: a signature over the scene's /v1 API with the
    same expiry, so the page can fetch the manifest and chunks ('' for a public scene)."""
    if not is_signed(request):
        return ""
    secret = request.app[PRIVACY].secret or b""  # set whenever a request was admitted signed
    expires = int(request.query[EXPIRES])
    return urlencode(signing_params(secret, unquote(api) + "/", expires), safe="/")


async def play(request: web.Request) -> web.StreamResponse:
    """GET /play/{scene}: the player page of one scene (404 for an unknown scene)."""
    scene = await find_scene(request, request.match_info["id"])
    api = f"/v1/scenes/{quote(scene.id)}"
    config = {"scene": scene.id, "manifest": f"{api}/manifest", "chunks": f"{api}/chunks/"}
    if query := _scene_query(request, api):
        config["query"] = query
    return await _player_page(scene.id, config)


async def to_index(request: web.Request) -> web.StreamResponse:
    """GET / and GET /play: redirect to the index page of scenes."""
    raise web.HTTPFound("/play/")


def add_player_routes(app: web.Application) -> None:
    """Register the player routes on ``app`` (made by :func:`~.app.make_app`)."""
    app[ETAGS] = {}
    r = app.router
    r.add_get("/", to_index)
    r.add_get("/play", to_index)
    r.add_get("/play/", index)
    r.add_get("/play/{id:.+}", play)
    r.add_get("/player/engine/" + ENGINE_FILE, engine)
    r.add_get("/player/{file}", player_file)


__all__ = ["add_player_routes", "engine_path"]
