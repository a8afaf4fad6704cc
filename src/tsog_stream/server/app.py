"""The aiohttp application: raw files with RFC 9110 byte ranges, and the streaming API.

Routes (see docs/http.md): ``GET|HEAD /files/{path}``, ``GET /v1/scenes``,
``GET /v1/scenes/{id}/manifest[?after=SEQ]``, ``GET /v1/scenes/{id}/chunks?t=&horizon=``,
``GET /v1/scenes/{id}/chunks/{n}.sog``, ``GET /v1/scenes/{id}/thumbnail``, ``GET /healthz``,
``GET /v1/authorize``, ``OPTIONS`` preflight anywhere, and the player's pages (:mod:`.player`).
Bodies go out through :mod:`.respond`; each request's privacy is decided once (:mod:`.private`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import math
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote

from aiohttp import HttpVersion10, HttpVersion11, web

from ..container.stream_index import MANIFEST
from ..errors import AccessError, InputError, TsogError
from ..io.objects import ObjectPath, is_object_url
from .catalog import BusyError, Catalog, NotFoundError
from .conditional import Outcome, evaluate, http_date
from .live import after_sequence, manifest_caching, newer_than
from .logs import log_out_of_fds, quiet_client_errors
from .object_catalog import ObjectCatalog
from .player import add_player_routes
from .private import (
    PRIVACY,
    AccessLog,
    Privacy,
    admitted,
    authorize,
    mark_private_responses,
    signed_suffix,
)
from .respond import CORS, IMMUTABLE, LIMITS, LOAD, REVALIDATE, Limits, Load, send_representation
from .scenes import CATALOG, find_scene, scene_list, thumbnail_rel

PREFLIGHT = {
    "Access-Control-Allow-Methods": "GET, HEAD, OPTIONS",
    "Access-Control-Allow-Headers": "Range, If-Match, If-None-Match, If-Range, "
    "If-Modified-Since, If-Unmodified-Since",
    "Access-Control-Max-Age": "86400",
}
HTTP_VERSIONS = (HttpVersion10, HttpVersion11)
HEALTHZ = "/healthz"
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _error(status: int, message: str, **extra: Any) -> web.Response:
    """A JSON error body ``{"error": {"status", "message", ...}}``."""
    body = {"error": {"status": status, "message": message, **extra}}
    return web.json_response(body, status=status, headers={"Cache-Control": "no-store"})


def _busy(message: str) -> web.Response:
    """503 with ``Retry-After: 1``: try again in a second."""
    resp = _error(503, message)
    resp.headers["Retry-After"] = "1"
    return resp


@web.middleware
async def _guard(request: web.Request, handler: Handler) -> web.StreamResponse:
    """HTTP version and method, OPTIONS preflight, the concurrency caps (in all, and per client
    address), then errors as JSON. ``/healthz`` passes every cap, so a monitor sees a busy
    server as alive."""
    if request.version not in HTTP_VERSIONS:
        resp = _error(505, "only HTTP/1.0 and HTTP/1.1 are served")
        resp.force_close()
        return resp
    if request.method == "OPTIONS":
        return web.Response(status=204, headers=PREFLIGHT)
    if request.method not in ("GET", "HEAD"):
        resp = _error(405, f"{request.method[:20]} is not served: only GET, HEAD and OPTIONS")
        resp.headers["Allow"] = "GET, HEAD, OPTIONS"
        return resp
    if request.path == HEALTHZ:
        return await handler(request)
    load, client = request.app[LOAD], request.remote or ""
    refusal = load.refuses(client, request.app[LIMITS])
    if refusal is not None:
        return _busy(refusal)
    load.enter(client)
    try:
        return await handler(request)
    except AccessError as exc:
        return _error(403, str(exc))
    except NotFoundError as exc:
        return _error(404, str(exc))
    except BusyError as exc:
        log_out_of_fds(str(exc))
        return _busy(str(exc))
    except InputError as exc:
        return _error(400, str(exc))
    except web.HTTPException as exc:
        if exc.status < 400:
            raise
        return _error(exc.status, exc.reason)
    finally:
        load.leave(client)


async def _add_cors(request: web.Request, response: web.StreamResponse) -> None:
    """CORS headers on every response."""
    response.headers.update(CORS)


async def files(request: web.Request) -> web.StreamResponse:
    """GET/HEAD /files/{path}: a raw file under the root (private ones need a signed URL); a
    live scene's ``manifest.json`` with ``?after=SEQ`` as the API's blocking reload."""
    catalog, rel = request.app[CATALOG], request.match_info["path"]
    found = await admitted(request, [rel], catalog.find(rel), lambda f: catalog.relative(f[0]))
    after = after_sequence(request.query.get("after"))
    scene_id = rel.removesuffix(f"/{MANIFEST}")
    if after is None or scene_id == rel:
        return await send_representation(request, await catalog.file_at(*found))
    try:
        scene = await catalog.scene(scene_id)
    except TsogError:  # not a scene's index: a file like any other
        return await send_representation(request, await catalog.file_at(*found))
    scene = await newer_than(scene, after, lambda: catalog.scene(scene_id))
    rep = await catalog.file_at(*await catalog.find(rel))
    return await send_representation(request, rep, manifest_caching(scene, after))


async def thumbnail(request: web.Request) -> web.StreamResponse:
    """GET/HEAD /v1/scenes/{id}/thumbnail: the PNG tsog segment drew beside the scene (404
    when there is none); admitted as the scene is."""
    scene = await find_scene(request, request.match_info["id"])
    catalog = request.app[CATALOG]
    return await send_representation(request, await catalog.file(thumbnail_rel(catalog, scene)))


async def scenes(request: web.Request) -> web.StreamResponse:
    """GET /v1/scenes: every readable public scene under the root (private ones are not listed)."""
    items = await scene_list(request)
    return web.json_response({"scenes": items}, headers={"Cache-Control": "no-cache"})


async def manifest(request: web.Request) -> web.StreamResponse:
    """GET /v1/scenes/{id}/manifest: the index JSON, ETag = the container identity; with
    ``?after=SEQ``, a live scene's next publication as soon as there is one (:mod:`.live`)."""
    after = after_sequence(request.query.get("after"))
    scene = await find_scene(request, request.match_info["id"])
    if after is not None:
        catalog = request.app[CATALOG]
        scene = await newer_than(scene, after, lambda: catalog.scene(scene.id))
    etag = f'"{scene.index.identity}"'
    caching = manifest_caching(scene, after)
    headers = {"ETag": etag, "Cache-Control": caching, "Last-Modified": http_date(scene.mtime)}
    outcome = evaluate(request.method, request.headers, etag, scene.mtime)
    if outcome is not Outcome.PROCEED:
        return web.Response(status=outcome.value, headers=headers)
    return web.Response(body=scene.manifest_json, content_type="application/json", headers=headers)


