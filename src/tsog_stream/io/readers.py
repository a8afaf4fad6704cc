"""Input detection and loading: any supported file becomes a :class:`~tsog_stream.model.Scene`.

Formats are recognised by content (magic bytes, PLY header properties, zip members), not by
extension; ``format=`` overrides detection. Every reader's warnings come back as ``notes``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Final, Literal

from ..codec.bundle import is_zip
from ..constants import is_container
from ..errors import InputError, UnsupportedError
from ..model import Scene
from ..schemas.cameras import Camera
from .cameras import cameras_for_input
from .chunks import is_unbundled, read_chunk
from .compressed_ply import is_compressed_ply
from .files import open_regular, read_bytes, read_head
from .foreign import foreign_format, foreign_npz
from .fourdgs import parse_4dgs, sniff_4dgs
from .freetimegs import (
    is_freetimegs_npz,
    is_freetimegs_ply,
    parse_freetimegs_npz,
    parse_freetimegs_ply,
    zip_members,
)
from .loaded import Loaded4D
from .objects import Location, as_location
from .ply import parse_ply, sniff_ply
from .ply_header import parse_header
from .sequence import DEFAULT_FPS, detect_sequence, read_ply_sequence, read_sog_sequence
from .splatv import parse_splatv, sniff_splatv

FORMATS: tuple[str, ...] = ("ply", "compressed-ply", "sog", "ply-sequence", "sog-sequence")
FORMATS += ("freetimegs-ply", "freetimegs-npz", "splatv", "4dgs")
"""Input formats this version reads (``--format`` values)."""
STREAMS = ("tsogs", "tsogs-dir")
"""Segmented streams (a container file or its unpacked folder); detected, not loaded whole."""
HEAD_BYTES = 64 * 1024
Progress = Callable[[str], None]


@dataclass(frozen=True)
class ReadOptions:
    """Per-format reading options; each applies only to the formats named."""

    fps: float | None = None
    """Frame rate of PLY/SOG sequences (default DEFAULT_FPS)."""
    duration_s: float | None = None
    """Seconds spanned by a .splatv clip's normalised time (default 1 s)."""
    scene_length_s: float | None = None
    """Seconds spanned by a FreeTimeGS scene's normalised time (default 1 s)."""
    duration_mode: Literal["log", "linear"] = "log"
    """How a FreeTimeGS PLY stores durations."""


@dataclass(frozen=True)
class LoadedScene:
    """A scene with the format it was read as and any warnings the reader had."""

    scene: Scene
    format: str
    notes: list[str] = field(default_factory=list)
    cameras: list[Camera] = field(default_factory=list)
    """Capture cameras: given with ``cameras=``, carried by the file, or found beside it."""
    cameras_source: str = ""
    """Where the cameras were read ("" without cameras)."""
    duration_assumed: bool = False
    """The scene's length was assumed, not read (a ``.splatv`` or FreeTimeGS input read without
    its length: 1 s, :func:`length_flag` sets it); a container made of it says so
    (``SceneInfo.duration_assumed``)."""


def _detect_file(p: Location) -> str:
    """Format of a single file, from its first bytes (and its zip members)."""
    head = read_head(p, HEAD_BYTES)
    if is_container(head):
        return "tsogs"
    if sniff_splatv(head):
        return "splatv"
    if sniff_4dgs(head):
        return "4dgs"
    if is_zip(head):
        return _zip_format(p)
    if sniff_ply(head):
        header = parse_header(head, name=str(p))
        if is_compressed_ply(header):
            return "compressed-ply"
        return "freetimegs-ply" if is_freetimegs_ply(header) else "ply"
    raise UnsupportedError(
        foreign_format(head, str(p))
        or "not a PLY, SOG/TSOG, .splatv, .4dgs or FreeTimeGS file (unknown magic bytes)",
        where=str(p),
    )


