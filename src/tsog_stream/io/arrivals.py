"""Frames arriving in a folder while a capture or a training pipeline writes them.

A frame is a numbered PLY or SOG file (or SOG chunk folder) of the folder; it counts once it is
complete: unchanged in size and modification time for :data:`SETTLE_S` (a file written then
renamed in counts after that moment too) and, where its format says how long it is (a binary
PLY's header, a zip's directory), whole. Frames are handed out in their natural order, each
once; an ``END`` file in the folder says no frame will follow (docs/live.md).
"""

from __future__ import annotations

import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

from ..codec.bundle import is_zip
from ..constants import META_JSON
from ..errors import InputError, SourceError, TsogError
from .files import open_regular, read_head
from .ply_header import MAX_HEADER_BYTES, PlyFormat, element_dtype, parse_header
from .sequence import frame_number, natural_key, sniff_frame

SETTLE_S = 0.15
"""How long a frame file must stay unchanged to count as complete."""
GIVE_UP_S = 10.0
"""A frame unchanged this long but still short of its declared size is left out (named)."""
END_MARKER = "END"
"""A file of this name in the folder ends the event once every frame before it is taken."""
MAX_LISTED = 1_000_000
"""Entries of the folder read at most per look (a bound, not a tuning)."""
FRAME_SUFFIXES = (".ply", ".sog")


@dataclass(frozen=True)
class Arrival:
    """A complete frame: its file, its position in the event, when it was complete (Unix
    seconds: the file's last modification) and its kind ("ply" or "sog", by its content)."""

    path: Path
    index: int
    arrived_s: float
    kind: str


class FrameArrivals:
    """The complete frames of ``folder`` not yet handed out, in order, the first ``skip``
    frames (handed out before a restart) passed over."""

    def __init__(self, folder: str | os.PathLike[str], *, skip: int = 0) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise InputError("expected a folder that frames are written into", where=str(folder))
        self.taken = 0
        self.kind: str | None = None
        self.left_out: list[str] = []
        """Frames left out, each named once with why: one that sorted before a frame already
        taken (it came late), one that stayed short of its declared size."""
        self._skip = skip
        self._last: str | None = None
        self._names: set[str] = set()
        self._seen: dict[str, tuple[int, int, float]] = {}

    def ended(self) -> bool:
        """The end marker is there."""
        return (self.folder / END_MARKER).exists()

    def poll(self) -> list[Arrival]:
        """The frames complete since the last call that follow every frame taken, in order;
        a frame still being written holds back the ones after it."""
        now = time.monotonic()
        settled = [(name, self._settled(name, now)) for name in self._new_names()]
        out: list[Arrival] = []
        for name, arrived in settled:
            if arrived is None:
                break
            path = self.folder / name
            if not _whole(path):
                if now - self._seen[name][2] < GIVE_UP_S:
                    break
                self._leave_out(name, f"it stayed short of its declared size for {GIVE_UP_S:g} s")
                self._take(name, counted=False)
                continue
            out.append(Arrival(path, self.taken, arrived, self._kind_of(path)))
            self._take(name)
        return out

    def waiting(self) -> bool:
        """A frame file is there that is not complete yet."""
        return bool(self._new_names())

    def _take(self, name: str, *, counted: bool = True) -> None:
        """Hand ``name`` out (``counted``: as the next frame) and look past it from now on."""
        self._seen.pop(name, None)
        self.taken += counted
        self._last = name
        self._names.add(name)

    def _leave_out(self, name: str, why: str) -> None:
        """Name a frame left out, once."""
        said = f"left out {name}: {why}"
        if said not in self.left_out:
            self.left_out.append(said)

    def _new_names(self) -> list[str]:
        """Frame names after the last one taken, in natural order (the first ``skip`` of a
        restart taken at the first look); one sorting before it arrived late and is named."""
        ordered = sorted(self._frame_names(), key=natural_key)
        if self._skip:
            if len(ordered) < self._skip:
                raise InputError(
                    f"holds {len(ordered)} frames, fewer than the {self._skip} already published",
                    where=str(self.folder),
                )
            for name in ordered[: self._skip]:
                self._take(name)
            self._skip = 0
        if self._last is None:
            return ordered
        last = natural_key(self._last)
        fresh = []
        for name in ordered:
            if natural_key(name) > last:
                fresh.append(name)
            elif name not in self._names:
                self._leave_out(name, "it arrived after a frame that sorts after it")
        return fresh

    def _frame_names(self) -> list[str]:
        """The names of the folder that frames may have (at most MAX_LISTED entries read)."""
        names = []
        with os.scandir(self.folder) as entries:
            for count, entry in enumerate(entries):
                if count >= MAX_LISTED:
                    raise SourceError(
                        f"holds more than {MAX_LISTED} entries", where=str(self.folder)
                    )
                numbered = frame_number(self.folder / entry.name) is not None
                if numbered and _is_frame_name(entry.name):
                    names.append(entry.name)
        return names

    def _settled(self, name: str, now: float) -> float | None:
        """When ``name`` was complete (its modification time), or None while it may change."""
        try:
            st = os.stat(self.folder / name)
        except FileNotFoundError:
            return None
        state = (st.st_size, st.st_mtime_ns)
        first = self._seen.get(name)
        if first is None or first[:2] != state:
            self._seen[name] = (*state, now)
            return None
        if now - first[2] < SETTLE_S:
            return None
        return st.st_mtime_ns / 1e9

    def _kind_of(self, path: Path) -> str:
        """A frame's kind by its content; every frame of an event is of the first frame's."""
        kind = sniff_frame(path)
        if kind is None:
            raise InputError("is neither a PLY nor a SOG frame", where=str(path))
        if self.kind is None:
            self.kind = kind
        elif kind != self.kind:
            raise InputError(
                f"is a {kind.upper()} frame in an event of {self.kind.upper()} frames",
                where=str(path),
            )
        return kind


def _whole(path: Path) -> bool:
    """The frame file holds every byte its format declares (a binary PLY's elements, a zip's
    directory at its end); a format that does not say (ASCII PLY, a chunk folder) is whole."""
    if path.is_dir():
        return (path / META_JSON).is_file()
    try:
        head = read_head(path, MAX_HEADER_BYTES)
        if is_zip(head):
            with open_regular(path) as file, zipfile.ZipFile(file):
                return True
        header = parse_header(head, name=str(path))
        if header.format is PlyFormat.ASCII or not all(e.is_fixed for e in header.elements):
            return True
        rows = sum(e.count * element_dtype(e, header.format).itemsize for e in header.elements)
        return path.stat().st_size >= header.size + rows
    except (TsogError, zipfile.BadZipFile, OSError, ValueError, EOFError):
        return False


def _is_frame_name(name: str) -> bool:
    """A name a frame may have: a PLY or SOG file, or a SOG chunk folder, not hidden."""
    if name.startswith("."):
        return False
    suffix = Path(name).suffix.lower()
    return suffix in FRAME_SUFFIXES or suffix == ""