def _seconds(request: web.Request, name: str, default: float | None) -> float:
    """A finite float query parameter (InputError naming it otherwise)."""
    raw = request.query.get(name)
    if raw is None:
        if default is None:
            raise InputError(f"query parameter {name!r} is required (seconds)", where=name)
        return default
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or (name == "horizon" and value < 0):
        raise InputError(f"expected a finite number of seconds, got {raw[:40]!r}", where=name)
    return value


async def chunks(request: web.Request) -> web.StreamResponse:
    """GET /v1/scenes/{id}/chunks?t=T&horizon=H: the chunks [T, T+H] needs."""
    t, horizon = _seconds(request, "t", None), _seconds(request, "horizon", 0.0)
    scene = await find_scene(request, request.match_info["id"])
    base, suffix = f"/v1/scenes/{quote(scene.id)}/chunks", signed_suffix(request)
    fields = ("id", "offset", "length", "sha256", "start_s", "end_s")
    items = [
        {**{k: getattr(c, k) for k in fields}, "url": f"{base}/{c.id}.sog?v={c.sha256}{suffix}"}
        for c in scene.index.chunks_for_interval(t, t + horizon)
    ]
    body = {"scene": scene.id, "identity": scene.index.identity, "t": t, "horizon": horizon}
    return web.json_response({**body, "chunks": items}, headers={"Cache-Control": "no-cache"})


