"""The CPU rasterizer against hand-computed cases, invariances and its two backends."""

from __future__ import annotations

import importlib
import json
import math
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image
from pydantic import ValidationError

from conftest import SAMPLES
from helpers import ThreadedServer
from test_invalid_corpus import targets
from tsog_stream import columns
from tsog_stream.cli.main import main
from tsog_stream.constants import SH_C0
from tsog_stream.errors import FormatError, InputError, SourceError
from tsog_stream.framing import world_to_camera
from tsog_stream.io.cameras import parse_cameras_json, read_cameras
from tsog_stream.io.ply import write_ply
from tsog_stream.model import Gaussians, Scene
from tsog_stream.render import (
    Backend,
    Camera,
    load_cameras_json,
    look_at,
    numba_available,
    orbit_cameras,
    project,
    raster,
    render,
    save_png,
    scene_orbit,
    to_uint8,
)
from tsog_stream.render.camera import (
    DEFAULT_PIXELS,
    FOCAL_PER_SIDE,
    MAX_ASPECT,
    RENDER_MAX_PIXELS,
    from_capture,
    stretched,
)
from tsog_stream.render.evaluate import RenderStyle, opening_camera, scene_source
from tsog_stream.render.plot import Series, line_chart
from tsog_stream.render.sh import SH_C1, sh_basis, sh_colors
from tsog_stream.segment import SegmentOptions, segment_scene, segmenter
from tsog_stream.server import make_app

project_module = importlib.import_module("tsog_stream.render.project")  # shadowed by project()
SIZE = 63  # odd: the principal point cx = 31.5 lands on pixel index 31
FOCAL = 100.0
BG = (0.1, 0.2, 0.3)
IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def head_on_camera(size: int = SIZE) -> Camera:
    """Camera at the origin looking down +z (identity world-to-camera)."""
    return Camera(
        width=size, height=size, fx=FOCAL, fy=FOCAL, position=(0.0, 0.0, 0.0), rotation=IDENTITY
    )


def aimed(
    size: tuple[int, int], fx: float, eye: list[float], target: list[float], **more: float
) -> Camera:
    """A camera of ``size`` pixels at ``eye`` looking at ``target``, -y up; ``more``: fy, cx,
    cy (by default fx and the image centre)."""
    c2w = look_at(eye, target, [0, -1, 0])[:3, :3].T
    return Camera(
        width=size[0],
        height=size[1],
        fx=fx,
        fy=more.get("fy", fx),
        cx=more.get("cx"),
        cy=more.get("cy"),
        position=tuple(map(float, eye)),
        rotation=tuple(tuple(row) for row in c2w.tolist()),
    )


def logit(p: float) -> float:
    """The opacity logit of probability ``p``."""
    return math.log(p / (1 - p))


def gaussian(
    mean: tuple[float, float, float],
    sigma: float,
    opacity: float,
    rgb: tuple[float, float, float],
    sh_rest: npt.ArrayLike | None = None,
) -> Gaussians:
    """One isotropic Gaussian with a base colour ``rgb`` (DC only unless ``sh_rest``)."""
    dc = (np.array(rgb) - 0.5) / SH_C0
    return Gaussians.from_arrays(
        [mean],
        [[math.log(sigma)] * 3],
        [[1.0, 0.0, 0.0, 0.0]],
        [logit(opacity)],
        [dc],
        shN=None if sh_rest is None else np.asarray(sh_rest)[None],
    )


def random_scene(n: int, seed: int, sh_coeffs: int = 15) -> Gaussians:
    """``n`` random anisotropic Gaussians in front of the origin, ``sh_coeffs`` SH per channel."""
    rng = np.random.default_rng(seed)
    means = rng.normal([0.0, 0.0, 6.0], [1.0, 1.0, 1.0], (n, 3))
    return Gaussians.from_arrays(
        means,
        rng.normal(-2.5, 0.6, (n, 3)),
        rng.normal(size=(n, 4)),
        rng.normal(0.5, 1.5, n),
        rng.normal(0, 0.8, (n, 3)),
        shN=rng.normal(0, 0.2, (n, sh_coeffs, 3)),
    )


