"""``tsog view INPUT``: one step from any input to the web player.

A container (or unpacked folder) is served as it is; any other input is segmented once into a
cache folder, keyed by the input's files (names, sizes, modification times), the reading
options and the version, so opening it again while it is unchanged starts at once. The
server listens on 127.0.0.1 (a free port unless ``--port``) and the player URL is printed
(and opened in a browser with ``--open``). Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import hashlib
import json
import os
import webbrowser
from pathlib import Path
from typing import Any
from urllib.parse import quote

from .._version import __version__
from ..client import open_stream
from ..errors import InputError, TsogError, printable
from ..inputs import STREAM_KINDS, input_kind, is_url
from ..io.objects import is_object_url
from ..io.sequence import list_frames
from ..pipeline import segment_input
from ..schemas.manifest import SceneInfo
from .common import (
    Integer,
    Subparsers,
    Told,
    add_cameras,
    add_common,
    add_input,
    assumed_duration,
    local_file,
    note,
    scene_duration,
    warn,
)
from .progress import Progress
from .segment_report import print_segment_report
from .stream_commands import default_options, reading_options
from .view_cache import (
    KEY_LENGTH,
    MAX_CACHE_BYTES,
    claimed,
    clear,
    entry_kind,
    evict,
    has_record,
    mark_used,
    record,
    serving,
    unusable_cache,
)

CACHE_ENV = "TSOG_CACHE_DIR"
MAX_FINGERPRINT_FILES = 100_000
"""A folder with more files than this is refused rather than walked for ever."""

VIEW_EPILOG = f"""examples, one per kind of input:
  tsog view clip.splatv --duration-s 10       a .splatv (its length: the file does not say it)
  tsog view frames/ --fps 30 --open           numbered PLY or SOG frames, opened in a browser
  tsog view 'frames/f_*.ply' --fps 30         the same frames by pattern (quoted)
  tsog view point_cloud.ply                   a 3DGS PLY, compressed PLY or FreeTimeGS PLY
  tsog view ckpt.npz --scene-length-s 4       a FreeTimeGS checkpoint
  tsog view scene.sog                         a SOG/TSOG chunk (.sog zip or its folder)
  tsog view clip.4dgs                         a .4dgs scene
  tsog view clip.tsogs --port 8080            a container (or unpacked folder), served as it is
  tsog view clip.splatv -v                    also print the segment report (layout, sizes)

The segmented copy lives in $TSOG_CACHE_DIR, else $XDG_CACHE_HOME/tsog-stream/view, else
~/.cache/tsog-stream/view (--cache DIR to choose), one folder per input version. Making a
copy removes the copies of earlier versions of that input, then the least recently used
ones beyond {MAX_CACHE_BYTES >> 30} GiB in all (never one being served); anything else found
in a copy's place (a link, a file, what a stopped run left) is made again. Delete the
folder freely. The server listens on 127.0.0.1 only; Ctrl-C stops it."""


def add_view_command(sub: Subparsers) -> None:
    """Register ``view`` on the main parser."""
    p = sub.add_parser(
        "view",
        help="open any input in the web player: segment it once (cached), serve it, print the URL",
        epilog=VIEW_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_input(p)
    add_cameras(p)
    p.add_argument(
        "--port", type=Integer(0, 65535), default=0, help="port on 127.0.0.1 (default: any free)"
    )
    p.add_argument("--open", action="store_true", help="open the player in a web browser")
    p.add_argument("--cache", type=local_file, help="folder for segmented copies (see below)")
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="print the segment command's whole report (layout, seek cost, sizes per level)",
    )
    add_common(p)


def cache_root(given: Path | None) -> Path:
    """Where segmented copies are kept."""
    if given is not None:
        return given
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "tsog-stream" / "view"


def _files_of(target: Path) -> list[Path]:
    """The files an input is read from: itself, a folder's files, or a pattern's frames."""
    if target.is_file():
        return [target]
    if target.is_dir():
        found = []
        for path in sorted(target.rglob("*")):
            if path.is_file():
                found.append(path)
            if len(found) > MAX_FINGERPRINT_FILES:
                raise InputError(f"more than {MAX_FINGERPRINT_FILES} files", where=str(target))
        return found
    # a frame pattern: the frames the sequence reader reads (local: Path(args.input) is local)
    return [p for p in list_frames(str(target)) if isinstance(p, Path)]


def source_of(args: argparse.Namespace) -> dict[str, Any]:
    """What a copy is of: the input's path, the reading options and this program's version."""
    if is_object_url(args.input):
        raise InputError(
            "tsog view opens local inputs; segment a stored one with tsog segment and view the "
            "container, or serve it",
            where=args.input,
        )
    cameras = str(Path(args.cameras).resolve()) if args.cameras else None
    reading = [args.format, args.fps, args.duration_s, args.scene_length_s, args.duration_mode]
    return {
        "input": str(Path(args.input).resolve()),
        "options": [cameras, *reading],
        "version": __version__,
    }


def fingerprint(args: argparse.Namespace) -> str:
    """A key that changes when the input's files, the reading options or the version do."""
    source = source_of(args)
    files = _files_of(Path(args.input)) + (_files_of(Path(args.cameras)) if args.cameras else [])
    stats = [(str(path.resolve()), path.stat()) for path in files]
    items = [source, [[name, st.st_size, st.st_mtime_ns] for name, st in stats]]
    return hashlib.sha256(json.dumps(items, sort_keys=True).encode()).hexdigest()[:KEY_LENGTH]


