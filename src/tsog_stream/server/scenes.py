"""Scene lookup shared by the API and the player pages: one scene by id, admitted only as
its privacy allows, and the list of public scenes."""

from __future__ import annotations

import asyncio

from aiohttp import web

from ..errors import InputError, TsogError
from .catalog import CONTAINER_SUFFIX, Catalog, NotFoundError, SceneEntry
from .private import PRIVACY

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
    return scene


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
