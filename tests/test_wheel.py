"""The package carries its player: the wheel, installed into a fresh virtual environment with
no npm and no checkout, serves the player page and every asset it references."""

from __future__ import annotations

import re
import subprocess
import sys
import sysconfig
import urllib.request
from pathlib import Path
from urllib.parse import urljoin

import pytest

from conftest import REPO
from helpers import free_port
from serve_process import _wait_listening
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.synthetic import small_scene

REFERENCE = re.compile(
    r"""(?:src|href)="(/[^"]+)"|"(/player/[^"]+)"|(?:from|import)\s+['"]([^'"]+)['"]"""
)
"""What a page or module refers to: src/href attributes, import-map targets, and ES imports."""


def build_wheel(out: Path) -> Path:
    """The wheel of this checkout (setuptools in an isolated build environment)."""
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(REPO)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    [wheel] = out.glob("tsog_stream-*.whl")
    return wheel


def fresh_venv(folder: Path, wheel: Path) -> Path:
    """A new virtual environment with the wheel installed; its dependencies (numpy, aiohttp...)
    come from this interpreter's site-packages through a path entry, not from a download. A
    path entry's own .pth files are not run, so the checkout's editable install stays out."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True)
    python = folder / "bin" / "python"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--no-deps",
            "-q",
            str(wheel),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    (Path(site) / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return folder


def get(url: str) -> tuple[int, bytes]:
    """Status and body of a GET."""
    try:
        with urllib.request.urlopen(url, timeout=30) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def referenced(url: str, body: bytes) -> set[str]:
    """Absolute URLs of what a page or module refers to (bare specifiers skipped: the import
    map names those)."""
    found = set()
    for match in REFERENCE.finditer(body.decode("utf-8", "replace")):
        target = next(g for g in match.groups() if g)
        if target.startswith(("/", "./", "../")):
            found.add(urljoin(url, target))
    return found


@pytest.mark.slow
def test_the_installed_wheel_serves_the_player_and_every_asset(tmp_path: Path) -> None:
    wheel = build_wheel(tmp_path / "dist")
    venv = fresh_venv(tmp_path / "venv", wheel)
    root = tmp_path / "site"
    root.mkdir()
    segment_scene(
        small_scene(TimelineType.CENTER_SCALE), root / "clip.tsogs", SegmentOptions(window_s=0.5)
    )
    check = "import tsog_stream, sys; print(tsog_stream.__file__)"
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", check],
        cwd=tmp_path,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    assert where.startswith(str(venv)), where  # the wheel's files, not the checkout's
    port = free_port()
    server = subprocess.Popen(
        [str(venv / "bin" / "tsog"), "serve", str(root), "--port", str(port), "-q"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        _wait_listening(server, port, Path("/dev/null"))
        base = f"http://127.0.0.1:{port}"
        todo = [f"{base}/play/", f"{base}/play/clip"]
        fetched: dict[str, int] = {}
        while todo:
            url = todo.pop()
            if url in fetched:
                continue
            status, body = get(url)
            fetched[url] = status
            if status == 200 and url.endswith(("/", "/clip", ".js", ".mjs", ".html")):
                todo.extend(referenced(url, body) - set(fetched))
    finally:
        server.terminate()
        _, err = server.communicate(timeout=15)
    assert {u: s for u, s in fetched.items() if s != 200} == {}
    engine = f"{base}/player/engine/playcanvas.mjs"
    assert engine in fetched and f"{base}/player/player.js" in fetched
    assert len(fetched) >= 9, sorted(fetched)  # pages, modules, stylesheet, engine
    assert b"Traceback" not in err
