"""Frame sequences: numbered per-frame PLY or SOG files -> one type-0 (frame id) Scene.

A folder or glob pattern of files whose names carry a frame number, in natural order (frame id
= position: gaps noted, not kept), each told PLY or SOG by its magic bytes; mixed SH degrees are
padded to the highest. Headers are read first, so the output is allocated once and filled frame
by frame (peak: the result plus one frame). Decisions: docs/inputs.md, "Frame sequences"."""

from __future__ import annotations

import glob
import os
import re
import zipfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Final

import numpy as np

from ..codec.bundle import is_zip
from ..codec.chunk import read_meta
from ..constants import META_JSON, SH_BANDS_BY_COEFFS, SH_COEFFS_BY_BANDS
from ..errors import InputError, IntegrityError, SogError, SourceError, UnsupportedError
from ..model import Gaussians, Scene, Timeline, TimelineType
from .chunks import read_chunk
from .compressed_ply import is_compressed_ply
from .files import open_regular, read_bytes, read_head
from .loaded import Loaded4D
from .objects import Location, as_location, glob_objects, is_object_url
from .ply import read_ply, sniff_ply
from .ply_header import MAX_HEADER_BYTES, parse_header

DEFAULT_FPS: Final = 30.0
"""Frame rate assumed when the caller gives none (PLY and SOG files carry no frame rate)."""
PLY_SEQUENCE: Final = "ply-sequence"
SOG_SEQUENCE: Final = "sog-sequence"

Progress = Callable[[str], None]
Source = str | os.PathLike[str]

_DIGITS = re.compile(r"(\d+)")
_GLOB_MAGIC = re.compile(r"[*?[]")
_SNIFF_BYTES = 8


def natural_key(name: str) -> tuple[tuple[object, ...], str]:
    """Sort key comparing digit runs as numbers: ``frame_2`` < ``frame_10``."""
    parts = _DIGITS.split(name.lower())
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)), name


def frame_number(path: Location) -> int | None:
    """The last number in a frame's name (extension excluded), or None when it has none."""
    stem = path.name if path.is_dir() else path.stem
    numbers = _DIGITS.findall(stem)
    return int(numbers[-1]) if numbers else None


def sniff_frame(path: Location) -> str | None:
    """ "ply" or "sog" from a file's magic bytes (or a folder's meta.json), else None."""
    if path.is_dir():
        return "sog" if (path / META_JSON).is_file() else None
    head = read_head(path, _SNIFF_BYTES)
    if sniff_ply(head):
        return "ply"
    return "sog" if is_zip(head) else None


@dataclass(frozen=True)
class _Frames:
    """A scanned sequence: frame paths in order, their numbers, kind and the files skipped."""

    paths: list[Location]
    numbers: list[int]
    kind: str
    ignored: list[Location]


def _is_glob(source: Source) -> bool:
    """True for a string with glob wildcards that is not itself an existing path."""
    if not isinstance(source, str) or not _GLOB_MAGIC.search(source):
        return False
    return is_object_url(source) or not Path(source).exists()


def _glob(pattern: str) -> list[Location]:
    """The entries matching a glob pattern, local or in a store."""
    if is_object_url(pattern):
        return list(glob_objects(pattern))
    return [Path(m) for m in glob.glob(pattern)]


def _folder_entries(text: str) -> list[Location]:
    """The visible entries of a folder (or store prefix) of frames."""
    p = as_location(text)
    if p.is_dir():
        if (p / META_JSON).is_file():
            raise InputError("is one unbundled SOG chunk, not a sequence of frames", where=text)
        try:
            return [e for e in p.iterdir() if not e.name.startswith(".")]
        except OSError as exc:
            raise SourceError(f"cannot list: {exc.strerror or exc}", where=text) from exc
    if p.exists():
        raise InputError("expected a folder of numbered frames or a glob pattern", where=text)
    raise InputError("no such folder (and not a glob pattern)", where=text)


def _candidates(source: Source) -> list[Location]:
    """Entries with a number in their name, from a folder or a glob pattern, naturally sorted."""
    text = os.fspath(source)
    entries = _glob(text) if _is_glob(source) else _folder_entries(text)
    numbered = [e for e in entries if frame_number(e) is not None]
    return sorted(numbered, key=lambda e: natural_key(e.name))


