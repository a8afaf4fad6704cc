"""Every 4D input survives TSOG encode/decode: at(t) of the chunk matches at(t) of the input.

Bounds are those of tests/helpers.py ``check_decoded_at`` (16-bit position and coefficient
steps, plus one timeline step at lifespan edges), at times including lifespan edges.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fixtures_4d import freetime_npz, freetime_ply, freetime_truth
from helpers import check_decoded_at
from tsog_stream import Scene
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.io.freetimegs import parse_freetimegs_npz, parse_freetimegs_ply
from tsog_stream.io.readers import ReadOptions, load_scene
from tsog_stream.temporal import lifespans, time_range

LOADERS: dict[str, Callable[[Path], Scene]] = {
    "splatv coffeeshort2": lambda d: (
        load_scene(d / "4d/splatv/macaburguera_coffeeshort2.splatv").scene
    ),
    "splatv hanabi2": lambda d: load_scene(d / "4d/splatv/tztechno_hanabi2_synthetic.splatv").scene,
    "PLY sequence": lambda d: (
        load_scene(d / "4d/tztechno_fireworks_frames", options=ReadOptions(fps=6)).scene
    ),
    "FreeTimeGS PLY": lambda _d: (
        parse_freetimegs_ply(freetime_ply(freetime_truth(n=400)), scene_length_s=2.0).scene
    ),
    "FreeTimeGS npz": lambda _d: (
        parse_freetimegs_npz(freetime_npz(freetime_truth(n=400, seed=9)), scene_length_s=3.0).scene
    ),
}


OPTIONAL = {"splatv coffeeshort2"}
"""Inputs from the optional sample set (real captures derived from N3DV, CC-BY-NC-4.0)."""


@pytest.mark.parametrize("name", list(LOADERS))
def test_input_survives_encode_decode(name: str, request: pytest.FixtureRequest) -> None:
    data: Path = request.getfixturevalue("optional_samples" if name in OPTIONAL else "samples")
    scene = LOADERS[name](data)
    assert scene.timeline is not None
    files = encode_chunk(scene)
    decoded = decode_chunk(files)
    src = scene.subset(texel_order(scene))
    meta = json.loads(files["meta.json"])
    assert src.timeline is not None
    first, last = time_range(src.timeline)
    start, end = lifespans(src.timeline)
    inside = (start > first) & (start < last)
    edges = np.concatenate([start[inside][:4], end[(end > first) & (end < last)][:4]])
    for t in sorted({*np.linspace(first, last, 7).tolist(), *edges.tolist()}):
        check_decoded_at(src, decoded, meta, float(t))
