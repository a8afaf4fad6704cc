"""SH bands as chunks of their own (issue 19): a layered stream's base is stored with DC colour
only and its bands beyond DC come in SH-band chunks of the next layer; readers put them back
texel for texel, and everything that reads chunks knows the kind."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tsog_stream.client import StreamClient
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, decode_chunk_bytes, encode_chunk
from tsog_stream.codec.sh_bands import (
    decode_sh_bands,
    decode_sh_bands_bytes,
    encode_sh_bands,
    without_sh,
)
from tsog_stream.errors import InputError, IntegrityError, MetaError, SogError
from tsog_stream.io.sequence import open_sequence
from tsog_stream.model import Scene, TimelineType
from tsog_stream.render import from_capture, render, to_uint8
from tsog_stream.render.metrics import psnr
from tsog_stream.schemas.manifest import dump_manifest, parse_manifest
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.synthetic import SceneSpec, generate_scene, small_scene


@pytest.fixture(scope="module")
def host() -> Scene:
    return small_scene(TimelineType.CENTER_SCALE, sh_bands=3)


def test_an_sh_band_chunk_restores_its_hosts_bands_texel_for_texel(host: Scene) -> None:
    whole = decode_chunk(encode_chunk(host))
    bare = decode_chunk_bytes(bundle_bytes(encode_chunk(without_sh(host))))
    bands = decode_sh_bands_bytes(bundle_bytes(encode_sh_bands(host)))
    assert bare.gaussians.shN.shape == (len(host), 0, 3)
    joined = bands.attach(bare, where="test")
    for name in ("means", "scales", "quats", "opacities", "sh0", "shN"):
        assert np.array_equal(getattr(joined.gaussians, name), getattr(whole.gaussians, name))
    assert bands.shN.shape == (len(host), 15, 3) and np.abs(bands.shN).max() > 0


def test_sh_bands_of_another_count_are_refused(host: Scene) -> None:
    bands = decode_sh_bands(encode_sh_bands(host))
    other = decode_chunk(encode_chunk(without_sh(host.subset(np.arange(10)))))
    with pytest.raises(IntegrityError, match="SH bands of 1200 Gaussians for a chunk of 10"):
        bands.attach(other, where="test")


def test_each_kind_of_chunk_refuses_to_be_read_as_the_other(host: Scene) -> None:
    with pytest.raises(MetaError, match="meta of an SH-band chunk"):
        decode_chunk(encode_sh_bands(host))
    with pytest.raises(MetaError, match="expected an SH-band chunk"):
        decode_sh_bands(encode_chunk(host))


def _forged(files: dict[str, bytes], change: Callable[[dict[str, Any]], None]) -> dict[str, bytes]:
    meta = json.loads(files["meta.json"])
    change(meta)
    return {**files, "meta.json": json.dumps(meta).encode()}


def _set_count(n: int) -> Callable[[dict[str, Any]], None]:
    return lambda meta: meta.update(count=n)


def _set_bands(meta: dict[str, Any]) -> None:
    meta["shN"]["bands"] = 1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_set_count(36_000_000), "36000000 Gaussians, over the read budget"),
        (_set_count(1300), r"expected at most \d+ Gaussians \('shN_labels.webp' is"),
        (_set_bands, "expected width 192 .64 x coefficients of 1 bands., found 960"),
    ],
)
def test_an_sh_band_chunk_is_checked_against_its_count_before_decoding(
    host: Scene, change: Callable[[dict[str, Any]], None], message: str
) -> None:
    """The same budgets as any chunk: counts and image sizes from the WebP headers, before
    a pixel is decoded."""
    with pytest.raises((SogError, MetaError), match=message):
        decode_sh_bands(_forged(encode_sh_bands(host), change))


@pytest.fixture(scope="module")
def streams(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """A generated scene with three SH bands, with three quality layers and with one."""
    folder = tmp_path_factory.mktemp("sh_bands")
    scene = generate_scene(SceneSpec(background=2000, objects=4, per_object=300, sh_bands=3))
    out = {}
    for layers in (3, 1):
        out[layers] = folder / f"{layers}.tsogs"
        segment_scene(scene, out[layers], SegmentOptions(window_s=1.0, layers=layers))
    return out


def test_a_layered_base_is_stored_without_its_bands_and_they_follow_it(
    streams: dict[int, Path],
) -> None:
    async def run() -> None:
        async with await StreamClient.open(streams[3]) as client:
            m = client.index.manifest
            base = [c for c in m.chunks if c.layer == 0]
            bands = [c for c in m.chunks if c.sh_of is not None]
            assert sorted(c.sh_of or 0 for c in bands) == [c.id for c in base]  # one each
            for c in bands:
                host = m.chunks[c.sh_of or 0]
                assert (c.layer, c.count, c.node, c.level) == (1, host.count, host.node, host.level)
                assert (c.start_s, c.end_s) == (host.start_s, host.end_s)
            # the file: every base chunk, then their bands, then the rest of layer 1
            kinds = [(c.layer, c.sh_of is None) for c in sorted(m.chunks, key=lambda c: c.offset)]
            assert kinds == sorted(kinds, key=lambda k: (k[0], k[1]))
            # the index counts Gaussians once: SH-band chunks hold none
            stored = sum(c.count for c in m.chunks if c.sh_of is None)
            assert sum(layer.gaussians for layer in m.layers) == stored == m.scene.stored
            for c in base:
                bare = decode_chunk_bytes(await client.chunk_bytes(c.id))
                assert bare.gaussians.shN.shape[1] == 0
                assert (await client.chunk_scene(c.id)).gaussians.shN.shape[1] == 15
            with pytest.raises(InputError, match=f"holds the SH bands of chunk {base[0].id}"):
                await client.chunk_scene(bands[0].id)
            assert (await client.verify()).problems == []

    asyncio.run(run())


def test_the_base_shows_dc_colour_and_all_layers_the_one_layer_frame(
    streams: dict[int, Path],
) -> None:
    """The recorded base PSNR (measured with DC colour only) is what the decoded base shows;
    the second layer brings the base's bands; all layers show the one-layer picture."""

    async def run() -> None:
        async with (
            await StreamClient.open(streams[3]) as layered,
            await StreamClient.open(streams[1]) as single,
        ):
            m = layered.index.manifest
            assert m.view is not None and m.layers[0].psnr_db is not None
            camera = from_capture(m.view, 256)
            times = [(k + 0.5) * (m.scene.end_s - m.scene.start_s) / 3 for k in range(3)]
            errors = []
            for t in times:
                base = await layered.frame_at(t, layers=1)
                two = await layered.frame_at(t, layers=2)
                full = await layered.frame_at(t)
                assert not np.any(base.shN)
                assert np.count_nonzero(np.any(two.shN != 0, axis=(1, 2))) >= len(base)
                whole = await single.frame_at(t)
                shown = [to_uint8(render(g, camera)) for g in (base, full, whole)]
                assert psnr(shown[1], shown[2]) > 40.0, t
                errors.append(np.mean((shown[0] / 255.0 - shown[1] / 255.0) ** 2))
            measured = -10 * math.log10(float(np.mean(errors)))
            assert abs(measured - m.layers[0].psnr_db) < 1.5, (measured, m.layers[0].psnr_db)

    asyncio.run(run())