def _scan(source: Source) -> _Frames:
    """Find the frames of ``source``; refuse an empty, mixed or ambiguous sequence."""
    where = os.fspath(source)
    frames: dict[str, list[Location]] = {"ply": [], "sog": []}
    ignored: list[Location] = []
    for entry in _candidates(source):
        kind = sniff_frame(entry)
        (frames[kind] if kind else ignored).append(entry)
    if frames["ply"] and frames["sog"]:
        raise InputError(
            f"mixes PLY frames ({frames['ply'][0].name}, ...) and SOG frames "
            f"({frames['sog'][0].name}, ...); expected one kind",
            where=where,
        )
    kind = "ply" if frames["ply"] else "sog"
    paths = frames[kind]
    if not paths:
        raise InputError("holds no numbered PLY or SOG frames", where=where)
    numbers = [n for n in map(frame_number, paths) if n is not None]
    for (a, na), (b, nb) in pairwise(zip(paths, numbers, strict=True)):
        if na == nb:
            raise InputError(f"frames {a.name!r} and {b.name!r} both have number {na}", where=where)
    return _Frames(paths, numbers, kind, ignored)


def list_frames(source: Source) -> list[Location]:
    """The frame files of a folder or glob pattern, in natural numeric order."""
    return _scan(source).paths


def detect_sequence(path: Source) -> str | None:
    """ "ply-sequence" or "sog-sequence" when ``path`` holds >= 2 numbered frames of one kind.

    The kind is that of the first numbered entry with PLY or SOG magic bytes; the frames are
    the entries sharing its extension. Anything else (including a single chunk folder) is None.
    """
    if not _is_glob(path):
        p = as_location(path)
        if not p.is_dir() or (p / META_JSON).is_file():
            return None
    candidates = _candidates(path)
    for entry in candidates:
        kind = sniff_frame(entry)
        if kind is None:
            continue
        suffix = entry.suffix.lower()
        same = [
            e for e in candidates if e.suffix.lower() == suffix and e.is_dir() == entry.is_dir()
        ]
        if len(same) < 2:
            return None
        return PLY_SEQUENCE if kind == "ply" else SOG_SEQUENCE
    return None


_FIELDS: Final = ("means", "scales", "quats", "opacities", "sh0", "shN")


class FrameStack:
    """Output arrays allocated once from per-frame (count, SH coefficients), filled in order."""

    def __init__(self, counts: Sequence[int], coeffs: Sequence[int], pad_to: int = 0) -> None:
        self.counts = list(counts)
        self.offsets = np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)])
        total, k = int(self.offsets[-1]), max([*coeffs, pad_to])
        tails = ((3,), (3,), (4,), (), (3,), (k, 3))
        self.arrays = {
            n: np.zeros((total, *t), np.float32) for n, t in zip(_FIELDS, tails, strict=True)
        }

    def put(self, index: int, g: Gaussians, where: str) -> None:
        """Copy frame ``index``; its size must match what its header declared. The one frame
        of a one-frame stack is taken as read, never held twice."""
        a, b = int(self.offsets[index]), int(self.offsets[index + 1])
        k = g.shN.shape[1]
        if len(g) != b - a or k > self.arrays["shN"].shape[1]:
            raise IntegrityError(
                f"header declared {b - a} Gaussians, decoding gave {len(g)} (SH coefficients {k})",
                where=where,
            )
        theirs = {n: getattr(g, n) for n in _FIELDS}
        if len(self.counts) == 1 and all(
            x.shape == y.shape and x.dtype == y.dtype and y.flags.c_contiguous
            for x, y in zip(self.arrays.values(), theirs.values(), strict=True)
        ):
            self.arrays = theirs
            return
        for name in _FIELDS[:-1]:
            self.arrays[name][a:b] = theirs[name]
        self.arrays["shN"][a:b, :k] = g.shN

    def scene(
        self,
        fps: float,
        first: int = 0,
        total: int | None = None,
        numbers: Sequence[int] | None = None,
    ) -> Scene:
        """The type-0 scene: frame id = first + position (or the frames' ``numbers``, for frames
        not in a run), scene_length = total frames / fps."""
        frames = len(self.counts)
        given = range(first, first + frames) if numbers is None else numbers
        ids = np.repeat(np.asarray(given, dtype=np.float64), self.counts)
        length = (frames if total is None else total) / fps
        timeline = Timeline(
            TimelineType.FRAME, ids, np.zeros_like(ids), fps=fps, scene_length=length
        )
        return Scene(Gaussians(**self.arrays), timeline)


def _check_fps(fps: float) -> float:
    """A positive finite frame rate, or InputError."""
    try:
        rate = float(fps)
    except (TypeError, ValueError):
        rate = float("nan")
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}", where="fps")
    return rate


