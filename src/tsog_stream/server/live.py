"""Live scenes: the blocking reload of an index and the cache rules a CDN can follow.

``GET /v1/scenes/{id}/manifest?after=SEQ`` answers as soon as the scene's index has a
``live.sequence`` above SEQ (or has ended), waiting at most :func:`reload_wait_s`, then with
the current index, as LL-HLS's blocking playlist reload does (docs/http.md, "Live scenes").
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable

from ..errors import InputError
from ..schemas.manifest import Manifest
from .catalog import SceneEntry
from .respond import REVALIDATE

RELOAD_POLL_S = 0.05
"""How often a blocked reload looks at the index again (a stat, the parse cached)."""
MAX_RELOAD_WAIT_S = 10.0
"""The longest a blocked reload waits, whatever the window."""
MAX_SEQUENCE = 2**53
"""Largest ``after`` taken (a JSON-safe integer)."""


def after_sequence(raw: str | None) -> int | None:
    """The ``after`` query parameter: a publication number, or None when absent."""
    if raw is None:
        return None
    if not (raw.isascii() and raw.isdigit() and len(raw) <= 16 and int(raw) <= MAX_SEQUENCE):
        raise InputError(f"expected a publication number, got {raw[:40]!r}", where="after")
    return int(raw)


def reload_wait_s(manifest: Manifest) -> float:
    """How long a reload may wait for the next publication: three windows (a window is
    published about once a window), at most MAX_RELOAD_WAIT_S."""
    return min(3 * manifest.window_s, MAX_RELOAD_WAIT_S)


def is_waiting_on(scene: SceneEntry, after: int) -> bool:
    """The scene is live and has not yet published anything after ``after``."""
    live = scene.index.manifest.live
    return live is not None and not live.ended and live.sequence <= after


async def newer_than(
    scene: SceneEntry, after: int, reopen: Callable[[], Awaitable[SceneEntry]]
) -> SceneEntry:
    """``scene`` as soon as ``reopen`` gives a version published after ``after`` (or ended),
    else the version current when the wait is over."""
    deadline = time.monotonic() + reload_wait_s(scene.index.manifest)
    while is_waiting_on(scene, after) and time.monotonic() < deadline:
        await asyncio.sleep(RELOAD_POLL_S)
        scene = await reopen()
    return scene


def manifest_caching(scene: SceneEntry, after: int | None) -> str:
    """Cache-Control of a scene's index: a live one for at most half a window; the answer to
    a reload that found the publication asked for, for a window (its URL names it); a
    recorded or ended one revalidated as any file."""
    manifest = scene.index.manifest
    live = manifest.live
    if live is None or live.ended:
        return REVALIDATE
    if after is not None and live.sequence > after:
        return f"public, max-age={max(0, math.floor(manifest.window_s))}"
    if after is not None:
        return "no-cache"
    return f"public, max-age={math.floor(manifest.window_s / 2)}"
