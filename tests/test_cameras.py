"""Capture cameras: cameras.json, COLMAP text and binary models, .splatv headers, where they
are found beside an input, the floater-proof framing, and their trip through a container."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import missing_optional
from helpers import ThreadedServer, write_ply_frames
from tsog_stream import framing
from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.constants import MAX_CAMERAS
from tsog_stream.errors import FormatError, InputError, printable
from tsog_stream.framing import (
    FRAMING_NAME,
    coverage,
    default_view,
    dense_core,
    look_at,
    looks_at_core,
    opening_view,
    scene_up,
    world_to_camera,
)
from tsog_stream.io.cameras import find_cameras, read_cameras
from tsog_stream.io.ply import read_ply, write_ply
from tsog_stream.io.readers import load_scene
from tsog_stream.model import Gaussians, Scene, Timeline, TimelineType
from tsog_stream.render import from_capture, render, to_uint8
from tsog_stream.render.metrics import psnr
from tsog_stream.schemas.cameras import Camera, HeaderCamera
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app

HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"


def ring_cameras(count: int = 3) -> list[Camera]:
    """Cameras on a circle around (5, 0, 0) (where blob_with_floaters is), y down (COLMAP
    style), looking at it."""
    cameras = []
    for k in range(count):
        phi = 2 * math.pi * k / count
        eye = np.array([5 + 4 * math.sin(phi), -1.0, -4 * math.cos(phi)])
        c2w = look_at(eye, [5, 0, 0], [0, -1, 0])[:3, :3].T
        cameras.append(
            Camera(
                name=f"img_{k:03d}.png",
                width=800,
                height=600,
                fx=700.0 + k,
                fy=705.0 + k,
                cx=401.5,
                cy=299.0,
                position=tuple(eye.tolist()),
                rotation=tuple(tuple(r) for r in c2w.tolist()),
            )
        )
    return cameras


def _qvec(m: np.ndarray) -> tuple[float, float, float, float]:
    """A unit quaternion (w, x, y, z) of a rotation matrix: the eigenvector of the largest
    eigenvalue of Bar-Itzhack's symmetric 4x4 matrix (any rotation, no division by zero)."""
    k = (
        np.array(
            [
                [m[0, 0] - m[1, 1] - m[2, 2], 0, 0, 0],
                [m[1, 0] + m[0, 1], m[1, 1] - m[0, 0] - m[2, 2], 0, 0],
                [m[2, 0] + m[0, 2], m[2, 1] + m[1, 2], m[2, 2] - m[0, 0] - m[1, 1], 0],
                [m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], np.trace(m)],
            ]
        )
        / 3.0
    )
    _, vectors = np.linalg.eigh(k, UPLO="L")
    x, y, z, w = (float(v) for v in vectors[:, -1])
    return (w, x, y, z) if w >= 0 else (-w, -x, -y, -z)


Pose = tuple[int, tuple[float, float, float, float], list[float], int]


def _poses(cameras: list[Camera]) -> list[Pose]:
    """(image id, qvec, tvec, camera id) per camera, ids in reverse name order."""
    out: list[Pose] = []
    for k, c in enumerate(cameras):
        w2c = world_to_camera(c)
        out.append((len(cameras) - k, _qvec(w2c[:3, :3]), w2c[:3, 3].tolist(), k + 1))
    return out