def _ply_shape(path: Location) -> tuple[int, int]:
    """(Gaussians, SH coefficients per channel) declared by a PLY frame's header."""
    head = read_head(path, MAX_HEADER_BYTES)
    header = parse_header(head, name=str(path))
    vertex = header.element("vertex")
    count = vertex.count if vertex else 0
    if is_compressed_ply(header):
        sh = header.element("sh")
        return count, len(sh.names) // 3 if sh else 0
    rest = [n for n in (vertex.names if vertex else ()) if n.startswith("f_rest_")]
    return count, len(rest) // 3


def _sog_shape(path: Location) -> tuple[int, int]:
    """(Gaussians, SH coefficients per channel) from a SOG frame's meta.json alone."""
    where = str(path)
    if path.is_dir():
        data = read_bytes(path / META_JSON)
    else:
        try:
            with open_regular(path) as file, zipfile.ZipFile(file) as archive:
                data = archive.read(META_JSON)
        except KeyError:
            raise SogError("archive has no meta.json at its root", where=where) from None
        except (zipfile.BadZipFile, ValueError, EOFError) as exc:
            raise SogError(f"not a readable zip archive: {exc}", where=where) from exc
        except OSError as exc:
            raise SourceError(f"cannot read: {exc.strerror or exc}", where=where) from exc
    meta = read_meta({META_JSON: data}, where=where)
    if meta.timeline is not None:
        raise UnsupportedError(
            "is a TSOG chunk with a timeline; a SOG sequence holds static frames", where=where
        )
    return int(meta.count), SH_COEFFS_BY_BANDS[meta.shN.bands] if meta.shN else 0


def frame_shape(kind: str, path: Location) -> tuple[int, int]:
    """(Gaussians, SH coefficients per channel) a ``kind`` ("ply" or "sog") frame declares."""
    return _ply_shape(path) if kind == "ply" else _sog_shape(path)


def _sequence_notes(frames: _Frames, shapes: Sequence[tuple[int, int]]) -> list[str]:
    """Notes on skipped files, numbering gaps, differing sizes and mixed SH degrees."""
    notes: list[str] = []
    if frames.ignored:
        names = ", ".join(p.name for p in frames.ignored[:5])
        more = "" if len(frames.ignored) <= 5 else f" and {len(frames.ignored) - 5} more"
        notes.append(
            f"ignored {len(frames.ignored)} numbered entries that are not frames: {names}{more}"
        )
    gaps = [(a, b) for a, b in zip(frames.numbers, frames.numbers[1:], strict=False) if b - a > 1]
    if gaps:
        spans = ", ".join(f"{a + 1}-{b - 1}" if b - a > 2 else str(a + 1) for a, b in gaps[:5])
        missing = sum(b - a - 1 for a, b in gaps)
        notes.append(
            f"frame numbering skips {spans} ({missing} missing); frame ids are consecutive "
            "positions, so the gaps take no time"
        )
    counts = [c for c, _ in shapes]
    if len(set(counts)) > 1:
        notes.append(f"frames differ in size: {min(counts)} to {max(counts)} Gaussians")
    degrees = sorted({SH_BANDS_BY_COEFFS.get(k, k) for _, k in shapes})
    if len(degrees) > 1:
        top = SH_COEFFS_BY_BANDS.get(degrees[-1], 0)
        padded = sum(1 for _, k in shapes if k != top)
        notes.append(
            f"frames mix SH degrees {degrees}: {padded} frames padded to degree {degrees[-1]} "
            "with zero coefficients (one scene holds one degree; zeros render as before)"
        )
    return notes


def _merge_notes(per_frame: Iterable[tuple[str, list[str]]]) -> list[str]:
    """One line per distinct reader note, naming the frames it came from."""
    seen: dict[str, list[str]] = {}
    for name, notes in per_frame:
        for note in notes:
            seen.setdefault(note, []).append(name)
    merged = []
    for note, names in seen.items():
        which = names[0] if len(names) == 1 else f"{len(names)} frames, {names[0]}..{names[-1]}"
        merged.append(f"{which}: {note}")
    return merged


