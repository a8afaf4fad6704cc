"""Every format byte held: the SHA-256 of what the writers make, for a fixed set of inputs and
options, against ``tests/data/held_digests.json``.

What it guards: a refactor (issue 56, "one house") must keep every container byte-identical
for the same input and options. Each case segments one input to a ``.tsogs`` with the public
API (``load_scene`` + ``segment_scene``, or a generated scene in memory), or runs ``tsog
segment`` (which adds the frame sequences' merge probe, the window-by-window sequence path, the
choice of quality layers and the thumbnail), or encodes one chunk with ``encode_chunk``; the
digests of the container, of the thumbnail PNG and of each chunk file must equal the recorded
ones. Covered: every input kind the repository has samples for (static SH0 and SH3 PLY,
compressed PLY, unbundled SOG, a PLY frame sequence, SOG flipbook frames, ``.splatv``),
generated FreeTimeGS PLY and ``.npz``, a generated scene of each timeline type, layered scenes
(chosen and ``--layers 3``) with SH-band chunks, static scenes (a stream of one moment),
quality 50, and two encoder processes (which must give the bytes of one). Each case also
states what its container must hold (timeline type, layers, SH-band chunks), so that a case
cannot keep its digest by quietly covering less.

The digests are recorded per machine numerics (:func:`numerics`): the SH palette's matrix
products go through the BLAS kernel for the CPU (AVX2 and AVX-512 round differently), the layer
choice through NumPy's SIMD loops, so the same code writes other palette bytes on another kind
of CPU. A machine whose numerics have no digests fails here with the way to record them: from a
git worktree of the last commit whose digests held, ``scripts/hold_digests.py --add``.

After an intended format change (a new byte in the container, its index or a chunk), and only
then: add an entry to the changelog of ``docs/spec.md`` saying what changed and why, rewrite
the digests with ``.venv/bin/python scripts/hold_digests.py`` and commit the file with the
change (``scripts/hold_digests.py --check`` compares without writing). A digest that moves
without a spec changelog entry is a regression to fix, not a file to regenerate.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import platform
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import features
from threadpoolctl import threadpool_info

from conftest import REPO, SAMPLES
from fixtures_4d import freetime_npz, freetime_ply, freetime_truth
from tsog_stream import (
    Scene,
    SegmentOptions,
    TimelineType,
    encode_chunk,
    load_scene,
    open_stream,
    segment_scene,
)
from tsog_stream.cli.main import main
from tsog_stream.constants import thumbnail_path
from tsog_stream.synthetic import small_scene, static_gaussians

DIGESTS = REPO / "tests" / "data" / "held_digests.json"
CONTAINER = "held.tsogs"
"""The name every segmenting case gives its container, in the case's own folder."""
Artifacts = dict[str, bytes]
"""What a case made: an artifact's name (``container``, ``thumbnail``, a chunk file) -> bytes."""
Digests = dict[str, dict[str, Any]]
"""An artifact's name -> ``{"sha256": hex, "bytes": size}``."""
Make = Callable[[Path], Artifacts]
"""Makes a case's artifacts in the empty folder given."""
Source = Callable[[Path], Path]
"""The input file of a case: a sample, or a file generated into the folder given."""


@dataclass(frozen=True)
class Case:
    """One held output: how it is made, and what its container must hold (keys of
    :func:`holds`; none for a chunk)."""

    make: Make
    holds: Mapping[str, Any] = field(default_factory=dict)


def digest(data: bytes) -> dict[str, Any]:
    """The record of one artifact's bytes."""
    return {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}


def holds(container: Path) -> dict[str, Any]:
    """What a container holds, read from its index."""
    with open_stream(container) as stream:
        m = stream.index.manifest
    return {
        "timeline_type": m.scene.timeline_type,
        "layers": len({c.layer for c in m.chunks}),
        "sh_band_chunks": any(c.sh_of is not None for c in m.chunks),
        "duration_assumed": m.scene.duration_assumed,
    }


def _sample(relative: str) -> Source:
    """A sample of tests/data/real."""
    return lambda _out: SAMPLES / relative


