"""The README's Python example runs as written (only the server's port is the test's own)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import tsog_stream as tsog
from helpers import ThreadedServer
from tsog_stream.server.app import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene

README = Path(__file__).resolve().parents[1] / "README.md"
EXAMPLE_URL = "http://127.0.0.1:8080"


def readme_example() -> str:
    """The first ```python block of the README."""
    found = re.search(r"```python\n(.*?)```", README.read_text(), re.S)
    assert found is not None, "the README has no Python example"
    return found.group(1)


def write_frames(folder: Path, count: int = 12, fps: float = 30.0) -> None:
    """A folder of numbered PLY frames sampled from a generated 4D scene."""
    scene = generate_scene(SceneSpec(seed=3, background=300, objects=2, per_object=80, duration=1))
    folder.mkdir()
    for k in range(count):
        tsog.write_ply(folder / f"frame_{k:04d}.ply", scene.at(k / fps))


def test_the_readme_example_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    code = readme_example()
    assert "import tsog_stream as tsog" in code and EXAMPLE_URL in code
    assert not re.search(r"from tsog_stream\.\w", code), "the example uses the public API only"
    monkeypatch.chdir(tmp_path)
    write_frames(tmp_path / "frames")
    (tmp_path / "streams").mkdir()
    server = ThreadedServer(make_app(tmp_path / "streams"))
    try:
        exec(code.replace(EXAMPLE_URL, f"http://127.0.0.1:{server.port}"), {})
    finally:
        server.stop()
    frame = tsog.load_scene("frame.ply").scene.gaussians
    with tsog.open_stream(tmp_path / "streams" / "clip.tsogs") as local:
        want = local.frame_at(0.2)
    assert len(frame) == len(want) > 0
    order = np.lexsort(frame.means.T), np.lexsort(want.means.T)
    np.testing.assert_array_equal(frame.means[order[0]], want.means[order[1]])
    printed = capsys.readouterr().out
    assert f"{len(want)} Gaussians" in printed and "requests" in printed
