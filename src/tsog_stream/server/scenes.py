"""Scene lookup shared by the API and the player pages: one scene by id, admitted as its
privacy allows, and the list of public scenes.

A signed prefix scope under ``/v1/scenes/`` names exactly what it covers: the scene whose id it
spells (the player's ``/v1/scenes/paid/show/`` opens ``paid/show`` and not a scene
``paid/show/bonus`` below it), or every scene below a folder that is not itself a scene.
"""

from __future__ import annotations

import asyncio
from typing import Any
from urllib.parse import quote

from aiohttp import web

from ..constants import thumbnail_path
from ..container.stream_index import MANIFEST
from ..errors import AccessError, InputError, TsogError
from ..signing import SCOPE, decoded_path
from .catalog import CONTAINER_SUFFIX, Catalog, NotFoundError, SceneEntry
from .private import PRIVACY, admitted, is_signed

SCENES_API = "/v1/scenes/"
CATALOG = web.AppKey("catalog", Catalog)


async def find_scene(request: web.Request, scene_id: str) -> SceneEntry:
    """The scene ``scene_id``, admitted as its privacy allows (:func:`.private.admitted`: the id
    as asked and the file it resolves to); a malformed id is not found."""
    catalog = request.app[CATALOG]
    asked = [scene_id + CONTAINER_SUFFIX, scene_id]
    try:
        found = await admitted(request, asked, catalog.scene_file(scene_id), catalog.scene_relative)
    except InputError as exc:
        raise NotFoundError("no such scene", where=scene_id[:80]) from exc
    scene = await catalog.scene(scene_id, found)
    if is_signed(request):
        await _check_scene_scope(request, catalog, scene_id)
    return scene


async def _check_scene_scope(request: web.Request, catalog: Catalog, scene_id: str) -> None:
    """Refuse a signed scope that names another scene, one above the scene asked for."""
    scope = decoded_path(request.query.get(SCOPE, ""))
    if not (scope.startswith(SCENES_API) and scope.endswith("/")):
        return
    named = scope[len(SCENES_API) : -1]
    if named in ("", scene_id):
        return
    try:
        await catalog.scene(named)
    except TsogError:
        return  # a folder of scenes, not a scene: it covers every scene below it
    raise AccessError(f"the signed URL covers the scene {named[:80]} only", where=scene_id[:80])


def thumbnail_rel(catalog: Catalog, scene: SceneEntry) -> str:
    """The root-relative name of a scene's thumbnail (beside its container or manifest)."""
    rel = catalog.scene_relative(scene)
    return thumbnail_path(rel if scene.packed else f"{rel}/{MANIFEST}")


def _scene_json(scene: SceneEntry, has_thumbnail: bool = False) -> dict[str, Any]:
    """One item of the scene list (docs/http.md): ``gaussians`` counts every Gaussian of the
    source, ``gaussians_per_frame`` the most shown at one time."""
    q = quote(scene.id)
    info = scene.index.manifest.scene
    return {
        "id": scene.id,
        "url": f"/files/{q}.tsogs" if scene.packed else f"/files/{q}/manifest.json",
        "manifest": f"/v1/scenes/{q}/manifest",
        "packed": scene.packed,
        "bytes": scene.size,
        "identity": scene.index.identity,
        "start_s": info.start_s,
        "end_s": info.end_s,
        "duration_s": info.end_s - info.start_s,
        "duration_assumed": info.duration_assumed,
        "static": info.timeline_type is None,
        "chunks": len(scene.index.manifest.chunks),
        "gaussians": info.gaussians,
        "gaussians_per_frame": scene.gaussians_per_frame,
        "cameras": len(scene.index.manifest.cameras),
        "thumbnail": f"/v1/scenes/{q}/thumbnail" if has_thumbnail else None,
    }


async def scene_list(request: web.Request) -> list[dict[str, Any]]:
    """Every readable scene under the root that is not private (unreadable ones left out), as
    the API and the player's index list them."""
    catalog, privacy = request.app[CATALOG], request.app[PRIVACY]
    found = []
    for scene_id in await asyncio.to_thread(catalog.scene_ids):  # a walk: off the loop
        try:
            scene = await catalog.scene(scene_id)
        except TsogError:
            continue
        rels = [scene_id + CONTAINER_SUFFIX, scene_id, catalog.scene_relative(scene)]
        if not any(privacy.is_private(r) for r in rels):
            found.append(scene)
    thumbs = [thumbnail_rel(catalog, s) for s in found]
    present = await asyncio.to_thread(lambda: [catalog.has_file(rel) for rel in thumbs])
    return [_scene_json(s, has) for s, has in zip(found, present, strict=True)]
