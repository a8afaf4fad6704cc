"""Frame sequences (PLY and SOG folders) read as one type-0 scene."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from helpers import log_space_error, means_log_step
from tsog_stream import Gaussians, InputError, Scene, TimelineType
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.compare import rotation_angles_deg
from tsog_stream.io import sequence as sequence_module
from tsog_stream.io.chunks import read_chunk
from tsog_stream.io.ply import read_ply, write_ply
from tsog_stream.io.sequence import (
    DEFAULT_FPS,
    detect_sequence,
    list_frames,
    open_sequence,
    read_ply_sequence,
    read_sog_sequence,
)
from tsog_stream.synthetic import static_gaussians

FIREWORKS_FRAMES = 6
FIREWORKS_PER_FRAME = 4000
ROTATION_MAX_DEG = 1.1
"""SOG smallest-three rotations, 8 bits per component (as in test_codec)."""


@pytest.fixture(scope="module")
def fireworks(samples: Path) -> Path:
    return samples / "4d" / "tztechno_fireworks_frames"


@pytest.fixture(scope="module")
def fireworks_scene(fireworks: Path) -> Scene:
    loaded = read_ply_sequence(fireworks, fps=30.0)
    assert loaded.notes == []
    return loaded.scene


@pytest.fixture()
def wave5(samples: Path, tmp_path: Path) -> Path:
    """The first five wave frames, copied so the test stays fast."""
    folder = tmp_path / "wave"
    folder.mkdir()
    for i in range(1, 6):
        shutil.copy(samples / "4d" / "pc_flipbook_wave" / f"wave_{i:04d}.sog", folder)
    return folder


def _normalised(quats: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    """Quaternions normalised in float64, as evaluation does."""
    q = quats.astype(np.float64)
    return np.asarray(q / np.linalg.norm(q, axis=1, keepdims=True), np.float64)


def _assert_same_gaussians(got: Gaussians, want: Gaussians) -> None:
    """Equal arrays; quaternions compared after the normalisation evaluation applies."""
    np.testing.assert_array_equal(got.means, want.means)
    np.testing.assert_array_equal(got.scales, want.scales)
    np.testing.assert_array_equal(got.opacities, want.opacities)
    np.testing.assert_array_equal(got.sh0, want.sh0)
    np.testing.assert_array_equal(got.shN, want.shN)
    np.testing.assert_allclose(got.quats, _normalised(want.quats), atol=1e-7)


def test_fireworks_sequence_is_one_type0_scene(fireworks_scene: Scene) -> None:
    scene = fireworks_scene
    assert len(scene) == FIREWORKS_FRAMES * FIREWORKS_PER_FRAME
    tl = scene.timeline
    assert tl is not None and tl.type is TimelineType.FRAME
    assert tl.fps == 30.0 and tl.scene_length == pytest.approx(FIREWORKS_FRAMES / 30.0)
    ids, counts = np.unique(tl.t0, return_counts=True)
    assert ids.tolist() == list(range(FIREWORKS_FRAMES))
    assert counts.tolist() == [FIREWORKS_PER_FRAME] * FIREWORKS_FRAMES
    assert not scene.temporal


def test_fireworks_frame_k_at_k_over_fps_is_that_ply(
    fireworks: Path, fireworks_scene: Scene
) -> None:
    for k, path in enumerate(list_frames(fireworks)):
        ply = read_ply(path).gaussians
        _assert_same_gaussians(fireworks_scene.at(k / 30.0), ply)
        _assert_same_gaussians(fireworks_scene.at((k + 0.5) / 30.0), ply)
        rows = fireworks_scene.subset(fireworks_scene.timeline.t0 == k).gaussians  # type: ignore[union-attr]
        np.testing.assert_array_equal(rows.quats, ply.quats)  # file order, untouched


def test_fireworks_tsog_round_trip_within_sog_error(
    fireworks: Path, fireworks_scene: Scene
) -> None:
    files = encode_chunk(fireworks_scene)
    decoded = decode_chunk(files)
    order = texel_order(fireworks_scene)  # texel j holds source row order[j]
    meta = json.loads(files["meta.json"])
    step = means_log_step(meta["means"]["mins"], meta["means"]["maxs"])
    assert decoded.timeline is not None
    for k, path in enumerate(list_frames(fireworks)):
        ply = read_ply(path).gaussians
        rows = order[np.rint(decoded.timeline.t0) == k] - k * FIREWORKS_PER_FRAME
        assert sorted(rows.tolist()) == list(range(FIREWORKS_PER_FRAME))
        got = decoded.at(k / 30.0)
        want = ply.subset(rows)
        assert np.all(log_space_error(got.means, want.means) <= step * 0.5 + 1e-7)
        assert rotation_angles_deg(got.quats, want.quats).max() < ROTATION_MAX_DEG
        alpha = 1 / (1 + np.exp(-np.stack([got.opacities, want.opacities]).astype(np.float64)))
        assert np.abs(alpha[0] - alpha[1]).max() <= 0.5 / 255 + 1e-6


def test_natural_numeric_order_and_gap_note(tmp_path: Path) -> None:
    sizes = {2: 1, 10: 2, 1: 3}  # number in the name -> Gaussians in that frame
    for number, n in sizes.items():
        write_ply(tmp_path / f"frame_{number}.ply", static_gaussians(n, seed=number))
    assert [p.name for p in list_frames(tmp_path)] == ["frame_1.ply", "frame_2.ply", "frame_10.ply"]
    loaded = read_ply_sequence(tmp_path, fps=10.0)
    tl = loaded.scene.timeline
    assert tl is not None
    assert tl.t0.tolist() == [0, 0, 0, 1, 2, 2]  # 3 from frame_1, 1 from frame_2, 2 from frame_10
    np.testing.assert_array_equal(loaded.scene.at(0.2).means, static_gaussians(2, seed=10).means)
    assert any("skips 3-9 (7 missing)" in note for note in loaded.notes)
    assert loaded.scene.timeline.scene_length == pytest.approx(0.3)  # type: ignore[union-attr]


def test_glob_pattern_selects_frames(tmp_path: Path) -> None:
    for i in range(3):
        write_ply(tmp_path / f"a_{i}.ply", static_gaussians(2, seed=i))
        write_ply(tmp_path / f"b_{i}.ply", static_gaussians(5, seed=i))
    loaded = read_ply_sequence(str(tmp_path / "a_*.ply"))
    assert len(loaded.scene) == 6
    assert loaded.scene.timeline is not None and loaded.scene.timeline.fps == DEFAULT_FPS
    assert detect_sequence(str(tmp_path / "b_*.ply")) == "ply-sequence"


def test_mixed_sh_degrees_are_padded_and_noted(tmp_path: Path) -> None:
    low, high = static_gaussians(4, sh_bands=0, seed=1), static_gaussians(3, sh_bands=2, seed=2)
    write_ply(tmp_path / "f_0.ply", low)
    write_ply(tmp_path / "f_1.ply", high)
    loaded = read_ply_sequence(tmp_path)
    g = loaded.scene.gaussians
    assert g.shN.shape == (7, 8, 3)
    assert not g.shN[:4].any()
    np.testing.assert_array_equal(g.shN[4:], high.shN)
    assert any("mix SH degrees [0, 2]" in n and "1 frames padded" in n for n in loaded.notes)
    assert any("differ in size: 3 to 4" in n for n in loaded.notes)


def test_kind_is_told_by_content_not_extension(tmp_path: Path) -> None:
    for i in range(2):
        write_ply(tmp_path / f"shot{i}.bin", static_gaussians(2, seed=i))
    (tmp_path / "readme1.txt").write_text("not a frame")
    assert detect_sequence(tmp_path) == "ply-sequence"
    loaded = read_ply_sequence(tmp_path)
    assert len(loaded.scene) == 4
    assert any("readme1.txt" in n for n in loaded.notes)


def test_sog_sequence_frame_k_is_that_chunk(wave5: Path) -> None:
    messages: list[str] = []
    loaded = read_sog_sequence(wave5, fps=10.0, progress=messages.append)
    assert messages == [f"frame {i}/5" for i in range(1, 6)]
    assert loaded.notes == []
    assert detect_sequence(wave5) == "sog-sequence"
    scene = loaded.scene
    assert scene.timeline is not None and scene.timeline.scene_length == pytest.approx(0.5)
    for k, path in enumerate(list_frames(wave5)):
        _assert_same_gaussians(scene.at(k / 10.0), read_chunk(path).gaussians)


@pytest.mark.parametrize(("kind", "frames"), [("samples", 3), ("optional_samples", 50)])
def test_monkey_sog_sequence_count(kind: str, frames: int, request: pytest.FixtureRequest) -> None:
    data: Path = request.getfixturevalue(kind)  # 3 frames in the repository, 50 optional
    loaded = read_sog_sequence(data / "4d" / "pc_flipbook_monkey")
    tl = loaded.scene.timeline
    assert tl is not None and len(loaded.scene) == frames * 31658
    ids, counts = np.unique(tl.t0, return_counts=True)
    assert ids.tolist() == list(range(frames)) and set(counts.tolist()) == {31658}


def test_detect_sequence_says_none_for_other_inputs(samples: Path, tmp_path: Path) -> None:
    assert detect_sequence(samples / "4d" / "splatv") is None
    assert detect_sequence(samples / "4d" / "pc_flipbook_wave" / "wave_0001.sog") is None
    assert detect_sequence(tmp_path) is None
    write_ply(tmp_path / "only_1.ply", static_gaussians(2))
    assert detect_sequence(tmp_path) is None  # one frame is not a sequence
    assert len(read_ply_sequence(tmp_path).scene) == 2  # ... but it reads


def test_bad_sequences_are_refused(samples: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no numbered PLY or SOG frames"):
        list_frames(tmp_path)
    with pytest.raises(InputError, match="no such folder"):
        list_frames(tmp_path / "missing")
    with pytest.raises(InputError, match="no numbered"):
        list_frames(str(tmp_path / "nothing_*.ply"))
    write_ply(tmp_path / "f_1.ply", static_gaussians(2))
    shutil.copy(samples / "4d" / "pc_flipbook_wave" / "wave_0001.sog", tmp_path / "f_2.sog")
    with pytest.raises(InputError, match="mixes PLY frames"):
        list_frames(tmp_path)
    (tmp_path / "f_2.sog").unlink()
    write_ply(tmp_path / "f_01.ply", static_gaussians(2))
    with pytest.raises(InputError, match="both have number 1"):
        list_frames(tmp_path)
    (tmp_path / "f_01.ply").unlink()
    with pytest.raises(InputError, match="use read_ply_sequence"):
        read_sog_sequence(tmp_path)
    with pytest.raises(InputError, match="fps"):
        read_ply_sequence(tmp_path, fps=0.0)
    with pytest.raises(InputError, match="expected a folder"):
        read_ply_sequence(tmp_path / "f_1.ply")


def test_a_window_of_one_frame_is_that_frame_s_arrays(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A window of one frame takes the frame's arrays as read, not a copy of them (a window
    job's worker held a 500k SH3 frame twice while it was copied); a frame whose SH must be
    padded to the sequence's, and a window of several frames, are copied."""
    write_ply(tmp_path / "f_0.ply", static_gaussians(5, sh_bands=2, seed=1))
    write_ply(tmp_path / "f_1.ply", static_gaussians(4, sh_bands=1, seed=2))
    seq = open_sequence(tmp_path)
    read: list[Gaussians] = []
    real = sequence_module._read_frame

    def recorded(kind: str, path: Any) -> tuple[Gaussians, list[str], set[str]]:
        found = real(kind, path)
        read.append(found[0])
        return found

    monkeypatch.setattr(sequence_module, "_read_frame", recorded)
    one = seq.window(0, 1).read().scene.gaussians
    assert one.means is read[-1].means and one.shN is read[-1].shN
    padded = seq.window(1, 2).read().scene.gaussians
    assert padded.shN.shape == (4, 8, 3) and not padded.shN[:, 3:].any()
    np.testing.assert_array_equal(padded.shN[:, :3], read[-1].shN)
    both = seq.window(0, 2).read().scene.gaussians
    assert not any(np.shares_memory(both.means, g.means) for g in read[-2:])
    np.testing.assert_array_equal(both.means, np.concatenate([g.means for g in read[-2:]]))