def write_colmap_text(folder: Path, cameras: list[Camera]) -> None:
    """cameras.txt (PINHOLE) and images.txt with a 2D-points line per image."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:"]
    for k, c in enumerate(cameras):
        lines.append(f"{k + 1} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}")
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for (image_id, q, t, cam), c in zip(_poses(cameras), cameras, strict=True):
        lines.append(" ".join(map(repr, (image_id, *q, *t, cam))) + f" {c.name}")
        lines.append("12.5 30.25 -1 400.0 2.0 7")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")


def write_colmap_binary(folder: Path, cameras: list[Camera]) -> None:
    """cameras.bin (OPENCV: 8 parameters, distortion ignored) and images.bin with 2D points."""
    folder.mkdir(parents=True, exist_ok=True)
    data = struct.pack("<Q", len(cameras))
    for k, c in enumerate(cameras):
        data += struct.pack("<iiQQ", k + 1, 4, c.width, c.height)
        data += struct.pack("<8d", c.fx, c.fy, c.cx, c.cy, 0.01, -0.02, 0.0, 0.0)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(cameras))
    for (image_id, q, t, cam), c in zip(_poses(cameras), cameras, strict=True):
        data += struct.pack("<i7di", image_id, *q, *t, cam) + c.name.encode() + b"\0"
        data += struct.pack("<Q", 3) + struct.pack("<ddq", 1.0, 2.0, -1) * 3
    (folder / "images.bin").write_bytes(data)


def assert_same_cameras(got: list[Camera], want: list[Camera]) -> None:
    assert [c.name for c in got] == [c.name for c in want]
    for a, b in zip(got, want, strict=True):
        assert (a.width, a.height) == (b.width, b.height)
        np.testing.assert_allclose(
            [a.fx, a.fy, *a.principal_point], [b.fx, b.fy, *b.principal_point], rtol=1e-12
        )
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
        np.testing.assert_allclose(a.rotation, b.rotation, atol=1e-9)


@pytest.mark.parametrize("writer", [write_colmap_text, write_colmap_binary])
def test_colmap_models_give_the_cameras_they_describe(tmp_path: Path, writer: object) -> None:
    cameras = ring_cameras(4)
    writer(tmp_path / "sparse" / "0", cameras)  # type: ignore[operator]
    for where in (tmp_path, tmp_path / "sparse" / "0", tmp_path / "sparse" / "0" / "images.txt"):
        if where.suffix == ".txt" and writer is write_colmap_binary:
            continue
        found = read_cameras(where)
        assert_same_cameras(found.cameras, cameras)  # name order, not image-id order


def test_a_cameras_json_round_trips_and_draws_as_the_player_shows_it(tmp_path: Path) -> None:
    cameras = ring_cameras(2)
    entries = [
        {
            "id": i,
            "img_name": c.name,
            "width": c.width,
            "height": float(c.height),
            "position": list(c.position),
            "rotation": [list(r) for r in c.rotation],
            "fx": c.fx,
            "fy": c.fy,
        }
        for i, c in enumerate(cameras)
    ]
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(entries))
    got = read_cameras(path).cameras
    assert got[0].cx is None and got[0].principal_point == (400.0, 300.0)
    np.testing.assert_allclose(got[1].rotation, cameras[1].rotation, atol=1e-15)
    # Drawn in a 640x480 window: the vertical field of view is kept, pixels stay square.
    camera = from_capture(got[0], 640, 480)
    assert camera.fy == pytest.approx(705.0 * 480 / 600) and camera.fx == pytest.approx(560.0)
    point = np.array([*got[0].position, 1.0]) + np.append(np.array(got[0].rotation)[:, 2], 0)
    x, y, z, _ = world_to_camera(camera) @ point  # one unit straight ahead
    assert (x, y, z) == pytest.approx((0.0, 0.0, 1.0))


@pytest.mark.parametrize(
    ("name", "data", "message"),
    [
        ("cameras.json", b"{", "not valid UTF-8 JSON"),
        ("cameras.json", b"[]", "non-empty JSON list"),
        ("cameras.json", b"[1]", "camera 0 is not a JSON object"),
        ("cameras.json", json.dumps([{"width": 1}] * (MAX_CAMERAS + 1)).encode(), "more than"),
    ],
)
def test_bad_camera_files_are_format_errors(
    tmp_path: Path, name: str, data: bytes, message: str
) -> None:
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(FormatError, match=message):
        read_cameras(path)


def _entry(**changes: object) -> dict[str, object]:
    c = ring_cameras(1)[0]
    entry: dict[str, object] = {
        "img_name": "a",
        "width": 800,
        "height": 600,
        "fx": 700.0,
        "fy": 700.0,
        "position": list(c.position),
        "rotation": [list(r) for r in c.rotation],
    }
    entry.update(changes)
    return entry


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"rotation": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}, "not orthonormal"),
        ({"rotation": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "reflection"),
        ({"fx": float("nan")}, "[0].fx"),
        ({"fy": -1}, "[0].fy"),
        ({"width": 0}, "[0].width"),
        ({"width": 2**40}, "[0].width"),
        ({"position": [0, 0]}, "[0].position"),
    ],
)
def test_bad_cameras_are_named(tmp_path: Path, changes: dict[str, object], field: str) -> None:
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([_entry(**changes)]).replace("NaN", '"NaN"'))
    with pytest.raises(FormatError) as info:
        read_cameras(path)
    assert field in str(info.value)


def _binary_model(tmp_path: Path) -> tuple[bytes, bytes]:
    write_colmap_binary(tmp_path, ring_cameras(2))
    return (tmp_path / "cameras.bin").read_bytes(), (tmp_path / "images.bin").read_bytes()


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda c, i: (struct.pack("<Q", 2**60) + c[8:], i), "declares 1152921504606846976"),
        (lambda c, i: (c, struct.pack("<Q", 2**60) + i[8:]), "declares 1152921504606846976"),
        (lambda c, i: (c[:-9], i), "ends early"),
        (lambda c, i: (c[:12] + struct.pack("<i", 99) + c[16:], i), "unknown model id 99"),
        (
            lambda c, i: (c, struct.pack("<Q", 1) + i[8:72] + b"no-terminator" * 2),
            "ends inside an image name",
        ),
        (lambda c, i: (c, i[: 8 + 64] + b"x" * 5000), "longer than 4096"),
        (
            lambda c, i: (
                c,
                i[:84] + struct.pack("<Q", 2**50) + i[92:],  # the count after "img_000.png"
            ),
            "points past the end",
        ),
    ],
)
def test_hostile_binary_models_are_refused_before_allocating(
    tmp_path: Path, damage: object, message: str
) -> None:
    cams, imgs = damage(*_binary_model(tmp_path))  # type: ignore[operator]
    (tmp_path / "cameras.bin").write_bytes(cams)
    (tmp_path / "images.bin").write_bytes(imgs)
    with pytest.raises(FormatError, match=message):
        read_cameras(tmp_path)


@pytest.mark.parametrize(
    ("cameras_txt", "images_txt", "message"),
    [
        ("1 PINHOLE 800 600 700 700 400\n", "", "PINHOLE takes 4 parameters, found 3"),
        ("1 WEIRD 800 600 1\n", "", "expected CAMERA_ID MODEL"),
        ("1 PINHOLE 800 600 700 nan 400 300\n", "", "non-finite"),
        ("1 PINHOLE 800 600 700 700 400 300\n", "1 1 0 0 0 0 0 0 2 a.png\n\n", "unknown camera 2"),
        ("1 PINHOLE 800 600 700 700 400 300\n", "1 0 0 0 0 0 0 0 1 a.png\n\n", "zero pose"),
        ("1 PINHOLE 800 600 700 700 400 300\n", "1 1 0 0\n", "expected IMAGE_ID"),
        ("1 PINHOLE 800 600 700 700 400 300\n", "# none\n", "no registered images"),
    ],
)
def test_bad_text_models_are_format_errors(
    tmp_path: Path, cameras_txt: str, images_txt: str, message: str
) -> None:
    (tmp_path / "cameras.txt").write_text(cameras_txt)
    (tmp_path / "images.txt").write_text(images_txt)
    with pytest.raises(FormatError, match=message):
        read_cameras(tmp_path)


def test_a_huge_points_line_is_skipped_in_pieces(tmp_path: Path) -> None:
    write_colmap_text(tmp_path, ring_cameras(2))
    text = (tmp_path / "images.txt").read_text().splitlines()
    text[2] = "1.0 2.0 -1 " * 300_000  # a 3.3 MB 2D-points line
    (tmp_path / "images.txt").write_text("\n".join(text) + "\n")
    assert_same_cameras(read_cameras(tmp_path).cameras, ring_cameras(2))


def blob_with_floaters(seed: int = 0) -> Gaussians:
    """2000 opaque Gaussians within 1 unit of (5, 0, 0) and 40 faint floaters 200 units away."""
    rng = np.random.default_rng(seed)
    core = rng.normal(size=(2000, 3)) * 0.4 + [5.0, 0.0, 0.0]
    floaters = rng.normal(size=(40, 3))
    floaters = 200 * floaters / np.linalg.norm(floaters, axis=1, keepdims=True)
    means = np.concatenate([core, floaters])
    n = len(means)
    opacity = np.concatenate([np.full(2000, 3.0), np.full(40, -1.0)])
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Gaussians.from_arrays(means, np.full((n, 3), -3.0), quats, opacity, np.zeros((n, 3)))


def test_the_framing_fits_the_dense_core_not_the_floaters() -> None:
    gaussians = blob_with_floaters()
    centre, radius = dense_core(gaussians)
    np.testing.assert_allclose(centre, [5, 0, 0], atol=0.1)
    assert 0.5 < radius < 1.0  # 80 % of the weight of a sigma-0.4 blob; the box is 400 wide
    view = default_view(gaussians, [])
    assert view is not None and view.name == FRAMING_NAME
    camera = from_capture(view, 320, 240)
    points = np.c_[gaussians.means[:2000], np.ones(2000)] @ world_to_camera(camera).T
    cx, cy = camera.principal_point
    x = camera.fx * points[:, 0] / points[:, 2] + cx
    y = camera.fy * points[:, 1] / points[:, 2] + cy
    inside = (points[:, 2] > 0) & (x >= 0) & (x < 320) & (y >= 0) & (y < 240)
    assert inside.mean() > 0.95 and (np.abs(x - 160) < 80).mean() > 0.5
    # Up is -y without cameras (COLMAP captures), the capture cameras' own up with them.
    np.testing.assert_allclose(scene_up([]), [0, -1, 0])
    np.testing.assert_allclose(scene_up(ring_cameras()), [0, -1, 0], atol=1e-12)
    # A capture camera that sees the scene opens it; one that looks away does not.
    facing = look_at([5.0, -1.0, -4.0], [5.0, 0.0, 0.0], [0, -1, 0])[:3, :3].T
    seeing = ring_cameras(1)[0].model_copy(
        update={"position": (5.0, -1.0, -4.0), "rotation": tuple(map(tuple, facing.tolist()))}
    )
    away = seeing.model_copy(update={"rotation": tuple(map(tuple, (-facing).tolist()))})
    assert coverage(gaussians, seeing) > 0.95 and coverage(gaussians, away) < 0.05
    assert opening_view(gaussians, [seeing, away]) == (
        seeing,
        "capture camera 0 sees 99% of the scene",
    )
    view, why = opening_view(gaussians, [away, seeing])
    assert view.name == FRAMING_NAME
    assert why == "capture camera 0 sees only 0% of the scene and is not aimed at its dense core"
    with pytest.raises(InputError, match="without a visible Gaussian"):
        dense_core(Gaussians.empty(0))
    assert default_view(Gaussians.empty(0), []) is None


def test_a_big_scene_is_framed_from_a_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    """Above FRAMING_SAMPLE Gaussians the view is measured on every k-th: the same core
    within a few percent of its radius, floaters still ignored."""
    gaussians = blob_with_floaters()
    whole = dense_core(gaussians)
    monkeypatch.setattr(framing, "FRAMING_SAMPLE", len(gaussians) // 7)
    sample = framing.framing_sample(gaussians)
    assert len(sample) <= len(gaussians) // 7
    centre, radius = dense_core(sample)
    assert np.linalg.norm(centre - whole[0]) < 0.05 * whole[1]
    assert abs(radius - whole[1]) < 0.05 * whole[1]
    monkeypatch.setattr(framing, "FRAMING_SAMPLE", len(gaussians))
    assert framing.framing_sample(gaussians) is gaussians


def test_cameras_are_found_where_trainers_leave_them(tmp_path: Path) -> None:
    gaussians = blob_with_floaters()
    model = tmp_path / "model"
    ply = model / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    ply.parent.mkdir(parents=True)
    write_ply(ply, gaussians)
    assert find_cameras(ply) is None
    cameras = ring_cameras(3)
    (model / "cameras.json").write_text(
        json.dumps([{"img_name": c.name, **c.model_dump(exclude={"name"})} for c in cameras])
    )
    loaded = load_scene(ply)
    assert_same_cameras(loaded.cameras, cameras)
    assert loaded.cameras_source.endswith("cameras.json")
    # A COLMAP model beside a frame folder; one that cannot be read is noted, not fatal.
    frames = tmp_path / "frames"
    frames.mkdir()
    write_ply(frames / "frame_000.ply", gaussians)
    write_ply(frames / "frame_001.ply", gaussians)
    write_colmap_binary(frames / "sparse" / "0", cameras)
    assert_same_cameras(load_scene(frames).cameras, cameras)
    (frames / "sparse" / "0" / "images.bin").write_bytes(b"\1")
    loaded = load_scene(frames)
    assert loaded.cameras == [] and any("ignored the cameras beside" in n for n in loaded.notes)
    # Given explicitly, a broken file is the caller's error.
    with pytest.raises(FormatError):
        load_scene(frames / "frame_000.ply", cameras=frames / "sparse" / "0")


def test_splatv_cameras_come_from_its_header(samples: Path, tmp_path: Path) -> None:
    loaded = load_scene(samples / HANABI)
    (camera,) = loaded.cameras
    assert (camera.name, camera.width, camera.height, camera.fx) == (
        "camera_0001",
        1920,
        1080,
        1000.0,
    )
    assert camera.position == (0.0, 0.0, 3.0)
    data = (samples / HANABI).read_bytes()
    length = struct.unpack_from("<I", data, 4)[0]
    header = json.loads(data[8 : 8 + length])
    header[0]["cameras"][0]["rotation"] = [[1, 0, 0]]
    raw = json.dumps(header).encode()
    broken = tmp_path / "broken.splatv"
    broken.write_bytes(data[:4] + struct.pack("<I", len(raw)) + raw + data[8 + length :])
    loaded = load_scene(broken)
    assert loaded.cameras == [] and len(loaded.scene) > 0
    assert any(n.startswith("ignored the file's cameras") for n in loaded.notes)


def test_a_container_carries_the_cameras_and_the_opening_view(tmp_path: Path) -> None:
    gaussians = blob_with_floaters()
    n = len(gaussians)
    timeline = Timeline(TimelineType.CENTER_SCALE, np.full(n, 0.5), np.full(n, 2.0), scene_length=1)
    scene = Scene(gaussians, timeline)
    cameras = ring_cameras(3)
    segment_scene(scene, tmp_path / "with.tsogs", SegmentOptions(), cameras=cameras)
    segment_scene(scene, tmp_path / "without.tsogs", SegmentOptions())
    with open_stream(tmp_path / "with.tsogs") as reader:
        manifest = reader.index.manifest
        assert manifest.cameras == cameras and manifest.view == cameras[0]
    with open_stream(tmp_path / "without.tsogs") as reader:
        manifest = reader.index.manifest
        assert manifest.cameras == [] and manifest.view == default_view(scene.gaussians, [])


def test_cli_segment_info_and_render_use_the_cameras(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "frames"
    ply = write_ply_frames(folder, (blob_with_floaters(seed=k) for k in range(3)))[0]
    write_colmap_text(folder / "sparse" / "0", ring_cameras(3))
    out = tmp_path / "scene.tsogs"
    assert main(["segment", str(folder), "-o", str(out), "--temporal", "off", "-q"]) == 0
    said = capsys.readouterr().out
    assert "3 capture cameras from " in said
    assert "opens from the first (img_000.png; capture camera 0 sees 99% of the scene)" in said
    assert main(["info", str(out), "--json", "-q"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["cameras"]["count"] == 3
    assert info["cameras"]["opens_from"].startswith("capture camera img_000.png at (")
    # The default render is capture camera 0, from the input and from its container alike.
    images = {}
    for name, argv in {
        "input": [str(ply)],
        "container": [str(out)],
        "camera0": [str(out), "--camera", "0"],
    }.items():
        png = tmp_path / f"{name}.png"
        assert main(["render", *argv, "--width", "96", "-o", str(png), "-q"]) == 0
        images[name] = png.read_bytes()
    assert images["container"] == images["camera0"]
    other = tmp_path / "camera1.png"
    assert main(["render", str(out), "--camera", "1", "--width", "96", "-o", str(other), "-q"]) == 0
    assert other.read_bytes() != images["camera0"]
    capsys.readouterr()
    assert main(["render", str(out), "--camera", "3", "-o", str(tmp_path / "x.png"), "-q"]) == 1
    err = capsys.readouterr().err
    assert err == "tsog: error: --camera: no camera 3; there are cameras 0-2\n"


@pytest.mark.parametrize(
    "argv",
    [
        ["--cameras", "{tmp}/missing.json"],
        ["--cameras", "{tmp}"],
        ["--camera", "0"],
        ["--camera", "0", "--view", "1"],
        ["--camera", "-1"],
    ],
)
def test_camera_options_fail_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    ply = tmp_path / "scene.ply"
    write_ply(ply, blob_with_floaters())
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        code = main(["render", str(ply), *args, "-o", str(tmp_path / "x.png"), "-q"])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code  # type: ignore[assignment]
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code == 2:  # argparse: usage, then one error line
        assert err.splitlines()[-1].startswith("tsog render: error: argument --camera")
    else:
        assert code == 1 and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()


def test_a_real_capture_renders_from_its_own_camera_by_default(
    optional_samples: Path, tmp_path: Path
) -> None:
    """spinach_4.splatv opened as a new user would: its container's default render is exactly
    the CPU render from the capture camera, and the raw file's is the same picture."""
    capture = optional_samples / "4d/splatv/macaburguera_spinach_4.splatv"
    loaded = load_scene(capture)
    (camera,) = loaded.cameras
    container = tmp_path / "spinach.tsogs"
    assert main(["segment", str(capture), "-o", str(container), "-q"]) == 0
    with open_stream(container) as reader:
        assert reader.index.manifest.cameras == [camera]
        frame = reader.frame_at(0.5)
    reference = to_uint8(render(frame, from_capture(camera, 640, 480)))
    size = ["--t", "0.5", "--width", "640", "--height", "480", "-q"]
    images = {}
    for name, target in (("container", container), ("raw", capture)):
        out = tmp_path / f"{name}.png"
        assert main(["render", str(target), *size, "-o", str(out)]) == 0
        with Image.open(out) as image:
            images[name] = np.asarray(image)
    assert np.array_equal(images["container"], reference)
    assert psnr(images["raw"], reference) > 35  # the raw file at full precision, q90 stored


