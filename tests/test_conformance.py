"""The reader against chunks written to the paper's examples by an independent minimal writer
(scripts/make_conformance_corpus.py; tests/data/conformance/README.md lists the cases)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tsog_stream import Scene, TimelineType, decode_chunk, encode_chunk, read_chunk
from tsog_stream.codec.chunk import texel_order
from tsog_stream.opacity import logit_to_alpha
from tsog_stream.synthetic import small_scene

CORPUS = Path(__file__).resolve().parent / "data" / "conformance"
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "make_conformance_corpus.py"
CASES = sorted(p.name for p in CORPUS.iterdir() if p.is_dir())


def test_the_corpus_is_what_its_writer_makes() -> None:
    command = [sys.executable, str(SCRIPT), "--check"]
    proc = subprocess.run(command, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout
    assert len(CASES) == 5


def test_the_paper_example_is_taken_literally() -> None:
    meta = json.loads((CORPUS / "type2_paper_example" / "meta.json").read_text())
    temporal = meta["temporal"]
    assert set(temporal) == {"means", "quats", "sh0"}  # opacity rides in sh0's A channel
    assert [len(row) for row in temporal["quats"]["mins"]] == [3, 3]  # [qx, qy, qz] per order
    assert [len(row) for row in temporal["sh0"]["mins"]] == [4]
    assert temporal["quats"]["files"] == [
        "temporal_quats_1_l.webp",
        "temporal_quats_1_u.webp",
        "temporal_quats_2_l.webp",
        "temporal_quats_2_u.webp",
    ]


@pytest.mark.parametrize("case", CASES)
def test_each_case_reads_as_its_writer_meant(case: str) -> None:
    scene = read_chunk(CORPUS / case)
    expected = json.loads((CORPUS / case / "expected.json").read_text())
    assert len(scene) == 4 and expected
    for frame in expected:
        got = scene.at(frame["t"])
        where = f"{case} at t = {frame['t']}"
        assert len(got) == len(frame["visible"]), where
        if not frame["visible"]:
            continue
        np.testing.assert_allclose(got.means, frame["means"], atol=2e-4, err_msg=where)
        quats = got.quats / np.linalg.norm(got.quats, axis=1, keepdims=True)
        want = np.asarray(frame["quats"])
        same_sign = np.sign(np.sum(quats * want, axis=1))[:, None]  # q and -q: one rotation
        np.testing.assert_allclose(quats * same_sign, want, atol=2e-4, err_msg=where)
        np.testing.assert_allclose(got.sh0, frame["sh0"], atol=2e-4, err_msg=where)
        np.testing.assert_allclose(
            logit_to_alpha(got.opacities), frame["alpha"], atol=1e-3, err_msg=where
        )


@pytest.mark.parametrize(
    ("orders", "want_sh0_orders"),
    [({"opacity": 2}, None), ({"sh0": 1, "opacity": 2}, 1), ({"sh0": 2, "opacity": 1}, 2)],
)
def test_the_writer_puts_opacity_in_sh0s_alpha_channel(
    orders: dict[str, int], want_sh0_orders: int | None
) -> None:
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=tuple(orders), motion_order=2)
    temporal = {a: np.ascontiguousarray(scene.temporal[a][:, :k]) for a, k in orders.items()}
    scene = Scene(scene.gaussians, scene.timeline, temporal)
    files = encode_chunk(scene)
    meta = json.loads(files["meta.json"])
    assert set(meta["temporal"]) == {"sh0"}  # no separate opacity attribute any more
    entry = meta["temporal"]["sh0"]
    assert [len(row) for row in entry["mins"]] == [4] * max(orders.values())
    decoded = decode_chunk(files)
    assert set(decoded.temporal) == set(orders)  # the padding the writer added is dropped
    order = texel_order(scene)
    for attr, k in orders.items():
        got, src = decoded.temporal[attr], scene.temporal[attr][order]
        assert got.shape == src.shape == (len(scene), k, 3 if attr == "sh0" else 1)
        span = np.ptp(src, axis=0)
        assert np.all(np.abs(got - src) <= span / 65535 + 1e-6), attr
    if want_sh0_orders is None:
        assert all(v == 0.0 for row in entry["mins"] + entry["maxs"] for v in row[:3])
