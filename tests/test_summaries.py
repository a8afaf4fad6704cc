"""What the CLI says reads right to a new user: assumptions first, sizes and counts plainly,
times outside the scene and missing scenes named as such."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import ThreadedServer
from tsog_stream.cli.main import main
from tsog_stream.server import make_app

HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"


@pytest.fixture(scope="module")
def served(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    root = tmp_path_factory.mktemp("summaries")
    assert main(["segment", str(samples / HANABI), "-o", str(root / "clip.tsogs"), "-q"]) == 0
    server = ThreadedServer(make_app(root))
    try:
        yield f"http://127.0.0.1:{server.port}"
    finally:
        server.stop()


def test_the_assumed_splatv_duration_is_the_first_thing_said(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "c.tsogs"
    assert main(["segment", str(samples / HANABI), "-o", str(out), "-q"]) == 0
    said = capsys.readouterr()
    first = said.err.splitlines()[0]
    name = HANABI.rsplit("/", 1)[1]
    assert first == (
        f"tsog: warning: {name} does not say its length: read as 1 s; set it with --duration-s"
    )
    lines = said.out.splitlines()
    assert lines[0].startswith(f"{out}: ") and "smaller than the input" in lines[0]
    assert any(line.endswith(" stored copies") for line in lines)
    assert main(["segment", str(samples / HANABI), "-o", str(out), "-f", "--duration-s", "4"]) == 0
    said = capsys.readouterr()
    assert "does not say its length" not in said.err and "normalised" not in said.err
    assert "  duration 4.00 s" in said.out.splitlines()


def test_a_larger_output_is_said_to_be_larger(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The hanabi frames are 6 PLY files of 4,000 Gaussians; segmented at 100 quality with a
    window per frame and one chunk each, the container is smaller; a 1-frame window of its
    .splatv at quality 100 is compared the same way, and either way the words match the sign."""
    out = tmp_path / "c.tsogs"
    argv = ["segment", str(samples / HANABI), "-o", str(out), "--quality", "100", "-q"]
    assert main(argv) == 0
    first = capsys.readouterr().out.splitlines()[0]
    size, source = out.stat().st_size, (samples / HANABI).stat().st_size
    word = "larger" if size > source else "smaller"
    assert f" % {word} than the input" in first and "-" not in first.split("bytes,")[1]


def test_play_refuses_a_start_outside_the_scene(
    served: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["play", f"{served}/files/clip.tsogs", "--start", "99", "-q"]) == 1
    err = capsys.readouterr().err
    assert err == "tsog: error: --start: 99 s is outside the scene, which runs from 0 to 1 s\n"


def test_play_explains_what_a_stall_is(served: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["play", f"{served}/files/clip.tsogs", "--duration", "0.2", "-q"]) == 0
    out = capsys.readouterr().out
    assert "a stall: a frame whose chunks had not arrived when it was due" in out
    with pytest.raises(SystemExit):
        main(["play", "--help"])
    assert "A stall is a frame whose chunks had not arrived" in capsys.readouterr().out


@pytest.mark.parametrize("path", ["/files/nothing.tsogs", "/files/nothing/"])
def test_a_missing_scene_over_http_is_not_found(
    served: str, path: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", f"{served}{path}", "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("tsog: error: ") and "not found (HTTP 404)" in err
    message = err.replace(served, "")  # the address's port may hold any digits, 206 too
    assert "206" not in message and err.count("\n") == 1