# --- a 360-degree capture opens from its camera; a header's camera looking past does not -----

GUITAR = "3dgs/pc_guitar.compressed.ply"
"""A real static capture (90,854 Gaussians, a guitar standing in the scene's y-down world)."""
MACABURGUERA = {
    "macaburguera_coffee10.splatv": "own",
    "macaburguera_coffeeshort2.splatv": "own",
    "macaburguera_spinach_4.splatv": "own",
    "macaburguera_yellow_clip2.splatv": "framing",
}
"""How each real capture opens: its header camera (one converter's, the same in all) sees
most of the first three; it looks past yellow_clip2's core, a corner."""


def ring_around_core(gaussians: Gaussians, count: int = 12, radii: float = 1.0) -> list[Camera]:
    """``count`` 1280x720 cameras (50-degree vertical view) on a circle of ``radii`` core
    radii around the dense core, a little above it (y down), each looking at its centre: a
    360-degree capture whose cameras stand inside the scene."""
    centre, core_radius = dense_core(gaussians)
    radius = radii * core_radius
    focal = 360 / math.tan(math.radians(25))
    cameras = []
    for k in range(count):
        phi = 2 * math.pi * k / count
        eye = centre + radius * np.array([math.cos(phi), -0.2, math.sin(phi)])
        c2w = look_at(eye, centre, [0, -1, 0])[:3, :3].T
        cameras.append(
            Camera(
                name=f"ring_{k:02d}.jpg",
                width=1280,
                height=720,
                fx=focal,
                fy=focal,
                position=tuple(eye.tolist()),
                rotation=tuple(tuple(r) for r in c2w.tolist()),
            )
        )
    return cameras


