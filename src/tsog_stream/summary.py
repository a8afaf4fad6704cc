"""Human-oriented summaries of scenes and chunks (what ``tsog info`` prints)."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any

from PIL import Image

from .codec.chunk import read_meta
from .constants import META_JSON, TEMPORAL_CHANNELS
from .errors import SogError
from .model import Scene, TimelineType
from .schemas import listed_files
from .schemas.cameras import CaptureCamera
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


def _image_size(data: bytes, where: str) -> tuple[int, int]:
    """(width, height) read from a WebP header without decoding pixels."""
    try:
        with Image.open(io.BytesIO(data), formats=["WEBP"]) as img:
            return int(img.size[0]), int(img.size[1])
    except (OSError, ValueError) as exc:
        raise SogError(f"corrupt WebP image: {exc}", where=where) from exc


def chunk_summary(files: Mapping[str, bytes], *, where: str) -> dict[str, Any]:
    """Count, SH bands, timeline, image sizes and bytes per attribute of a chunk's files."""
    meta = read_meta(files, where=where)
    images: dict[str, list[int]] = {}
    groups: dict[str, int] = {"meta.json": len(files[META_JSON])}
    for field, name in listed_files(meta):
        data = files.get(name)
        if data is None:
            raise SogError(f"file {name!r} listed in {field} is missing", where=where)
        images[name] = list(_image_size(data, f"{where}/{name}"))
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


def scene_summary(scene: Scene) -> dict[str, Any]:
    """Count, SH bands, timeline type, time range and temporal orders of an in-memory scene."""
    out: dict[str, Any] = {"count": len(scene), "sh_bands": scene.gaussians.sh_bands}
    if scene.timeline is not None:
        first, last = time_range(scene.timeline)
        out["timeline"] = {
            "type": int(scene.timeline.type),
            "type_name": scene.timeline.type.name.lower(),
            "fps": scene.timeline.fps,
            "time_range_s": [round(first, 6), round(last, 6)],
        }
        out["temporal"] = {
            a: int(c.shape[1]) for a, c in scene.temporal.items() if a in TEMPORAL_CHANNELS
        }
    return out


def cameras_summary(
    cameras: Sequence[CaptureCamera], source: str = "", view: CaptureCamera | None = None
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