async def chunk(request: web.Request) -> web.StreamResponse:
    """GET/HEAD /v1/scenes/{id}/chunks/{n}.sog: one chunk, byte-exactly a standalone .sog.

    With ``?v=<sha256>`` (the form the chunk list gives) the URL names immutable content:
    it is cached for a year, and a stale ``v`` is 404.
    """
    scene = await find_scene(request, request.match_info["id"])
    rep = request.app[CATALOG].chunk(scene, int(request.match_info["n"]))
    version = request.query.get("v")
    if version is not None and f'"{version}"' != rep.etag:
        raise NotFoundError("chunk version gone; fetch the chunk list again", where=scene.id)
    return await send_representation(request, rep, IMMUTABLE if version else REVALIDATE)


async def healthz(request: web.Request) -> web.StreamResponse:
    """GET /healthz."""
    return web.json_response({"status": "ok"}, headers={"Cache-Control": "no-store"})


def _catalog(root: Path | str) -> Catalog:
    """The catalog of a folder or file, or of a store prefix or object (a storage URL)."""
    if is_object_url(root):
        store = ObjectPath.from_url(str(root))
        if not (store.is_dir() or store.is_file()):
            raise InputError("no such prefix or object in the store", where=str(root))
        return ObjectCatalog(store)
    path = Path(root)
    if not (path.is_dir() or path.is_file()):
        raise InputError("the server root must be a folder or a file", where=str(root))
    return Catalog(path)


def make_app(
    root: Path | str, *, limits: Limits | None = None, privacy: Privacy | None = None
) -> web.Application:
    """The application serving ``root``: a folder, or one file (only that file is served), or
    the same in object storage (``s3://bucket/media/``: bodies read with ranged GETs).

    ``privacy`` names the private paths and the URL secret (docs/http.md, "Private scenes").
    """
    app = web.Application(middlewares=[_guard])
    app[CATALOG] = _catalog(root)
    app[LIMITS] = limits or Limits()
    app[LOAD] = Load()
    app[PRIVACY] = privacy or Privacy()
    app.on_response_prepare.extend([_add_cors, mark_private_responses])
    r = app.router
    r.add_get(HEALTHZ, healthz)
    r.add_get("/files/{path:.+}", files)
    r.add_get("/v1/scenes", scenes)
    r.add_get("/v1/authorize", authorize)
    r.add_get("/v1/scenes/{id:.+}/manifest", manifest)
    r.add_get("/v1/scenes/{id:.+}/chunks", chunks)
    r.add_get("/v1/scenes/{id:.+}/thumbnail", thumbnail)
    r.add_get("/v1/scenes/{id:.+}/chunks/{n:[0-9]{1,9}}.sog", chunk)
    add_player_routes(app)
    return app


def cannot_listen(exc: OSError, host: str, port: int) -> InputError:
    """The one-line error for a port that cannot be bound."""
    if exc.errno == errno.EADDRINUSE:
        return InputError(f"port {port} is in use; try --port 0", where=host)
    return InputError(f"cannot listen: {exc.strerror}", where=f"{host}:{port}")


async def start_server(
    app: web.Application, host: str = "127.0.0.1", port: int = 0, *, reuse_port: bool = False
) -> tuple[web.AppRunner, int]:
    """Start ``app`` on host:port (0 = any free port); returns the runner and the port.
    ``reuse_port``: share the port with other processes (SO_REUSEPORT, server/workers.py)."""
    limits = app[LIMITS]
    quiet_client_errors()
    runner = web.AppRunner(
        app,
        keepalive_timeout=limits.keepalive_s,
        access_log_class=AccessLog,
        shutdown_timeout=limits.shutdown_timeout_s,
    )
    await runner.setup()
    try:
        await web.TCPSite(runner, host, port, reuse_port=reuse_port or None).start()
    except OSError as exc:
        await runner.cleanup()
        raise cannot_listen(exc, host, port) from exc
    return runner, int(runner.addresses[0][1])


def run_server(
    root: Path | str,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    limits: Limits | None = None,
    privacy: Privacy | None = None,
) -> None:
    """Blocking: serve ``root`` until interrupted (one process; server/workers.py for more)."""

    async def serve() -> None:
        app = make_app(root, limits=limits, privacy=privacy)
        runner, bound = await start_server(app, host, port)
        print(f"serving {root} on http://{host}:{bound}/ (web player: /play/)", flush=True)
        try:
            await asyncio.Event().wait()
        finally:
            await runner.cleanup()

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(serve())


__all__ = ["Limits", "Privacy", "make_app", "run_server", "send_representation", "start_server"]