def test_single_gaussian_peak_and_footprint() -> None:
    """Peak = a c + (1 - a) bg; the footprint is the disk alpha >= 1/255, inside 3 sigma tiles."""
    sigma_px, opacity, rgb = 2.0, 0.7, (0.8, 0.4, 0.2)
    scene = gaussian((0.0, 0.0, 5.0), sigma_px * 5.0 / FOCAL, opacity, rgb)
    image = render(scene, head_on_camera(), background=BG, backend="numpy")
    centre = SIZE // 2
    expected = opacity * np.array(rgb) + (1 - opacity) * np.array(BG)
    np.testing.assert_allclose(image[centre, centre], expected, atol=1e-6)

    variance = sigma_px**2 + 0.3  # the low-pass adds 0.3 px^2
    proj = project(scene, head_on_camera())
    assert proj.radius.tolist() == [math.ceil(3 * math.sqrt(variance))] == [7]
    ys, xs = np.mgrid[:SIZE, :SIZE]
    r2 = (xs - centre) ** 2 + (ys - centre) ** 2
    analytic = opacity * np.exp(-0.5 * r2 / variance) >= 1 / 255
    touched = np.any(np.abs(image - np.array(BG, np.float32)) > 0, axis=2)
    assert np.array_equal(touched, analytic)
    assert np.sqrt(r2[touched].max()) <= math.sqrt(2 * variance * math.log(255 * opacity))


def test_front_to_back_order_by_depth_not_input() -> None:
    """The nearer Gaussian dominates; input order does not matter."""
    near = gaussian((0.0, 0.0, 4.0), 0.08, 0.9, (1.0, 0.0, 0.0))
    far = gaussian((0.0, 0.0, 6.0), 0.12, 0.9, (0.0, 1.0, 0.0))
    a = render(Gaussians.concat([near, far]), head_on_camera(), background=BG, backend="numpy")
    b = render(Gaussians.concat([far, near]), head_on_camera(), background=BG, backend="numpy")
    assert np.array_equal(a, b)
    c = SIZE // 2
    red, green, bg = np.eye(3)[0], np.eye(3)[1], np.array(BG)
    expected = 0.9 * red + 0.1 * 0.9 * green + 0.1 * 0.1 * bg
    np.testing.assert_allclose(a[c, c], expected, atol=1e-6)
    assert a[c, c, 0] > 5 * a[c, c, 1]


def test_early_termination_drops_the_gaussian_that_crosses_the_threshold() -> None:
    """Two alpha-0.99 layers leave T = 1e-4 (kept); a third would go below 1e-4 and is dropped."""
    layers = [
        gaussian((0.0, 0.0, z), 0.5, 0.999, rgb)
        for z, rgb in ((4, (1, 0, 0)), (5, (0, 1, 0)), (6, (0, 0, 1)))
    ]
    image = render(Gaussians.concat(layers), head_on_camera(), background=BG, backend="numpy")
    c = SIZE // 2
    t_two = 0.01 * 0.01  # alpha is clamped to 0.99
    expected = np.array([0.99, 0.01 * 0.99, 0.0])
    if t_two * 0.01 >= 1e-4:  # pragma: no cover - guards the arithmetic of the test itself
        pytest.fail("the third layer should terminate the pixel")
    np.testing.assert_allclose(image[c, c], expected + t_two * np.array(BG), atol=1e-7)


def test_sh_degree1_colour_for_a_known_direction() -> None:
    """Direction (2, -3, 6) / 7: 0.5 + C0 dc - C1 y k1 + C1 z k2 - C1 x k3, clamped at 0."""
    dc = np.array([[0.2, -0.1, 0.0]])
    rest = np.array([[[0.3, 0.1, -0.2], [0.4, -0.5, 0.6], [0.7, 0.8, 6.0]]])
    camera_position = np.array([1.0, 1.0, 1.0])
    got = sh_colors(camera_position + np.array([[2.0, -3.0, 6.0]]), dc, rest, camera_position)
    x, y, z = 2 / 7, -3 / 7, 6 / 7
    by_hand = 0.5 + SH_C0 * dc[0] - SH_C1 * y * rest[0, 0] + SH_C1 * z * rest[0, 1]
    by_hand -= SH_C1 * x * rest[0, 2]
    assert by_hand[2] < 0 < by_hand[1] < by_hand[0]  # blue is negative by hand: clamped to 0
    np.testing.assert_allclose(got[0], [by_hand[0], by_hand[1], 0.0], atol=1e-12)


