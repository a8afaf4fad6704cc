"""PSNR/SSIM conventions, ``tsog eval`` and ``tsog render`` on real and generated scenes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from helpers import ThreadedServer
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.errors import InputError
from tsog_stream.inputs import open_source
from tsog_stream.io.chunks import write_chunk_files
from tsog_stream.io.ply import read_ply, write_ply
from tsog_stream.model import Gaussians, Scene, TimelineType
from tsog_stream.render.camera import scene_orbit
from tsog_stream.render.evaluate import (
    CameraSetup,
    evaluate,
    sample_times,
    scene_source,
)
from tsog_stream.render.metrics import (
    C1,
    C2,
    gaussian_filter,
    gaussian_window,
    psnr,
    ssim,
    ssim_map,
)
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server.app import make_app
from tsog_stream.synthetic import small_scene

DONUT = "3dgs/v3dg_donut_fused.ply"
SIZE = ["--width", "160", "--height", "120"]


def _noise(seed: int, shape: tuple[int, ...] = (40, 56, 3)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


# --- metrics -------------------------------------------------------------------------------


def test_identical_images_give_inf_psnr_and_ssim_exactly_one() -> None:
    for image in (_noise(0), _noise(1, (17, 23)), np.zeros((12, 12, 3), np.uint8)):
        assert psnr(image, image) == math.inf
        assert ssim(image, image) == 1.0


def test_psnr_of_a_known_mse() -> None:
    a = np.full((120, 160, 3), 100, np.uint8)
    b = a.copy()
    b[7, 9, 1] = 100 + 255 // 5  # one value off by 51/255 = 0.2: MSE = 0.04 / 57600
    assert psnr(a, b) == pytest.approx(10 * math.log10(57600 / 0.04), abs=1e-9)
    c = a + np.uint8(3)  # every value off by 3/255
    assert psnr(a, c) == pytest.approx(20 * math.log10(255 / 3), abs=1e-9)
    assert psnr(np.zeros((4, 4), np.uint8), np.full((4, 4), 255, np.uint8)) == 0.0


def test_filter_is_the_zero_padded_2d_gaussian_convolution() -> None:
    image = _noise(2, (13, 19, 2)).astype(np.float64) / 255
    w = gaussian_window()
    assert w.shape == (11,) and w.sum() == pytest.approx(1.0)
    assert w[5] / w[4] == pytest.approx(math.exp(1 / (2 * 1.5**2)))
    window = np.outer(w, w)
    padded = np.pad(image, ((5, 5), (5, 5), (0, 0)))
    direct = np.zeros_like(image)
    for i in range(13):
        for j in range(19):
            direct[i, j] = np.einsum("ij,ijc->c", window, padded[i : i + 11, j : j + 11])
    np.testing.assert_allclose(gaussian_filter(image), direct, atol=1e-14)


def _coverage(n: int) -> np.ndarray:
    """Weight of the 1D window that falls inside an image of n pixels, per pixel."""
    w = gaussian_window()
    return np.array([sum(w[k] for k in range(11) if 0 <= i + k - 5 < n) for i in range(n)])


def test_ssim_of_two_constant_images_has_a_closed_form() -> None:
    va, vb = 90, 140
    a, b = np.full((30, 36, 3), va, np.uint8), np.full((30, 36, 3), vb, np.uint8)
    x, y = va / 255, vb / 255
    # interior: the window sees only the constant, so variances vanish and only luminance is left
    interior = (2 * x * y + C1) / (x * x + y * y + C1)
    got = ssim_map(a, b)
    np.testing.assert_allclose(got[5:-5, 5:-5], interior, rtol=1e-12)
    # near the border the zero padding covers a fraction c of the window: mu = v c and
    # sigma^2 = v^2 c (1 - c), sigma_xy = x y c (1 - c)
    c = np.outer(_coverage(30), _coverage(36))
    v = c * (1 - c)
    expected = (2 * x * y * c * c + C1) * (2 * x * y * v + C2)
    expected /= ((x * x + y * y) * c * c + C1) * ((x * x + y * y) * v + C2)
    np.testing.assert_allclose(got[:, :, 0], expected, rtol=1e-9, atol=1e-12)
    assert ssim(a, b) == pytest.approx(float(expected.mean()), rel=1e-9)
    assert ssim(a, b) < interior  # the padding makes the borders worse than the interior


def test_ssim_is_symmetric_and_bounded() -> None:
    for seed in range(4):
        a, b = _noise(seed), _noise(seed + 10)
        blurred = np.clip(a.astype(int) + _noise(seed + 20) // 16, 0, 255).astype(np.uint8)
        for other in (b, blurred, 255 - a):
            assert ssim(a, other) == pytest.approx(ssim(other, a), abs=1e-15)
            assert -1.0 <= ssim(a, other) < 1.0
        assert ssim(a, blurred) > ssim(a, b)
        assert ssim(a, 255 - a) < 0  # anti-correlated structure


def test_metrics_refuse_mismatched_inputs() -> None:
    with pytest.raises(InputError, match="shape"):
        psnr(_noise(0, (8, 8, 3)), _noise(0, (8, 9, 3)))
    with pytest.raises(InputError, match="uint8"):
        ssim(np.zeros((8, 8, 3), np.float32), np.zeros((8, 8, 3), np.float32))


def test_sample_times() -> None:
    assert sample_times(None, 5) == [0.0]
    assert sample_times((0.0, 2.0), 4) == [0.25, 0.75, 1.25, 1.75]
    assert sample_times((1.0, 1.0), 3) == [1.0]
    assert sample_times((0.0, 2.0), 4, fps=10.0) == [0.2, 0.7, 1.2, 1.7]  # frame starts
    with pytest.raises(InputError):
        sample_times((0.0, 1.0), 0)


# --- tsog eval on a real scene ----------------------------------------------------------------


def _quantised_positions(g: Gaussians, bits: int = 8) -> Gaussians:
    """Positions rounded to 2^bits levels over the bounds of each axis (a damaged copy)."""
    lo, hi = g.means.min(axis=0), g.means.max(axis=0)
    levels = (1 << bits) - 1
    q = np.round((g.means - lo) / (hi - lo) * levels) / levels * (hi - lo) + lo
    return Gaussians.from_arrays(q, g.scales, g.quats, g.opacities, g.sh0, shN=g.shN)


@pytest.fixture(scope="module")
def donut_files(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("eval")
    source = samples / DONUT
    sog = folder / "donut.sog"
    assert main(["encode", str(source), str(sog), "-q"]) == 0
    damaged = folder / "damaged.ply"
    write_ply(damaged, _quantised_positions(read_ply(source).gaussians))
    return {"source": source, "sog": sog, "damaged": damaged}


def _eval_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, object]:
    capsys.readouterr()
    assert main(["eval", *args, *SIZE, "--json", "-q"]) == 0
    report: dict[str, object] = json.loads(capsys.readouterr().out)
    return report


def test_eval_of_a_scene_against_itself(
    donut_files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    src = str(donut_files["source"])
    report = _eval_json(capsys, src, src, "--views", "3")
    summary = report["summary"]
    assert isinstance(summary, dict) and isinstance(report["rows"], list)
    assert summary["images"] == 3 and summary["identical"] == 3
    assert summary["psnr_mean"] is None and summary["ssim_mean"] == 1.0  # null = inf in JSON
    assert [(r["t"], r["view"], r["psnr"], r["mse"]) for r in report["rows"]] == [
        (0.0, v, None, 0.0) for v in range(3)
    ]
    assert main(["eval", src, src, *SIZE, "--views", "2", "-q"]) == 0
    text = capsys.readouterr().out
    assert "mean: PSNR inf dB, SSIM 1.00000 over 2 images, 2 identical" in text
    assert text.count(" inf  1.00000") == 2


def test_eval_of_a_sog_round_trip_and_of_damaged_positions(
    donut_files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    src = str(donut_files["source"])
    whole = _eval_json(capsys, src, str(donut_files["sog"]))
    sizes = [donut_files[name].stat().st_size for name in ("source", "sog")]
    assert whole["bytes"] == {"reference": sizes[0], "candidate": sizes[1]}
    sog = whole["summary"]
    bad = _eval_json(capsys, src, str(donut_files["damaged"]))["summary"]
    assert isinstance(sog, dict) and isinstance(bad, dict)
    assert sog["identical"] == 0 and 45.0 < sog["psnr_mean"] < 90.0
    assert sog["psnr_worst"]["psnr"] > 40.0 and sog["ssim_mean"] > 0.999
    assert bad["psnr_mean"] < sog["psnr_mean"] - 10.0
    assert bad["ssim_mean"] < sog["ssim_mean"]


def test_eval_text_table_and_plot(
    donut_files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plot = tmp_path / "psnr.png"
    src, sog = str(donut_files["source"]), str(donut_files["sog"])
    argv = ["eval", src, sog, *SIZE, "--views", "2", "--plot", str(plot), "-q"]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[3].split() == ["t", "(s)", "view", "PSNR", "(dB)", "SSIM"]
    rows = [line.split() for line in lines[4:6]]
    assert [r[:2] for r in rows] == [["0", "0"], ["0", "1"]]
    assert all(40.0 < float(r[2]) < 90.0 and 0.99 < float(r[3]) <= 1.0 for r in rows)
    assert lines[-2] == f"plot: {plot}"
    sizes = donut_files["source"].stat().st_size, donut_files["sog"].stat().st_size
    ratio = sizes[1] / sizes[0]
    assert (
        lines[-1]
        == f"bytes: reference {sizes[0]:,}, candidate {sizes[1]:,} ({ratio:.3g}x the reference)"
    )
    with Image.open(plot) as image:
        assert image.format == "PNG" and image.size == (800, 420)
        pixels = np.asarray(image.convert("RGB"))
    assert np.any(np.all(pixels == (31, 119, 180), axis=2))  # the mean line is drawn
    assert main(argv) == 1  # the plot exists: refused without --force
    assert "already exists" in capsys.readouterr().err
    assert main([*argv, "--force"]) == 0


# --- 4D: a segmented container against its source ------------------------------------------


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scene, Path]:
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=1)
    path = tmp_path_factory.mktemp("clip") / "clip.tsogs"
    segment_scene(scene, path, SegmentOptions(window_s=0.5))
    return scene, path


def test_eval_of_a_container_against_its_source(clip: tuple[Scene, Path]) -> None:
    scene, path = clip
    setup = CameraSetup(views=2, width=160, height=120)
    with open_source(path) as stream:
        assert stream.kind == "tsogs" and stream.span == (0.0, 2.0)
        report = evaluate(scene_source(scene), stream, times=3, setup=setup)
    times = sample_times((0.0, 2.0), 3)
    assert times == pytest.approx([1 / 3, 1.0, 5 / 3])
    assert [(r.t, r.view) for r in report.rows] == [(t, v) for t in times for v in (0, 1)]
    assert all(40.0 < r.psnr < math.inf and r.ssim > 0.999 for r in report.rows)
    assert [s.t for s in report.times()] == sorted({r.t for r in report.rows})


def test_eval_cli_on_a_container_and_its_unpacked_folder(
    clip: tuple[Scene, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, path = clip
    folder = tmp_path / "unpacked"
    with open_stream(path) as reader:
        reader.unpack(folder)
    report = _eval_json(capsys, str(path), str(folder), "--times", "3", "--views", "2")
    summary = report["summary"]
    assert isinstance(summary, dict) and summary["images"] == 6 and summary["identical"] == 6


def test_eval_reads_a_stream_url_and_a_file_url(
    clip: tuple[Scene, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    _, path = clip
    server = ThreadedServer(make_app(path.parent))
    try:
        url = f"http://127.0.0.1:{server.port}/files/{path.name}"
        report = _eval_json(capsys, path.as_uri(), url, "--times", "2", "--views", "1")
    finally:
        server.stop()
    summary = report["summary"]
    assert isinstance(summary, dict) and summary["images"] == 2 and summary["identical"] == 2
    assert report["candidate"] == url


def test_eval_refuses_a_reading_option_that_fits_neither_input(
    clip: tuple[Scene, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    _, path = clip
    assert main(["eval", str(path), str(path), "--fps", "30", *SIZE, "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("tsog: error: --fps: applies to ply-sequence, sog-sequence inputs")


# --- tsog render ---------------------------------------------------------------------------


def test_render_writes_a_png_and_refuses_to_overwrite(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "view.png"
    argv = ["render", str(samples / DONUT), "--view", "1", "--views", "4", *SIZE]
    assert main([*argv, "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().out.strip() == f"{out}: 160x120, t = 0 s, view 1"
    with Image.open(out) as image:
        assert image.size == (160, 120) and image.mode == "RGB"
        pixels = np.asarray(image)
    assert pixels.max() > 100 and pixels[0, 0].tolist() == [0, 0, 0]  # scene on a black ground
    assert main([*argv, "-o", str(out), "-q"]) == 1
    assert "already exists" in capsys.readouterr().err
    white = tmp_path / "white.png"
    assert main([*argv, "--background", "1,1,1", "-o", str(white), "-q"]) == 0
    with Image.open(white) as image:
        assert np.asarray(image)[0, 0].tolist() == [255, 255, 255]


def test_cameras_json_gives_the_views_it_describes(
    samples: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The orbit written as a 3DGS cameras.json (at another size) renders the same images."""
    source = samples / DONUT
    orbit = scene_orbit(read_ply(source).gaussians, 4, 320, 240)
    entries = [
        {
            "id": i,
            "img_name": c.name,
            "width": c.width,
            "height": c.height,
            "position": list(c.position),
            "rotation": [list(r) for r in c.rotation],  # camera-to-world
            "fx": c.fx,
            "fy": c.fy,
        }
        for i, c in enumerate(orbit)
    ]
    cameras = tmp_path / "cameras.json"
    cameras.write_text(json.dumps(entries))
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    base = ["render", str(source), "--view", "2", *SIZE, "-q"]
    assert main([*base, "--views", "4", "-o", str(a)]) == 0
    assert main([*base, "--cameras", str(cameras), "-o", str(b)]) == 0
    with Image.open(a) as image_a, Image.open(b) as image_b:
        assert psnr(np.asarray(image_a), np.asarray(image_b)) > 60.0
    report = _eval_json(capsys, str(source), str(source), "--cameras", str(cameras))
    assert [r["view"] for r in report["rows"]] == [0, 1, 2, 3]  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--view", "4"], "no view 4; there are views 0-3"),
        (["--background", "2,0,0"], "--background"),
    ],
)
def test_render_errors_are_one_line(
    samples: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    out = tmp_path / "x.png"
    argv = ["render", str(samples / DONUT), "--views", "4", *extra, "-o", str(out), "-q"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("tsog: error:") and message in err and err.count("\n") == 1
    assert not out.exists()


def test_help_has_examples(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("render", "eval"):
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"])
        assert exit_info.value.code == 0
        assert f"examples:\n  tsog {command} " in capsys.readouterr().out


def test_up_axis_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "s.sog"
    write_chunk_files(scene, encode_chunk(small_scene(TimelineType.CENTER_SCALE)), overwrite=False)
    out = tmp_path / "v.png"
    base = ["render", str(scene), "--width", "64", "--height", "48", "-q"]
    assert main([*base, "--up", "0,-1,0", "-o", str(out)]) == 0 and out.exists()
    assert main([*base, "--up", "0,0,0", "-o", str(tmp_path / "w.png")]) == 1
    assert "--up" in capsys.readouterr().err