def write_cameras_json(path: Path, cameras: list[Camera]) -> None:
    """A 3DGS cameras.json of ``cameras`` (img_name, no principal point)."""
    entries = [
        {"id": k, "img_name": c.name, **c.model_dump(exclude={"name", "cx", "cy"})}
        for k, c in enumerate(cameras)
    ]
    path.write_text(json.dumps(entries))


def test_a_360_capture_opens_from_its_first_camera(samples: Path, tmp_path: Path) -> None:
    """The first camera of a ring inside a real scene sees under half of it, yet looks at its
    dense core: the scene opens there, in the library, tsog segment and tsog render alike. The
    same camera as a format header's is not trusted so far."""
    gaussians = read_ply(samples / GUITAR).gaussians
    cameras = ring_around_core(gaussians, radii=0.8)
    seen = coverage(gaussians, cameras[0])
    assert 0.2 < seen < framing.MIN_COVERAGE
    assert looks_at_core(cameras[0], dense_core(gaussians))
    view, why = opening_view(gaussians, cameras)
    assert view == cameras[0]
    assert why == f"capture camera 0 looks at the dense core (sees {seen:.0%} of the scene)"
    header = [HeaderCamera.of(c) for c in cameras]
    view, why = opening_view(gaussians, header)
    assert (
        view.name == FRAMING_NAME and why == f"capture camera 0 sees only {seen:.0%} of the scene"
    )
    # A camera on the ring looking along it, not at the core, is still refused.
    aside = cameras[0].model_copy(update={"rotation": cameras[3].rotation})
    assert coverage(gaussians, aside) < framing.MIN_COVERAGE
    assert opening_view(gaussians, [aside])[0].name == FRAMING_NAME
    # tsog segment stores that view; tsog render's default is capture camera 0's picture.
    folder = tmp_path / "capture"
    folder.mkdir()
    ply = folder / "guitar.compressed.ply"
    ply.write_bytes((samples / GUITAR).read_bytes())
    write_cameras_json(folder / "cameras.json", cameras)
    container = tmp_path / "guitar.tsogs"
    assert main(["segment", str(ply), "-o", str(container), "-q"]) == 0
    with open_stream(container) as reader:
        assert reader.index.manifest.view == read_cameras(folder / "cameras.json").cameras[0]
    images = {}
    for name, argv in {
        "default": [str(ply)],
        "camera0": [str(ply), "--camera", "0"],
        "container": [str(container)],
    }.items():
        out = tmp_path / f"{name}.png"
        assert main(["render", *argv, "--width", "160", "-o", str(out), "-q"]) == 0
        with Image.open(out) as png:
            images[name] = np.asarray(png)
    assert images["default"].shape == (90, 160, 3)
    assert np.array_equal(images["default"], images["camera0"])
    assert psnr(images["container"], images["camera0"]) > 30