def _scene_name(target: str) -> str:
    """A URL-friendly scene name from the input's name."""
    stem = Path(target.rstrip("/")).name.split("*")[0] or "scene"
    stem = stem.removesuffix(".tsogs").split(".")[0] or "scene"
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in stem)[:64]


def _segmented(args: argparse.Namespace, progress: Progress) -> Path:
    """The input's container in the cache, segmented now unless a complete copy of the
    unchanged input is there (anything else in its place is removed and made again)."""
    root = cache_root(args.cache)
    with claimed(root, fingerprint(args), progress) as folder:
        container = folder / f"{_scene_name(args.input)}.tsogs"
        scene = _complete_copy(folder, container)
        if scene is not None:
            if scene.duration_assumed:  # the first line, as when the reader said it
                warn(assumed_duration(args.input))
            shown = printable(str(container))
            print(f"{shown}: reusing the copy segmented earlier (the input is unchanged)")
            print(f"  {_copy_line(container, scene)}")
            mark_used(folder)
            return container
        _clear_leftovers(root, folder)
        try:
            _segment_into(args, container, progress)
            record(folder, source_of(args))
        except BaseException as exc:
            with contextlib.suppress(OSError):  # held still: no other run has begun in it
                clear(folder)
                folder.rmdir()  # a failed segment publishes nothing (nor a thumbnail)
            if isinstance(exc, OSError):  # writing the copy: the disk is full, or read-only
                raise unusable_cache(root, exc) from None
            raise
    removed = evict(root, folder)
    if removed:
        shown = printable(str(root))
        print(f"  cache: removed {len(removed)} older or least recently used copies ({shown})")
    return container


def _clear_leftovers(root: Path, folder: Path) -> None:
    """Empty a claimed folder that holds no complete copy, saying so if it held anything."""
    try:
        if clear(folder):
            shown = printable(str(folder))
            note(f"{shown}: an incomplete or damaged copy (a stopped run?): segmenting again")
    except OSError as exc:
        raise unusable_cache(root, exc) from None


def _complete_copy(folder: Path, container: Path) -> SceneInfo | None:
    """What a finished copy in ``folder`` holds (its record and container regular files, the
    container opening), or None."""
    if not has_record(folder) or entry_kind(container) != "file":
        return None
    try:
        return _scene_of(container)
    except (TsogError, OSError):
        return None


def _scene_of(container: Path) -> SceneInfo:
    """The scene a container's index describes (a damaged index or manifest fails here)."""
    with open_stream(container) as opened:
        return opened.index.manifest.scene


def _segment_into(args: argparse.Namespace, container: Path, progress: Progress) -> None:
    """Segment the input into ``container`` as ``tsog segment`` would with the same reading
    options; its report is printed with ``-v``, else two lines: what was made, where, how big."""
    options = default_options()
    told = Told(progress, args.input)
    made = segment_input(args.input, container, options, reading_options(args), told)
    progress.done()
    if args.verbose:
        print_segment_report(made, options.quality)
        return
    print(f"segmented {printable(args.input)} into {printable(str(container))} (-v: its layout)")
    print(f"  {_copy_line(container, _scene_of(container), made.input_bytes)}")


def _copy_line(container: Path, scene: SceneInfo, input_size: int = 0) -> str:
    """What a copy holds and how big it is, in one line."""
    was = f" (the input: {_bytes_text(input_size)})" if input_size else ""
    size = _bytes_text(container.stat().st_size)
    return f"{scene.gaussians:,} Gaussians, {scene_duration(scene)}, {size}{was}"


def _bytes_text(size: int) -> str:
    """A size as people read it: 950 B, 138 kB, 12.4 MB, 3.1 GB."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{size} B"


def cmd_view(args: argparse.Namespace, progress: Progress) -> int:
    """tsog view."""
    if is_url(args.input):
        raise InputError(
            "tsog view opens local inputs; for a served stream open its server's /play/ page"
        )
    kind = input_kind(args.input, args.format)
    if kind in STREAM_KINDS:
        with open_stream(args.input) as opened:  # a broken index fails here, in one line
            opened.index.manifest  # noqa: B018
        target = Path(args.input)
        root = target if kind == "tsogs" else target.parent
        name = target.name.removesuffix(".tsogs")
        held: contextlib.AbstractContextManager[None] = contextlib.nullcontext()
    else:
        root = _segmented(args, progress)
        name = root.name.removesuffix(".tsogs")
        held = serving(root.parent)  # no other tsog view evicts it while it is served
    progress.done()
    with held, contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(root, name, args.port, args.open))
    return 0


async def _serve(root: Path, name: str, port: int, open_browser: bool) -> None:
    """Serve ``root`` on 127.0.0.1 until cancelled; print (and open) the player URL."""
    from ..server import make_app, start_server  # noqa: PLC0415 - aiohttp.web for this command only

    runner, bound = await start_server(make_app(root), "127.0.0.1", port)
    url = f"http://127.0.0.1:{bound}/play/{quote(name)}"
    print(f"playing at {url}  (Ctrl-C to stop)", flush=True)
    if open_browser:
        webbrowser.open(url)
    try:
        await asyncio.Event().wait()
    finally:
        await runner.cleanup()
