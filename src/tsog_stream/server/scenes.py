"""Scene lookup shared by the API and the player pages: one scene by id, admitted only as
its privacy allows, and the list of public scenes.

A signed prefix scope under ``/v1/scenes/`` names exactly what it covers: the scene whose id it
spells (the player's ``/v1/scenes/paid/show/`` opens ``paid/show`` and not a scene
``paid/show/bonus`` below it), or every scene below a folder that is not itself a scene.
"""

from __future__ import annotations

import asyncio

from aiohttp import web

from ..errors import AccessError, InputError, TsogError
from ..signing import SCOPE, decoded_path
from .catalog import CONTAINER_SUFFIX, Catalog, NotFoundError, SceneEntry
from .private import PRIVACY, is_signed

SCENES_API = "/v1/scenes/"

CATALOG = web.AppKey("catalog", Catalog)


async def find_scene(request: web.Request, scene_id: str) -> SceneEntry:
    """The scene ``scene_id`` (private ones need a signed URL); a malformed id is not found."""
    catalog, privacy = request.app[CATALOG], request.app[PRIVACY]
    privacy.admit(request, [scene_id + CONTAINER_SUFFIX, scene_id])
    try:
        scene = await catalog.scene(scene_id)
    except InputError as exc:
        raise NotFoundError("no such scene", where=scene_id[:80]) from exc
    privacy.admit(request, [catalog.scene_relative(scene)])
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


async def public_scenes(request: web.Request) -> list[SceneEntry]:
    """Every readable scene under the root that is not private (unreadable ones are left out)."""
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
    return found