def test_sh_degree1_in_a_rendered_pixel() -> None:
    """Seen along +z only the z band (k = 2nd coefficient) adds: colour = base + C1 k."""
    rest = [[0.0, 0.0, 0.0], [0.2, -0.3, 0.1], [5.0, 5.0, 5.0]]
    scene = gaussian((0.0, 0.0, 5.0), 0.1, 0.6, (0.5, 0.5, 0.5), sh_rest=rest)
    image = render(scene, head_on_camera(), backend="numpy")
    c = SIZE // 2
    expected = 0.6 * (0.5 + SH_C1 * np.array(rest[1]))
    np.testing.assert_allclose(image[c, c], expected, atol=1e-6)


def test_sh_basis_is_orthonormal_on_the_sphere() -> None:
    """The 16 basis functions integrate to the identity (Fibonacci-lattice quadrature)."""
    n = 20000
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = math.pi * (1 + math.sqrt(5)) * k
    ring = np.sqrt(1 - z * z)
    dirs = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=1)
    basis = sh_basis(dirs, 16)
    gram = 4 * math.pi * basis.T @ basis / n
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-3)


def test_numpy_batches_equal_the_sequential_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    """Batch size 1 is the reference loop literally; other sizes give the same image."""
    scene = random_scene(400, seed=4)
    camera = aimed((48, 40), 45.0, [0, 0, 0], [0, 0, 6.0])
    images = []
    for batch in (1, 7, 32):
        monkeypatch.setattr(raster, "BATCH", batch)
        images.append(render(scene, camera, background=BG, backend="numpy"))
    assert np.abs(images[1] - images[0]).max() <= 1e-6
    assert np.abs(images[2] - images[0]).max() <= 1e-6


def test_blocked_projection_equals_one_block(monkeypatch: pytest.MonkeyPatch) -> None:
    """Projecting in blocks (big scenes) gives the same rows, indices into the whole input."""
    scene = random_scene(300, seed=5)
    camera = aimed((64, 48), 50.0, [0, 0, 3.0], [0, 0, 6.0])
    whole = project(scene, camera, antialiased=True)
    monkeypatch.setattr(columns, "BLOCK_BYTES", 64 * project_module.ROW_BYTES)  # 64 rows a block
    blocked = project(scene, camera, antialiased=True)
    assert 0 < whole.index.size < 300  # some culled (behind the camera at z = 3)
    for name in ("index", "xy", "conic", "opacity", "color", "depth", "radius", "rect"):
        assert np.array_equal(getattr(whole, name), getattr(blocked, name)), name


def test_translating_scene_and_camera_together_changes_nothing() -> None:
    """Same image when the scene and the camera move by the same vector (SH degree 3)."""
    scene = random_scene(300, seed=1)
    camera = aimed((80, 60), 70.0, [0.5, -0.3, 0.0], [0.0, 0.0, 6.0], fy=72.0, cx=41.0, cy=29.0)
    shift = np.array([3.0, -7.0, 11.0])
    moved = Gaussians(
        scene.means + shift, scene.scales, scene.quats, scene.opacities, scene.sh0, scene.shN
    )
    moved_camera = Camera.model_validate(
        {**camera.model_dump(), "position": np.add(camera.position, shift).tolist()}
    )
    a = render(scene, camera, background=BG, backend="numpy")
    b = render(moved, moved_camera, background=BG, backend="numpy")
    assert np.abs(a - b).max() <= 1e-5
    assert a.std() > 0.05  # the scene is visible


@pytest.mark.parametrize("antialiased", [False, True])
def test_numba_matches_numpy(antialiased: bool) -> None:
    """Both backends give the same image (tiles, early termination, SH degree 3)."""
    if not numba_available():
        pytest.skip("numba is not installed (pip install 'tsog-stream[render]')")
    scene = random_scene(2000, seed=2)
    camera = aimed((96, 72), 80.0, [0.0, 0.0, 0.0], [0.1, 0.0, 6.0])
    a = render(scene, camera, background=BG, antialiased=antialiased, backend="numpy")
    b = render(scene, camera, background=BG, antialiased=antialiased, backend="numba")
    assert np.abs(a - b).max() <= 1e-5
    assert (a != np.array(BG, np.float32)).any()