REAL_SH_FRAMES = (
    "3dgs/gs3d_pr477_lod2_tile_0.ply",
    "3dgs/supersplat_pr291_fruit_drops_minimal.ply",
    "3dgs/gs3d_pr477_lod3_tile_0.ply",
)
"""Three real captures with three SH bands (tests/data/real), played as a flipbook."""


def test_a_frame_sequences_bands_follow_each_frames_base(samples: Path, tmp_path: Path) -> None:
    """Per-frame windows of real SH3 captures: every window's SH-band chunks name the base
    chunks of that window (the index refuses any other pairing), the base shows DC colour, and
    every layer together is the one-layer frame."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, name in enumerate(REAL_SH_FRAMES):
        (folder / f"frame_{k:03d}.ply").write_bytes((samples / name).read_bytes())
    seq = open_sequence(folder, fps=10.0)
    paths = {n: tmp_path / f"{n}.tsogs" for n in (3, 1)}
    for n, path in paths.items():
        segment_sequence(seq, path, SegmentOptions(layers=n))

    async def run() -> None:
        async with (
            await StreamClient.open(paths[3]) as layered,
            await StreamClient.open(paths[1]) as single,
        ):
            m = layered.index.manifest
            assert m.scene.sh_bands == 3 and m.view is not None
            assert {c.node for c in m.chunks if c.sh_of is not None} == {0, 1, 2}
            camera = from_capture(m.view, 160)
            for k, (count, _) in enumerate(seq.shapes):
                t = (k + 0.5) / seq.fps
                base = await layered.frame_at(t, layers=1)
                full, whole = await layered.frame_at(t), await single.frame_at(t)
                assert len(full) == len(whole) == count and not np.any(base.shN)
                same = psnr(to_uint8(render(full, camera)), to_uint8(render(whole, camera)))
                assert same > 40.0, (t, same)

    asyncio.run(run())


def _paired(chunks: list[tuple[int, int, int | None]], sh_bands: int = 3) -> bytes:
    """An index document of one window holding ``chunks`` (count, layer, sh_of each)."""
    box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
    entries = [
        {
            "id": i,
            "file": f"chunks/{i:06d}.sog",
            "offset": 16384 + 10 * i,
            "length": 10,
            "sha256": "0" * 64,
            "count": count,
            "level": 0,
            "node": 0,
            "start_s": 0.0,
            "end_s": 1.0,
            "bbox": box,
            "layer": layer,
            "sh_of": sh_of,
        }
        for i, (count, layer, sh_of) in enumerate(chunks)
    ]
    layers = [
        {"index": k, "gaussians": 1, "bytes": 1, "psnr_db": None if k == 1 else 20.0}
        for k in range(2)
    ]
    return json.dumps(
        {
            "generator": "t",
            "policy": "hybrid",
            "window_s": 1.0,
            "max_pixels": 4096,
            "scene": {
                "gaussians": 2,
                "stored": 2,
                "start_s": 0.0,
                "end_s": 1.0,
                "timeline_type": 2,
                "temporal": {},
                "sh_bands": sh_bands,
                "bbox": box,
            },
            "nodes": [
                {
                    "level": 0,
                    "index": 0,
                    "start_s": 0.0,
                    "end_s": 1.0,
                    "chunks": list(range(len(entries))),
                }
            ],
            "chunks": entries,
            "payload_bytes": 10 * len(entries),
            "layers": layers,
        }
    ).encode()


def test_an_index_pairing_chunks_that_cannot_belong_together_is_refused() -> None:
    good = [(5, 0, None), (5, 1, 0)]
    assert parse_manifest(_paired(good)).chunks[1].sh_of == 0
    assert '"sh_of"' not in json.dumps(
        json.loads(dump_manifest(parse_manifest(_paired(good))))["chunks"][0]
    )
    bad = {
        "the scene has no SH bands": (good, 0),
        "the host must be an earlier chunk": ([(5, 1, 1), (5, 0, None)], 3),
        "differs in count and is in layer 0": ([(5, 0, None), (6, 1, 0)], 3),
        "differs in nothing and is in layer 1, not below 1": ([(5, 1, None), (5, 1, 0)], 3),
        "already has bands": ([(5, 0, None), (5, 1, 0), (5, 1, 0)], 3),
    }
    for message, (chunks, sh_bands) in bad.items():
        with pytest.raises(MetaError, match=message):
            parse_manifest(_paired(chunks, sh_bands))