def _generated_file(name: str, data: Callable[[], bytes]) -> Source:
    """A generated input, written as ``name`` in the case's folder."""

    def write(out: Path) -> Path:
        (out / name).write_bytes(data())
        return out / name

    return write


def _library(source: Source, options: SegmentOptions | None = None) -> Make:
    """Read the input with ``load_scene`` and segment it as a library user would."""

    def make(out: Path) -> Artifacts:
        loaded = load_scene(source(out))
        segment_scene(
            loaded.scene,
            out / CONTAINER,
            options,
            cameras=loaded.cameras,
            duration_assumed=loaded.duration_assumed,
        )
        return {"container": (out / CONTAINER).read_bytes()}

    return make


def _in_memory(scene: Callable[[], Scene], options: SegmentOptions | None = None) -> Make:
    """Segment a generated scene."""

    def make(out: Path) -> Artifacts:
        segment_scene(scene(), out / CONTAINER, options)
        return {"container": (out / CONTAINER).read_bytes()}

    return make


def _cli(source: Source, *flags: str) -> Make:
    """Run ``tsog segment`` in this process (one encoder process, as the other cases)."""

    def make(out: Path) -> Artifacts:
        container = out / CONTAINER
        argv = ["segment", str(source(out)), "-o", str(container), "--workers", "1", *flags]
        with contextlib.redirect_stdout(io.StringIO()):
            assert main([*argv, "-q"]) == 0
        thumbnail = Path(thumbnail_path(str(container)))
        return {"container": container.read_bytes(), "thumbnail": thumbnail.read_bytes()}

    return make


def _encoded(scene: Callable[[], Scene], quality: int) -> Make:
    """Encode one chunk: each of its files by name."""
    return lambda _out: encode_chunk(scene(), quality=quality)


FREETIME = freetime_truth(n=3000, seed=11, sh_bands=1)
FREETIME_PLY = _generated_file("freetime.ply", lambda: freetime_ply(FREETIME))
FRAMES = _sample("4d/tztechno_fireworks_frames")


def _static_sh3() -> Scene:
    """A generated static SH3 scene (no timeline: a stream of one moment)."""
    return Scene(static_gaussians(3000, sh_bands=3, seed=5))


def _moving(kind: TimelineType, sh_bands: int = 1) -> Callable[[], Scene]:
    """A generated 4D scene of timeline type ``kind``."""
    return lambda: small_scene(kind, sh_bands=sh_bands, seed=3)