def test_gaussians_behind_or_too_near_the_camera_are_culled() -> None:
    """z <= 0.2 in view space contributes nothing: the image is the background exactly."""
    behind = gaussian((0.0, 0.0, -5.0), 1.0, 0.9, (1, 1, 1))
    too_near = gaussian((0.0, 0.0, 0.15), 0.05, 0.9, (1, 1, 1))
    scene = Gaussians.concat([behind, too_near])
    assert project(scene, head_on_camera()).index.size == 0
    image = render(scene, head_on_camera(), background=BG, backend="numpy")
    assert np.array_equal(image, np.broadcast_to(np.array(BG, np.float32), image.shape))
    just_in_front = gaussian((0.0, 0.0, 0.25), 0.001, 0.9, (1, 1, 1))
    kept = project(Gaussians.concat([scene, just_in_front]), head_on_camera())
    assert kept.index.tolist() == [2]


def test_guard_band_clamps_the_jacobian_and_off_screen_culling_uses_the_footprint() -> None:
    """Off-screen means: J uses x/z clamped to 1.3 tan(fov/2); only empty tile rects are culled."""
    z, sigma = 5.0, 0.5
    half = SIZE / (2 * FOCAL)  # tan of the half field of view
    x = 2.0 * half * z  # twice the half frustum: x/z is clamped to 1.3 half
    proj = project(gaussian((x, 0.0, z), sigma, 0.9, (1, 1, 1)), head_on_camera())
    t = 1.3 * half
    a = sigma**2 * (FOCAL / z) ** 2 * (1 + t * t) + 0.3
    c = sigma**2 * (FOCAL / z) ** 2 + 0.3
    np.testing.assert_allclose(proj.conic, [[1 / a, 0.0, 1 / c]], rtol=1e-6, atol=1e-12)
    screen_x = FOCAL * x / z + SIZE / 2 - 0.5
    assert screen_x - proj.radius[0] < SIZE  # its footprint reaches into the image: kept
    tiny = project(gaussian((x, 0.0, z), 0.01, 0.9, (1, 1, 1)), head_on_camera())
    assert tiny.index.size == 0  # same mean, a footprint wholly outside: culled


def test_empty_and_fully_culled_scenes_render_the_background() -> None:
    """No Gaussians at all, with either backend."""
    backends: list[Backend] = ["numpy", "numba"] if numba_available() else ["numpy"]
    for backend in backends:
        image = render(Gaussians.empty(3), head_on_camera(), background=BG, backend=backend)
        assert np.array_equal(image, np.broadcast_to(np.array(BG, np.float32), image.shape))


def test_antialiased_scales_opacity_by_the_determinant_ratio() -> None:
    """A 0.3-px Gaussian: opacity * sqrt(det(cov) / det(cov + 0.3 I)) = 0.9 * 0.09 / 0.39."""
    scene = gaussian((0.0, 0.0, 5.0), 0.3 * 5.0 / FOCAL, 0.9, (1.0, 1.0, 1.0))
    classic = project(scene, head_on_camera())
    aa = project(scene, head_on_camera(), antialiased=True)
    np.testing.assert_allclose(classic.opacity, [0.9], atol=1e-12)
    np.testing.assert_allclose(aa.opacity, [0.9 * 0.09 / 0.39], atol=1e-9)
    image = render(scene, head_on_camera(), antialiased=True, backend="numpy")
    c = SIZE // 2
    np.testing.assert_allclose(image[c, c], [0.9 * 0.09 / 0.39] * 3, atol=1e-6)


def test_orbit_cameras_look_at_the_centre() -> None:
    """Every orbit camera sees the centre on its optical axis at the orbit radius."""
    centre = np.array([1.0, 2.0, 3.0])
    cams = orbit_cameras(centre, 4.0, 5, 64, 48, fov_deg=60, elevation_deg=30)
    assert len(cams) == 5
    for cam in cams:
        p = world_to_camera(cam) @ np.append(centre, 1.0)
        np.testing.assert_allclose(p[:3], [0.0, 0.0, 4.0], atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(np.subtract(cam.position, centre)), 4.0)
    assert cams[0].fy == pytest.approx(24 / math.tan(math.radians(30)))