@pytest.mark.parametrize("name", sorted(MACABURGUERA))
def test_the_header_camera_opens_only_the_captures_it_shows(
    name: str, optional_samples: Path
) -> None:
    """Every macaburguera .splatv carries one converter's camera: it opens the captures it
    sees most of, and yellow_clip2 (where it shows a corner) opens on a framing, as a header
    camera and as a capture camera alike (it looks past the dense core)."""
    path = optional_samples / "4d/splatv" / name
    if not path.is_file():
        missing_optional(f"4d/splatv/{name}")
    loaded = load_scene(path)
    (camera,) = loaded.cameras
    assert isinstance(camera, HeaderCamera)
    first = loaded.scene.at(0.0)
    view, why = opening_view(first, loaded.cameras)
    if MACABURGUERA[name] == "own":
        assert view is camera and why.startswith("capture camera 0 sees ")
        return
    assert view.name == FRAMING_NAME and why.startswith("capture camera 0 sees only ")
    assert not looks_at_core(camera, dense_core(first))
    trusted = Camera.model_validate(camera.model_dump())
    assert opening_view(first, [trusted])[0].name == FRAMING_NAME


# --- camera names from files and servers reach the terminal escaped ---------------------------

HOSTILE_NAMES = {
    "CSI colour": "\x1b[31mred\x1b[0m",
    "OSC 8 hyperlink": "\x1b]8;;http://127.0.0.1/\x07link\x1b]8;;\x07",
    "carriage return": "img\rFAKE",
    "bell": "img\x07",
    "bidi override": "img\u202egnp.exe",
    "C1 CSI": "img\u009b31m",
}


