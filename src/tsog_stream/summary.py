"""Human-oriented summaries of scenes and chunks (what ``tsog info`` prints)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from .codec.chunk import checked_images, read_meta
from .constants import META_JSON, TEMPORAL_CHANNELS
from .model import Scene, Timeline, TimelineType
from .schemas import listed_files
from .schemas.cameras import Camera
from .temporal import time_range

_GROUPS = {
    "means": "means",
    "quats": "quats",
    "scales": "scales",
    "sh0": "sh0+opacity",
    "shN": "shN",
    "timeline": "timeline",
}


def _group_of(field: str) -> str:
    """Attribute group of a meta field path such as ``temporal.means.files[0]``."""
    head = field.split(".", maxsplit=1)[0]
    if head == "temporal":
        return "temporal." + field.split(".")[1]
    return _GROUPS.get(head.split("[")[0], head)


def chunk_summary(files: Mapping[str, bytes], *, where: str) -> dict[str, Any]:
    """Count, SH bands, timeline, image sizes and bytes per attribute of a chunk's files
    (image sizes read from their headers and checked as a decode checks them, no pixel
    decoded)."""
    meta = read_meta(files, where=where)
    _, sizes = checked_images(meta, files, where=where)
    images: dict[str, list[int]] = {}
    groups: dict[str, int] = {"meta.json": len(files[META_JSON])}
    for field, name in listed_files(meta):
        data = files[name]
        images[name] = list(sizes[name])
        group = _group_of(field)
        groups[group] = groups.get(group, 0) + len(data)
    out: dict[str, Any] = {
        "count": meta.count,
        "sh_bands": meta.shN.bands if meta.shN is not None else 0,
        "bytes": sum(len(b) for b in files.values()),
        "bytes_per_attribute": groups,
        "images": images,
    }
    if meta.timeline is not None:
        out["timeline"] = {
            "type": int(meta.timeline.type),
            "type_name": TimelineType(int(meta.timeline.type)).name.lower(),
            "fps": meta.timeline.fps,
            "scene_length": meta.timeline.scene_length,
        }
        out["temporal"] = {a: len(e.mins) for a, e in (meta.temporal or {}).items()}
    return out


def duration_text(
    start_s: float, end_s: float, *, static: bool, assumed: bool = False, flag: str = "--duration-s"
) -> str:
    """A scene's length as ``tsog`` shows it: '2.50 s', '1.00 s (assumed: pass --duration-s)'
    when its reader assumed it (``flag``: the option that sets it for the input's kind, such
    as --scene-length-s for FreeTimeGS), or 'static (one moment)'."""
    if static:
        return "static (one moment)"
    text = f"{end_s - start_s:.2f} s"
    return f"{text} (assumed: pass {flag})" if assumed else text


def scene_summary(
    scene: Scene, *, duration_assumed: bool = False, flag: str = "--duration-s"
) -> dict[str, Any]:
    """Count, SH bands, duration (``duration_assumed``: its reader assumed it; ``flag`` sets
    it), timeline type, time range and temporal orders of an in-memory scene."""
    out: dict[str, Any] = {"count": len(scene), "sh_bands": scene.gaussians.sh_bands}
    if scene.timeline is not None:
        first, last = time_range(scene.timeline)
        out["duration"] = duration_text(
            first, last, static=False, assumed=duration_assumed, flag=flag
        )
        out["timeline"] = timeline_summary(scene.timeline)
        out["temporal"] = {
            a: int(c.shape[1]) for a, c in scene.temporal.items() if a in TEMPORAL_CHANNELS
        }
    return out


def timeline_summary(timeline: Timeline) -> dict[str, Any]:
    """Type, frame rate and the time range in which a timeline's Gaussians are visible."""
    first, last = time_range(timeline)
    return {
        "type": int(timeline.type),
        "type_name": timeline.type.name.lower(),
        "fps": timeline.fps,
        "time_range_s": [round(first, 6), round(last, 6)],
    }


def cameras_summary(
    cameras: Sequence[Camera], source: str = "", view: Camera | None = None
) -> dict[str, Any]:
    """How many capture cameras, from where, and the view a player opens on."""
    out: dict[str, Any] = {"count": len(cameras)}
    if source:
        out["from"] = source
    if cameras:
        first = cameras[0]
        out["first"] = f"{first.name or '(unnamed)'}, {first.width}x{first.height}"
    if view is not None:
        x, y, z = view.position
        label = "capture camera " + (view.name or "0") if view in cameras else view.name
        out["opens_from"] = f"{label} at ({x:.3g}, {y:.3g}, {z:.3g})"
    return out