def _zip_format(p: Location) -> str:
    """A zip's format from its member names (its directory only is read, not the whole file):
    a FreeTimeGS checkpoint, another NumPy .npz (refused by name), else a SOG bundle."""
    with open_regular(p) as file:
        members = zip_members(file) or set()
    if is_freetimegs_npz(members):
        return "freetimegs-npz"
    foreign = foreign_npz(members)
    if foreign is not None:
        raise UnsupportedError(foreign, where=str(p))
    return "sog"


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format name of the file, folder or glob pattern at ``path``, from its content."""
    if any(c in str(path) for c in "*?["):  # a glob pattern of frames
        kind = detect_sequence(str(path))
        if kind is None:
            raise InputError("the pattern matches no numbered frames", where=str(path))
        return kind
    p = as_location(path)
    if not p.exists():
        raise InputError("no such file or folder", where=str(p))
    if is_unbundled(p):
        return "sog"
    if (p / "manifest.json").is_file():
        return "tsogs-dir"
    if p.is_dir():
        kind = detect_sequence(str(p))
        if kind is None:
            raise UnsupportedError(
                "a folder must hold meta.json (SOG) or numbered PLY/SOG frames", where=str(p)
            )
        return kind
    return _detect_file(p)


def _read_4d(kind: str, path: str, options: ReadOptions, progress: Progress | None) -> Loaded4D:
    """Dispatch the 4D readers."""
    fps = options.fps if options.fps is not None else DEFAULT_FPS
    if kind == "ply-sequence":
        return read_ply_sequence(path, fps=fps, progress=progress)
    if kind == "sog-sequence":
        return read_sog_sequence(path, fps=fps, progress=progress)
    if kind == "freetimegs-npz":  # read member by member from the file, never whole
        with open_regular(path) as file:
            return parse_freetimegs_npz(file, name=path, scene_length_s=options.scene_length_s)
    data = read_bytes(path)
    if kind == "splatv":
        return parse_splatv(data, name=path, duration_s=options.duration_s)
    if kind == "freetimegs-ply":
        return parse_freetimegs_ply(
            data, name=path, scene_length_s=options.scene_length_s, duration=options.duration_mode
        )
    return parse_4dgs(data, name=path)


APPLIES: Final = {
    "fps": ("ply-sequence", "sog-sequence"),
    "duration_s": ("splatv",),
    "scene_length_s": ("freetimegs-ply", "freetimegs-npz"),
}
"""Each per-format read option and the input kinds it applies to."""


def length_flag(kind: str) -> str:
    """The command-line option that sets the length of an input of ``kind`` when its file does
    not say it (what a "(assumed: pass ...)" hint names)."""
    return "--scene-length-s" if kind in APPLIES["scene_length_s"] else "--duration-s"


def _check_options(kind: str, options: ReadOptions) -> None:
    """Refuse options that do not apply to the input, rather than ignore them silently."""
    for option, kinds in APPLIES.items():
        if getattr(options, option) is not None and kind not in kinds:
            flag = "--" + option.replace("_", "-")
            raise InputError(
                f"applies to {', '.join(kinds)} inputs; this input is {kind}", where=flag
            )


def load_scene(
    path: str | os.PathLike[str],
    *,
    format: str | None = None,
    options: ReadOptions | None = None,
    progress: Progress | None = None,
    cameras: str | os.PathLike[str] | None = None,
) -> LoadedScene:
    """Read any supported input as a Scene (static inputs have no timeline), with its capture
    cameras: ``cameras`` (a cameras.json or COLMAP model), else the file's own, else any found
    beside it (io/cameras.py)."""
    loaded = _load(path, format, options or ReadOptions(), progress)
    found = cameras_for_input(path, explicit=cameras, own=loaded.cameras)
    if found is None:
        return loaded
    return replace(
        loaded,
        notes=loaded.notes + found.notes,
        cameras=found.cameras,
        cameras_source=found.source if found.cameras else "",
    )


def _load(
    path: str | os.PathLike[str],
    format: str | None,
    options: ReadOptions,
    progress: Progress | None,
) -> LoadedScene:
    """The scene and notes of any input, with the cameras the file itself carries."""
    kind = format or detect_format(path)
    if kind in STREAMS:
        raise InputError(
            "is a segmented stream: use tsog frame/extract/unpack on it", where=str(path)
        )
    if kind not in FORMATS:
        raise InputError(f"unknown format {kind!r}; known: {', '.join(FORMATS)}", where="--format")
    _check_options(kind, options)
    if kind == "sog":
        return LoadedScene(read_chunk(path), kind)
    if kind in ("ply", "compressed-ply"):
        contents = parse_ply(read_bytes(path), name=str(path))  # the header tells which kind
        return LoadedScene(Scene(contents.gaussians), kind, list(contents.notes))
    loaded = _read_4d(kind, str(path), options, progress)
    return LoadedScene(
        loaded.scene,
        kind,
        list(loaded.notes),
        list(loaded.cameras),
        duration_assumed=loaded.duration_assumed,
    )