def test_scene_orbit_frames_the_scene() -> None:
    """The median of the means is at the image centre and the scene covers part of the view."""
    scene = random_scene(500, seed=3, sh_coeffs=0)
    cams = scene_orbit(scene, 3, 64, 48)
    image = render(scene, cams[0], backend="numpy")
    assert image.shape == (48, 64, 3)
    assert 0.2 < np.mean(image.sum(axis=2) > 0.05) < 1.0


def test_cameras_json_is_scaled_and_checked(tmp_path: Path) -> None:
    """3DGS cameras.json: rotation is camera-to-world; intrinsics follow the requested size."""
    rot = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0, 0, 1])[:3, :3].T
    entry = {
        "id": 0,
        "img_name": "a",
        "width": 800,
        "height": 600,
        "position": [1.0, 2.0, 3.0],
        "rotation": rot.tolist(),
        "fx": 700.0,
        "fy": 710.0,
    }
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([entry]))
    (cam,) = load_cameras_json(path, width=400)
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (
        400,
        300,
        350.0,
        355.0,
        200.0,
        150.0,
    )
    np.testing.assert_allclose(cam.position, [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(
        world_to_camera(cam) @ [0, 0, 0, 1.0], [0, 0, math.sqrt(14), 1], atol=1e-12
    )
    assert cam.name == "a"
    path.write_text(json.dumps([{k: v for k, v in entry.items() if k != "fx"}]))
    with pytest.raises(FormatError, match=r"'\[0\]\.fx': expected this key"):
        load_cameras_json(path)
    path.write_text(json.dumps([{**entry, "rotation": [[1, 0], [0, 1]]}]))
    with pytest.raises(FormatError, match=r"'\[0\]\.rotation\[0\]\[2\]': expected an item here"):
        load_cameras_json(path)
    path.write_text("{not json")
    with pytest.raises(FormatError):
        load_cameras_json(path)
    with pytest.raises(SourceError):
        load_cameras_json(tmp_path / "missing.json")
    with pytest.raises(InputError):
        load_cameras_json(path, width=0)


def test_bad_arguments_raise_input_errors() -> None:
    """Unknown backend, bad background; a camera that is none is refused where it is made."""
    scene = gaussian((0.0, 0.0, 5.0), 0.1, 0.5, (1, 1, 1))
    with pytest.raises(InputError):
        render(scene, head_on_camera(), backend="cuda")  # type: ignore[arg-type]
    with pytest.raises(InputError):
        render(scene, head_on_camera(), background=(0.0, 1.0))  # type: ignore[arg-type]
    fields = head_on_camera().model_dump()
    with pytest.raises(ValidationError, match="width"):
        Camera.model_validate({**fields, "width": 0})
    with pytest.raises(ValidationError, match="not orthonormal"):
        Camera.model_validate({**fields, "rotation": [[0.0] * 3] * 3})


def test_cameras_compare_by_value() -> None:
    """Equal fields make equal, hashable cameras; they cannot be changed."""
    a, b = orbit_cameras([0, 0, 0], 3.0, 2, 10, 10), orbit_cameras([0, 0, 0], 3.0, 2, 10, 10)
    assert a == b
    assert a[0] != a[1]
    assert len({a[0], b[0], a[1]}) == 2
    with pytest.raises(ValidationError, match="frozen"):
        a[0].width = 20  # type: ignore[misc]
    assert stretched(a[0], 20, 40).fy == 4 * a[0].fy


def test_to_uint8_and_save_png(tmp_path: Path) -> None:
    """round(clip(x) * 255), written as an RGB PNG that reads back identical."""
    image = np.array([[[-0.5, 0.5, 1.5], [0.2, 0.998, 0.001]]], np.float32)
    assert to_uint8(image).tolist() == [[[0, 128, 255], [51, 254, 0]]]
    save_png(image, tmp_path / "x.png")
    with Image.open(tmp_path / "x.png") as png:
        assert png.mode == "RGB"
        assert np.array_equal(np.asarray(png), to_uint8(image))


@pytest.mark.parametrize("keys", [2, 3, 4])
def test_every_legend_key_is_drawn_inside_the_chart(keys: int) -> None:
    """Keys too wide for one row wrap onto a second one instead of running off the left
    edge: every series' colour shows in the band between the title and the plot."""
    colours = [(200, 30 * k, 10) for k in range(keys)]
    series = [
        Series(f"a long description of variant number {k}", colour, [(1.0, 1.0), (2.0, 2.0)])
        for k, colour in enumerate(colours)
    ]
    band = np.asarray(line_chart("title", ("x", "y"), series))[24:57]
    for colour in colours:
        assert np.all(band == colour, axis=-1).any(), colour


def test_warming_loads_the_kernel_a_picture_then_uses() -> None:
    """render.warm (run by tsog segment while its last jobs encode) loads the numba kernel's
    one specialisation, the one any picture then uses: drawing adds none (in a fresh process,
    where nothing is loaded yet)."""
    if not numba_available():
        pytest.skip("numba is not installed (pip install 'tsog-stream[render]')")
    code = (
        "import numpy as np\n"
        "from tsog_stream.render import orbit_cameras, raster_numba, render, warm\n"
        "from tsog_stream.synthetic import static_gaussians\n"
        "assert raster_numba._KERNEL is None\n"
        "warm()\n"
        "loaded = list(raster_numba._KERNEL.signatures)\n"
        "camera = orbit_cameras([0.0, 0.0, 0.0], 6.0, 1, 64, 48)[0]\n"
        "image = render(static_gaussians(500, seed=1), camera)\n"
        "assert len(loaded) == 1 and list(raster_numba._KERNEL.signatures) == loaded\n"
        "print('ok')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


# --- cameras of any shape a file may declare: bounded before the renderer allocates ----------

SANE_ENTRY: dict[str, object] = {
    "id": 0,
    "img_name": "hostile",
    "width": 640,
    "height": 480,
    "position": [0.0, 0.0, -4.0],
    "rotation": IDENTITY,
    "fx": 500.0,
    "fy": 500.0,
}
"""A camera 4 units in front of the origin, looking at it along +z."""
HOSTILE_SHAPES = targets.HOSTILE_CAMERA_SHAPES
"""Shapes the camera schema accepts (sides up to 65536, any finite positive focal length):
the fuzz target's own, so the two cover the same cameras."""
REFUSED_SHAPES: dict[str, tuple[dict[str, object], str]] = {
    "width 0": ({"width": 0}, "[0].width"),
    "height -5": ({"height": -5}, "[0].height"),
    "width 65537": ({"width": 65537}, "[0].width"),
    "focal NaN": ({"fx": math.nan}, "[0].fx"),
    "focal inf": ({"fy": math.inf}, "[0].fy"),
    "focal 0": ({"fx": 0.0}, "[0].fx"),
    "focal -1": ({"fy": -1.0}, "[0].fy"),
}
"""Shapes refused where the file is read: one line naming the field."""


def hostile_cameras_json(path: Path, shape: str) -> Path:
    """A cameras.json holding one camera of HOSTILE_SHAPES[shape] (157 bytes or so)."""
    path.write_text(json.dumps([{**SANE_ENTRY, **HOSTILE_SHAPES[shape]}]))
    return path


def small_blob() -> Gaussians:
    """A few hundred Gaussians around the origin."""
    rng = np.random.default_rng(4)
    n = 300
    means = rng.normal(0.0, 0.4, (n, 3))
    rgb = rng.uniform(0.2, 0.9, (n, 3))
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Gaussians.from_arrays(
        means, np.full((n, 3), -3.0), quats, np.full(n, 2.0), (rgb - 0.5) / SH_C0
    )


def assert_bounded(camera: Camera, budget: int) -> None:
    """Within the pixel budget and 1:8..8:1, with a field of view of 1.1 to 175 degrees."""
    w, h = camera.width, camera.height
    assert 1 <= w * h <= budget and max(w, h) <= MAX_ASPECT * min(w, h), (w, h)
    lo, hi = FOCAL_PER_SIDE
    assert lo * w <= camera.fx <= hi * w and lo * h <= camera.fy <= hi * h
    cx, cy = camera.principal_point
    assert 0 <= cx <= w and 0 <= cy <= h


@pytest.mark.parametrize("shape", sorted(HOSTILE_SHAPES))
def test_any_camera_a_file_declares_draws_a_bounded_image(shape: str, tmp_path: Path) -> None:
    """The library: the default view is at most 1280x720's pixels, a size given in part at
    most RENDER_MAX_PIXELS, and what is drawn has exactly the camera's size."""
    (capture,) = read_cameras(hostile_cameras_json(tmp_path / "cameras.json", shape)).cameras
    source = scene_source(Scene(small_blob()), cameras=[capture])
    camera = opening_camera(source, 0, None, None)
    assert_bounded(camera, DEFAULT_PIXELS)
    image = RenderStyle().image(source.at(0.0), camera)
    assert image.shape == (camera.height, camera.width, 3)
    for partly in (
        from_capture(capture, None),
        from_capture(capture, 16384),
        from_capture(capture, None, 16384),
        stretched(capture, None, None),
        stretched(capture, 16384, None),
        opening_camera(source, 0, 16384, None),
        load_cameras_json(tmp_path / "cameras.json", height=16384)[0],
    ):
        assert_bounded(partly, RENDER_MAX_PIXELS)


def test_a_tall_camera_keeps_its_width_and_field_of_view_within_the_limits() -> None:
    """200x65536 is narrowed to 1:8 (the vertical field of view kept), then the 640-wide
    default shrunk to 1280x720's pixel count; a 178-degree view is held to 175."""
    entry = {**SANE_ENTRY, **HOSTILE_SHAPES["tall-200x65536"]}
    for focal, fy in ((50000.0, 50000.0 * 2712 / 65536), (500.0, FOCAL_PER_SIDE[0] * 2712)):
        raw = json.dumps([{**entry, "fx": focal, "fy": focal}]).encode()
        capture = parse_cameras_json(raw, where="c")[0]
        source = scene_source(Scene(small_blob()), cameras=[capture])
        camera = opening_camera(source, 0, None, None)
        assert (camera.width, camera.height) == (339, 2712)
        assert camera.fy == pytest.approx(fy)
    sane = parse_cameras_json(json.dumps([SANE_ENTRY]).encode(), where="c")[0]
    assert from_capture(sane, 640, 480) == Camera(
        name="hostile",
        width=640,
        height=480,
        fx=500.0,
        fy=500.0,
        cx=320.0,
        cy=240.0,
        position=sane.position,
        rotation=sane.rotation,
    )


@pytest.mark.parametrize(
    ("size", "message"),
    [
        ((4097, 4096), "4097x4096 is 16781312 pixels, more than the 16777216 an image may have"),
        ((16384, 16), "16384x16 is more than 8 times as wide as tall or as tall as wide"),
        ((1, 9), "1x9 is more than 8 times as wide as tall or as tall as wide"),
    ],
)
def test_explicit_sizes_beyond_the_limits_are_refused(size: tuple[int, int], message: str) -> None:
    scene = small_blob()
    width, height = size
    camera = head_on_camera().model_copy(update={"width": width, "height": height})
    with pytest.raises(InputError) as raised:
        render(scene, camera)  # refused before a pixel is allocated
    assert str(raised.value) == message
    source = scene_source(Scene(small_blob()))
    with pytest.raises(InputError) as raised:
        opening_camera(source, None, *size)
    assert str(raised.value) == f"--width/--height: {message}"
    with pytest.raises(InputError, match=r"focal lengths must be 0\.02 to 50 times"):
        render(scene, head_on_camera(64).model_copy(update={"fx": 1e-30}))
    with pytest.raises(ValidationError, match="cx"):
        Camera.model_validate({**head_on_camera(64).model_dump(), "cx": math.nan})


def _colmap_text_model(folder: Path, shape: str) -> Path:
    """cameras.txt and images.txt of one PINHOLE camera of HOSTILE_SHAPES[shape]."""
    entry = {**SANE_ENTRY, **HOSTILE_SHAPES[shape]}
    w, h, fx, fy = entry["width"], entry["height"], entry["fx"], entry["fy"]
    cx, cy = entry.get("cx", 1.0), entry.get("cy", 1.0)
    folder.mkdir()
    (folder / "cameras.txt").write_text(f"1 PINHOLE {w} {h} {fx!r} {fy!r} {cx!r} {cy!r}\n")
    (folder / "images.txt").write_text("1 1 0 0 0 0 0 4 1 hostile.png\n\n")
    return folder


def _splatv_with_camera(samples: Path, out: Path, shape: str) -> Path:
    """The synthetic .splatv sample with its header camera replaced by HOSTILE_SHAPES[shape]."""
    data = (samples / "4d/splatv/tztechno_hanabi2_synthetic.splatv").read_bytes()
    length = struct.unpack_from("<I", data, 4)[0]
    header = json.loads(data[8 : 8 + length])
    header[0]["cameras"] = [{**SANE_ENTRY, **HOSTILE_SHAPES[shape]}]
    raw = json.dumps(header).encode()
    out.write_bytes(data[:4] + struct.pack("<I", len(raw)) + raw + data[8 + length :])
    return out


def _container_opening_on(tmp_path: Path, shape: str, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A small container whose stored opening view is a camera of HOSTILE_SHAPES[shape] (as
    a hostile writer would store it: the segmenter is made to keep it)."""
    capture = parse_cameras_json(
        json.dumps([{**SANE_ENTRY, **HOSTILE_SHAPES[shape]}]).encode(), where="c"
    )[0]
    monkeypatch.setattr(segmenter, "opening_view", lambda _g, cams, _core: (cams[0], "kept"))
    path = tmp_path / "hostile.tsogs"
    segment_scene(Scene(small_blob()), path, SegmentOptions(), cameras=[capture])
    return path


ORIGINS = ["cameras.json", "COLMAP text", ".splatv header", ".tsogs view", ".tsogs view over HTTP"]


@pytest.mark.parametrize("origin", ORIGINS)
@pytest.mark.parametrize("shape", sorted(HOSTILE_SHAPES))
def test_tsog_render_draws_any_camera_within_the_pixel_budget(
    origin: str,
    shape: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """tsog render from a hostile camera of every origin: exit 0, an image at most
    1280x720's pixel count and 1:8..8:1, the size it reports."""
    ply = tmp_path / "scene.ply"
    write_ply(ply, small_blob())
    if origin == "cameras.json":
        argv = [str(ply), "--cameras", str(hostile_cameras_json(tmp_path / "c.json", shape))]
    elif origin == "COLMAP text":
        argv = [str(ply), "--cameras", str(_colmap_text_model(tmp_path / "sparse", shape))]
    elif origin == ".splatv header":
        argv = [str(_splatv_with_camera(SAMPLES, tmp_path / "h.splatv", shape))]
    else:
        argv = [str(_container_opening_on(tmp_path, shape, monkeypatch))]
    if not origin.startswith(".tsogs"):
        argv += ["--camera", "0"]
    out = tmp_path / "out" / "view.png"
    out.parent.mkdir()
    server = ThreadedServer(make_app(tmp_path)) if origin.endswith("HTTP") else None
    try:
        if server is not None:
            argv = [f"http://127.0.0.1:{server.port}/files/hostile.tsogs"]
        assert main(["render", *argv, "-o", str(out), "-q"]) == 0
    finally:
        if server is not None:
            server.stop()
    with Image.open(out) as png:
        w, h = png.size
    assert w * h <= DEFAULT_PIXELS and max(w, h) <= MAX_ASPECT * min(w, h)
    said = capsys.readouterr().out
    assert said.startswith(f"{out}: {w}x{h}, t = 0 s, ")


@pytest.mark.parametrize("shape", sorted(REFUSED_SHAPES))
def test_cameras_with_no_sane_reading_are_refused_in_one_line(
    shape: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    changes, field = REFUSED_SHAPES[shape]
    ply, cameras = tmp_path / "scene.ply", tmp_path / "cameras.json"
    write_ply(ply, small_blob())
    cameras.write_text(json.dumps([{**SANE_ENTRY, **changes}]))
    out = tmp_path / "view.png"
    assert main(["render", str(ply), "--cameras", str(cameras), "-o", str(out), "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"tsog: error: {cameras}: field '{field}': ") and err.count("\n") == 1
    assert not out.exists()
    with pytest.raises(FormatError, match=re.escape(f"'{field}'")):
        read_cameras(cameras)