def assert_printable(text: str) -> None:
    """Nothing a terminal would act on: every character printable, or a line break."""
    raw = sorted({ascii(c) for c in text if not (c.isprintable() or c == "\n")})
    assert not raw, f"raw control characters reached the terminal: {raw}"


@pytest.mark.parametrize("kind", sorted(HOSTILE_NAMES))
def test_camera_names_reach_the_terminal_escaped(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A hostile image name in a cameras.json, a COLMAP images.bin and a container's stored
    cameras (local and served) through every command that prints camera names."""
    hostile = HOSTILE_NAMES[kind]
    cameras = [c.model_copy(update={"name": f"{hostile}{k}"}) for k, c in enumerate(ring_cameras())]
    shown = printable(f"{hostile}0")
    single = tmp_path / "single"
    single.mkdir()
    ply = single / "scene.ply"
    write_ply(ply, blob_with_floaters())
    write_cameras_json(single / "cameras.json", cameras)
    frames = tmp_path / "frames"
    write_ply_frames(frames, (blob_with_floaters(seed=k) for k in range(2)))
    write_colmap_binary(frames / "sparse" / "0", cameras)
    container = tmp_path / "served" / "scene.tsogs"
    container.parent.mkdir()
    runs = [
        ["info", str(ply)],
        ["render", str(ply), "--width", "32", "-o", str(tmp_path / "a.png")],
        ["render", str(ply), "--camera", "0", "--width", "32", "-o", str(tmp_path / "b.png")],
        ["segment", str(frames), "-o", str(container), "--temporal", "off"],
        ["info", str(container)],
        ["render", str(container), "--width", "32", "-o", str(tmp_path / "c.png")],
    ]
    server = ThreadedServer(make_app(container.parent))
    url = f"http://127.0.0.1:{server.port}/files/scene.tsogs"
    runs += [["info", url], ["render", url, "--width", "32", "-o", str(tmp_path / "d.png")]]
    try:
        for argv in runs:
            assert main([*argv, "-q"]) == 0, argv
            out, err = capsys.readouterr()
            assert_printable(out + err)
            assert shown in out, (argv, out)
    finally:
        server.stop()