TYPE_2 = _moving(TimelineType.CENTER_SCALE)
SH3 = _moving(TimelineType.CENTER_SCALE, sh_bands=3)
LAYERED = SegmentOptions(layers=3)
STATIC = {"timeline_type": None}
CASES: dict[str, Case] = {
    "ply_sh0_donut": Case(_library(_sample("3dgs/v3dg_donut_fused.ply")), {**STATIC, "layers": 3}),
    "ply_sh3_tile": Case(_library(_sample("3dgs/gs3d_pr477_lod3_tile_0.ply")), STATIC),
    "compressed_ply": Case(_library(_sample("fixtures/pc_engine_test.compressed.ply")), STATIC),
    "sog_unbundled": Case(_library(_sample("3dgs/pc_playbot_lod6_sog")), STATIC),
    "ply_frames": Case(_library(FRAMES), {"timeline_type": 0}),
    "sog_flipbook": Case(_library(_sample("4d/pc_flipbook_wave")), {"timeline_type": 0}),
    "splatv": Case(
        _library(_sample("4d/splatv/tztechno_hanabi2_synthetic.splatv")),
        {"timeline_type": 2, "duration_assumed": True},
    ),
    "freetimegs_ply": Case(_library(FREETIME_PLY), {"timeline_type": 2}),
    "freetimegs_npz": Case(
        _library(_generated_file("freetime.npz", lambda: freetime_npz(FREETIME))),
        {"timeline_type": 2},
    ),
    "generated_type0": Case(_in_memory(_moving(TimelineType.FRAME)), {"timeline_type": 0}),
    "generated_type1": Case(_in_memory(_moving(TimelineType.START_DURATION)), {"timeline_type": 1}),
    "generated_type2": Case(_in_memory(TYPE_2), {"timeline_type": 2, "layers": 1}),
    "generated_type2_q50": Case(
        _in_memory(TYPE_2, SegmentOptions(quality=50)), {"timeline_type": 2}
    ),
    "generated_type0_workers2": Case(
        _in_memory(_moving(TimelineType.FRAME), SegmentOptions(workers=2)), {"timeline_type": 0}
    ),
    "layered3_sh_bands": Case(_in_memory(SH3, LAYERED), {"layers": 3, "sh_band_chunks": True}),
    "layered3_sh_bands_workers2": Case(
        _in_memory(SH3, replace(LAYERED, workers=2)), {"layers": 3, "sh_band_chunks": True}
    ),
    "static_generated": Case(_in_memory(_static_sh3), STATIC),
    "cli_ply_frames": Case(_cli(FRAMES), {"timeline_type": 0, "layers": 1}),
    "cli_ply_frames_layers3": Case(
        _cli(FRAMES, "--temporal", "off", "--layers", "3"),
        {"timeline_type": 0, "layers": 3},
    ),
    "cli_sog_flipbook": Case(_cli(_sample("4d/pc_flipbook_wave")), {"timeline_type": 1}),
    "cli_freetimegs_layers3": Case(
        _cli(FREETIME_PLY, "--layers", "3"), {"layers": 3, "sh_band_chunks": True}
    ),
    "encode_static_q100": Case(_encoded(_static_sh3, 100)),
    "encode_static_q50": Case(_encoded(_static_sh3, 50)),
    "encode_4d_q100": Case(_encoded(TYPE_2, 100)),
    "encode_4d_q50": Case(_encoded(TYPE_2, 50)),
}
"""Every held output by name (the keys of tests/data/held_digests.json)."""


def held_digests(name: str, out: Path) -> Digests:
    """The digests of case ``name``'s artifacts, made in the empty folder ``out``."""
    return {artifact: digest(data) for artifact, data in CASES[name].make(out).items()}


def numerics() -> str:
    """What decides this machine's rounding where the encoder's floats depend on the CPU: the
    architecture, NumPy's SIMD level, OpenBLAS's kernel, and the libwebp and zlib that write
    the images."""
    simd = np.show_config(mode="dicts")["SIMD Extensions"]["found"]
    blas = [i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"]
    parts = [platform.machine(), "simd:" + "+".join(simd or ["baseline"])]
    parts += [f"blas:{'+'.join(map(str, blas)) or 'none'}"]
    parts += [f"{lib}:{features.version(lib)}" for lib in ("webp", "zlib")]
    return " ".join(parts)


def recorded_all() -> dict[str, dict[str, Digests]]:
    """Every machine numerics' digests in tests/data/held_digests.json."""
    data: dict[str, dict[str, Digests]] = json.loads(DIGESTS.read_text())
    return data


def recorded() -> dict[str, Digests]:
    """This machine's digests (the test fails, saying how to record them, when there are none)."""
    found = recorded_all().get(numerics())
    if found is None:
        pytest.fail(
            f"no digests recorded for this machine's numerics ({numerics()}): from a git worktree "
            "of the last commit whose digests held, run scripts/hold_digests.py --add"
        )
    return found


def test_the_file_holds_every_case_and_no_other() -> None:
    assert sorted(recorded()) == sorted(CASES)


@pytest.mark.parametrize("name", ["generated_type0", "layered3_sh_bands"])
def test_two_encoder_processes_give_the_bytes_of_one(name: str) -> None:
    held = recorded()
    assert held[f"{name}_workers2"] == held[name]


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_bytes_are_held(name: str, tmp_path: Path) -> None:
    assert held_digests(name, tmp_path) == recorded()[name]
    case = CASES[name]
    if case.holds:
        found = holds(tmp_path / CONTAINER)
        assert {key: found[key] for key in case.holds} == dict(case.holds)