@dataclass(frozen=True)
class FrameSequence:
    """An opened sequence: frame files, their declared sizes, and the frame rate.

    Nothing but headers is read until :meth:`read`, which loads any run of frames, so a
    segmenter can hold one window of a long sequence at a time.
    """

    frames: _Frames
    shapes: list[tuple[int, int]]
    fps: float
    where: str

    @property
    def count(self) -> int:
        """Number of frames."""
        return len(self.frames.paths)

    @property
    def sh_coeffs(self) -> int:
        """SH coefficients per channel every frame is padded to (the highest present)."""
        return max((k for _, k in self.shapes), default=0)

    @property
    def gaussians(self) -> int:
        """Gaussians over all frames."""
        return sum(c for c, _ in self.shapes)

    def notes(self) -> list[str]:
        """Notes on skipped files, numbering gaps, sizes and SH degrees."""
        return _sequence_notes(self.frames, self.shapes)

    def window(self, first: int = 0, stop: int | None = None) -> FrameWindow:
        """Frames [first, stop) as a :class:`FrameWindow`: what a worker needs to read them."""
        stop = self.count if stop is None else stop
        return FrameWindow(
            self.frames.kind,
            self.frames.paths[first:stop],
            self.shapes[first:stop],
            self.sh_coeffs,
            self.fps,
            first,
            self.count,
        )

    def read(
        self, first: int = 0, stop: int | None = None, progress: Progress | None = None
    ) -> Loaded4D:
        """Frames [first, stop) as one type-0 scene with absolute frame ids."""
        return self.window(first, stop).read(progress)


def _read_frame(kind: str, path: Location) -> tuple[Gaussians, list[str], set[str]]:
    """One frame's Gaussians, reader notes and unkept extra properties."""
    if kind == "ply":
        contents = read_ply(path)
        return contents.gaussians, contents.notes, set(contents.extra)
    return read_chunk(path).gaussians, [], set()


@dataclass(frozen=True)
class FrameWindow:
    """A run of frames by location and declared shape, not by content: small to send, so a
    worker process or a cluster node reads its own window's frames (from disk or a store)."""

    kind: str
    paths: list[Location]
    shapes: list[tuple[int, int]]
    sh_coeffs: int
    """SH coefficients every frame is padded to (the sequence's highest)."""
    fps: float
    first: int
    """The sequence's frame number of the first frame here."""
    total: int
    """Frames in the whole sequence (the scene length)."""

    def read(self, progress: Progress | None = None) -> Loaded4D:
        """The frames as one type-0 scene with absolute frame ids."""
        shapes = self.shapes
        stack = FrameStack([c for c, _ in shapes], [k for _, k in shapes], self.sh_coeffs)
        per_frame: list[tuple[str, list[str]]] = []
        extras: set[str] = set()
        for i, path in enumerate(self.paths):
            if progress:
                progress(f"frame {self.first + i + 1}/{self.total}")
            g, notes, extra = _read_frame(self.kind, path)
            stack.put(i, g, str(path))
            per_frame.append((path.name, notes))
            extras.update(extra)
        notes = _merge_notes(per_frame)
        if extras:
            notes.append(f"per-frame extra properties are not kept: {', '.join(sorted(extras))}")
        return Loaded4D(stack.scene(self.fps, self.first, self.total), notes)


def open_sequence(
    source: Source, *, fps: float = DEFAULT_FPS, kind: str | None = None
) -> FrameSequence:
    """Scan a folder or glob of numbered frames and read their headers only."""
    rate = _check_fps(fps)
    frames = _scan(source)
    where = os.fspath(source)
    if kind is not None and frames.kind != kind:
        reader = f"read_{frames.kind}_sequence"
        raise InputError(f"holds {frames.kind.upper()} frames; use {reader}", where=where)
    shapes = [frame_shape(frames.kind, p) for p in frames.paths]
    return FrameSequence(frames, shapes, rate, where)


def read_ply_sequence(
    source: Source, *, fps: float = DEFAULT_FPS, progress: Progress | None = None
) -> Loaded4D:
    """Read numbered per-frame 3DGS PLYs as one type-0 scene (frame k's Gaussians in file order)."""
    return _read_all(open_sequence(source, fps=fps, kind="ply"), progress)


def read_sog_sequence(
    source: Source, *, fps: float = DEFAULT_FPS, progress: Progress | None = None
) -> Loaded4D:
    """Read numbered SOG frames (.sog zips or chunk folders) as one type-0 scene."""
    return _read_all(open_sequence(source, fps=fps, kind="sog"), progress)


def _read_all(seq: FrameSequence, progress: Progress | None) -> Loaded4D:
    """Every frame of ``seq``, the sequence's notes before the frames'."""
    loaded = seq.read(progress=progress)
    return Loaded4D(loaded.scene, seq.notes() + loaded.notes)


__all__ = [
    "DEFAULT_FPS",
    "PLY_SEQUENCE",
    "SOG_SEQUENCE",
    "FrameSequence",
    "FrameStack",
    "FrameWindow",
    "detect_sequence",
    "frame_number",
    "frame_shape",
    "list_frames",
    "natural_key",
    "open_sequence",
    "read_ply_sequence",
    "read_sog_sequence",
    "sniff_frame",
]
