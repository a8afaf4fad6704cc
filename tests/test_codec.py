"""SOG/TSOG chunk codec: round trips against the source within stated tolerances."""

from __future__ import annotations

import io
import json
import math
import multiprocessing
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from helpers import check_decoded_at, log_space_error, means_log_step
from tsog_stream import Scene, SogError, TimelineType, TsogError
from tsog_stream.codec import webp
from tsog_stream.codec.bundle import bundle_bytes, read_bundle
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, texel_order
from tsog_stream.codec.positions import decode_means
from tsog_stream.codec.rotations import SQRT2, decode_quats, encode_quats
from tsog_stream.codec.sog_decode import decode_sh
from tsog_stream.codec.sog_encode import scale_importance
from tsog_stream.codec.webp import ImageDecoder, ImageEncoder, decode_webp, encode_webp
from tsog_stream.compare import attribute_errors, rotation_angles_deg
from tsog_stream.io.ply import read_ply
from tsog_stream.model import Timeline
from tsog_stream.morton import morton_order
from tsog_stream.opacity import alpha_to_logit
from tsog_stream.quantize import assign_codebook, build_codebook
from tsog_stream.synthetic import small_scene, static_gaussians
from tsog_stream.temporal import (
    lifespans,
)

ROTATION_MAX_DEG = 1.1
"""Smallest-three, 8 bits per component: each stored component within 1/(255 sqrt2) after
rounding; with the reconstructed fourth component the worst case measured on real data is 0.95."""
ROTATION_MEAN_DEG = 0.4


@pytest.fixture(scope="module")
def sh3_scene(samples: Path) -> Scene:
    return Scene(read_ply(samples / "3dgs/supersplat_pr291_fruit_drops_minimal.ply").gaussians)


def test_static_round_trip_within_tolerances(sh3_scene: Scene) -> None:
    files = encode_chunk(sh3_scene)
    decoded = decode_chunk(files)
    src = sh3_scene.subset(texel_order(sh3_scene)).gaussians
    got = decoded.gaussians
    meta = json.loads(files["meta.json"])
    step = means_log_step(meta["means"]["mins"], meta["means"]["maxs"])
    float32_rounding = 1e-7  # decoded positions are float32
    assert np.all(log_space_error(src.means, got.means) <= step * 0.5 + float32_rounding)
    angles = rotation_angles_deg(src.quats, got.quats)
    assert angles.max() < ROTATION_MAX_DEG and angles.mean() < ROTATION_MEAN_DEG
    err = attribute_errors(src, got)
    alpha_step = 1 / 255
    assert err.opacity_max <= alpha_step / 2 + 1e-6
    assert err.scales_mean < 0.02 and err.sh0_mean < 0.01
    assert got.shN.shape == src.shN.shape and err.shN_rms < 0.05


def test_encoding_is_deterministic(sh3_scene: Scene) -> None:
    a = encode_chunk(sh3_scene, seed=3)
    b = encode_chunk(sh3_scene, seed=3)
    assert a == b
    assert bundle_bytes(a) == bundle_bytes(b)
    assert list(a)[-1] == "meta.json"


def test_bundle_round_trip_and_layout(sh3_scene: Scene) -> None:
    files = encode_chunk(sh3_scene)
    data = bundle_bytes(files)
    assert read_bundle(data) == files
    assert data[-22:-20] == b"PK" and data[-2:] == b"\x00\x00"  # end record, no comment


def test_meta_json_is_deflated_and_its_floats_are_exact(sh3_scene: Scene) -> None:
    """Spec 0.4: images stored, meta.json deflated; every codebook value is written as the
    shortest decimal that reads back as the very float32 the encoder chose."""
    files = encode_chunk(sh3_scene)
    with zipfile.ZipFile(io.BytesIO(bundle_bytes(files))) as archive:
        methods = {i.filename: i.compress_type for i in archive.infolist()}
        packed = archive.getinfo("meta.json").compress_size
    assert methods.pop("meta.json") == zipfile.ZIP_DEFLATED
    assert set(methods.values()) == {zipfile.ZIP_STORED}
    assert packed < 0.6 * len(files["meta.json"])
    meta = json.loads(files["meta.json"])
    for values in (meta["scales"]["codebook"], meta["sh0"]["codebook"], meta["means"]["mins"]):
        assert all(float(str(np.float32(v))) == v for v in values)  # shortest for its float32


@pytest.mark.parametrize("kind", list(TimelineType))
@pytest.mark.parametrize("order", [1, 2, 3])
def test_tsog_round_trip_matches_source_at_t(kind: TimelineType, order: int) -> None:
    scene = small_scene(kind, motion_order=order, dynamic=("means", "quats", "opacity"), seed=order)
    files = encode_chunk(scene)
    decoded = decode_chunk(files)
    src = scene.subset(texel_order(scene))
    assert decoded.timeline is not None and src.timeline is not None
    assert decoded.timeline.type is kind
    meta = json.loads(files["meta.json"])
    assert src.timeline is not None
    start, end = lifespans(src.timeline)
    edges = [*start[-3:].tolist(), *end[-3:].tolist()]  # object Gaussians come last
    for t in sorted({0.0, 0.37, 1.0, 1.99, *edges}):
        check_decoded_at(src, decoded, meta, t)


def test_frame_ids_survive_exactly() -> None:
    scene = small_scene(TimelineType.FRAME)
    decoded = decode_chunk(encode_chunk(scene))
    src = scene.subset(texel_order(scene))
    assert decoded.timeline is not None and src.timeline is not None
    np.testing.assert_array_equal(decoded.timeline.t0, src.timeline.t0)
    assert decoded.timeline.fps == src.timeline.fps


def test_frame_content_is_ordered_frame_after_frame_each_in_morton_order() -> None:
    """Spec §3: a type-0 chunk holds frame 0's Gaussians first, each frame in its own Morton
    order, whatever the input order; frames sharing the same space make a smaller chunk so
    than interleaved in one Morton order: what is the same within a frame (here colour, size
    and frame id) is one run of texels."""
    rng = np.random.default_rng(5)
    g = static_gaussians(3000, seed=4)
    ids = rng.integers(0, 3, 3000).astype(np.float64)  # three frames over the same box
    g.sh0 = np.repeat(ids[:, None] - 1.0, 3, axis=1).astype(np.float32)  # a colour per frame
    g.scales = np.repeat(ids[:, None] - 5.0, 3, axis=1).astype(np.float32)  # and a size
    g.quats[:] = (1.0, 0.0, 0.0, 0.0)  # the positions the only noise
    scene = Scene(g, Timeline(TimelineType.FRAME, ids, np.zeros(3000), 30.0))
    order = texel_order(scene)
    assert np.all(np.diff(ids[order]) >= 0)
    for frame in range(3):
        run = order[ids[order] == frame]
        inside = np.flatnonzero(ids == frame)
        np.testing.assert_array_equal(run, inside[morton_order(g.means[inside])])
    decoded = decode_chunk(encode_chunk(scene))
    assert decoded.timeline is not None and np.all(np.diff(decoded.timeline.t0) >= 0)
    per_frame = ("sh0.webp", "scales.webp", "timeline_l.webp", "timeline_u.webp")
    grouped, mixed = (
        sum(len(files[name]) for name in per_frame)
        for files in (encode_chunk(scene), encode_chunk(scene, order=morton_order(g.means)))
    )
    assert grouped < 0.7 * mixed, (grouped, mixed)


def test_an_error_in_the_timeline_made_beside_the_codebooks_reaches_the_caller() -> None:
    """The timeline is made on a thread beside the codebooks: its InputError (frame ids a
    16-bit range cannot hold) still reaches the caller as itself, naming the timeline."""
    g = static_gaussians(200, seed=2)
    ids = np.where(np.arange(200) < 100, 0.0, 70_000.0)
    scene = Scene(g, Timeline(TimelineType.FRAME, ids, np.zeros(200), 30.0))
    with pytest.raises(TsogError, match="frame ids span 70000 frames") as caught:
        encode_chunk(scene, quality=50)
    assert caught.value.where == "timeline"


def test_tsog_chunk_is_a_superset_of_sog() -> None:
    scene = small_scene(TimelineType.CENTER_SCALE, dynamic=("means", "quats"))
    files = encode_chunk(scene)
    meta = json.loads(files["meta.json"])
    assert meta["version"] == 2 and list(meta)[:3] == ["version", "asset", "count"]
    assert meta["timeline"]["files"] == ["timeline_l.webp", "timeline_u.webp"]
    assert meta["temporal"]["quats"]["files"][:2] == [
        "temporal_quats_1_l.webp",
        "temporal_quats_1_u.webp",
    ]
    static = decode_chunk(
        {k: v for k, v in files.items() if not k.startswith(("timeline", "temporal"))}
        | {
            "meta.json": json.dumps(
                {k: v for k, v in meta.items() if k not in ("timeline", "temporal")}
            ).encode()
        }
    )
    assert static.timeline is None and len(static) == len(scene)


def _damaged(files: dict[str, bytes], name: str, data: bytes) -> dict[str, bytes]:
    out = dict(files)
    out[name] = data
    return out


def test_bad_chunks_raise_tsog_errors_naming_the_file(sh3_scene: Scene) -> None:
    files = encode_chunk(sh3_scene)
    with pytest.raises(SogError, match=r"scales\.webp"):
        decode_chunk(_damaged(files, "scales.webp", files["scales.webp"][:100]))
    with pytest.raises(SogError, match=r"quats\.webp"):
        decode_chunk(_damaged(files, "quats.webp", b"GIF89a" + b"\0" * 64))
    small = encode_chunk(sh3_scene.subset(np.arange(10)))
    with pytest.raises(TsogError, match="sh0"):
        decode_chunk(_damaged(files, "sh0.webp", small["sh0.webp"]))
    with pytest.raises(SogError, match="missing"):
        decode_chunk({k: v for k, v in files.items() if k != "means_u.webp"})
    with pytest.raises(SogError, match="zip"):
        read_bundle(bundle_bytes(files)[:-30])
    with pytest.raises(SogError):
        read_bundle(b"not a zip at all")


def _quats_by_formula(texels: np.ndarray) -> np.ndarray:
    """Smallest-three decoding written out per Gaussian in float64 (SOG v2, as splat-transform)."""
    out = np.zeros((len(texels), 4))
    for i, (a, b, c, tag) in enumerate(texels.astype(np.float64)):
        largest = int(tag) - 252
        if not 0 <= largest <= 3:
            out[i] = (1.0, 0.0, 0.0, 0.0)
            continue
        kept = [(v / 255.0 * 2.0 - 1.0) / np.sqrt(2.0) for v in (a, b, c)]
        rest = np.sqrt(max(0.0, 1.0 - (kept[0] * kept[0] + kept[1] * kept[1] + kept[2] * kept[2])))
        out[i] = [*kept[:largest], rest, *kept[largest:]]
    return out.astype(np.float32)


def _quat_texel_by_formula(quat: np.ndarray) -> list[int]:
    """Smallest-three encoding written out for one quaternion in float64 (SOG v2): unit, the
    largest |component| (the first of equals) made positive and dropped, the rest as bytes; a
    zero or non-finite quaternion is the identity."""
    q = [float(v) for v in quat]
    norm = math.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3])
    largest = int(np.argmax(np.abs(np.asarray(q))))  # numpy's first-of-equals, NaN first
    sign = -1.0 if q[largest] < 0 else 1.0
    unit = [v * (sign / norm if norm > 0 else 1.0) for v in q]
    if not any(v != 0 for v in q) or not all(math.isfinite(v) for v in unit):
        unit, largest = [1.0, 0.0, 0.0, 0.0], 0
    kept = [v for k, v in enumerate(unit) if k != largest]
    codes = [int(np.clip(np.rint(255.0 * (v * SQRT2 * 0.5 + 0.5)), 0, 255)) for v in kept]
    return [*codes, 252 + largest]


def test_rotations_encode_as_the_per_gaussian_formula_bit_for_bit() -> None:
    """Rotations are encoded column by column (masks, byte picks); every texel is the formula's,
    through ties, zeros, negative largest parts, NaN, infinities and huge or tiny values."""
    rng = np.random.default_rng(8)
    quats = rng.normal(size=(3000, 4)).astype(np.float32)
    quats[::7] = np.round(quats[::7])  # ties between components
    quats[::11] = np.abs(np.round(quats[::11] * 2))
    quats[::13] = 0.0
    quats[::17, 1] = np.nan
    quats[::19, 0] = np.inf
    quats[::23, 3] = -np.inf
    with np.errstate(all="ignore"):  # some huge ones overflow to infinity
        quats[::29] *= np.float32(1e38)
        quats[::31] *= np.float32(1e-38)
        encoded = encode_quats(quats)
        expected = np.array([_quat_texel_by_formula(q) for q in quats], np.uint8)
    assert np.array_equal(encoded, expected)
    assert np.array_equal(encode_quats(np.zeros((0, 4), np.float32)), np.zeros((0, 4), np.uint8))


def test_table_decoders_equal_the_float64_formulas_bit_for_bit() -> None:
    """Rotations, positions, colours and opacities decode through lookup tables; each table
    holds the formula's values, so the result is the formula's, to the bit."""
    rng = np.random.default_rng(3)
    texels = rng.integers(0, 256, (4000, 4), dtype=np.uint8)
    texels[:, 3] = rng.integers(250, 257, 4000).clip(0, 255)  # the four tags and bad ones
    assert np.array_equal(decode_quats(texels), _quats_by_formula(texels))

    low, high = (rng.integers(0, 256, (4000, 3), dtype=np.uint8) for _ in range(2))
    mins, maxs = np.array([-2.0, 0.5, 1.0]), np.array([3.0, 0.5, 4.0])  # y: an empty range
    codes = low.astype(np.float64) + 256.0 * high
    span = np.where(maxs > mins, maxs - mins, 1.0)
    logs = mins + span * (codes / 65535.0)
    expected = (np.sign(logs) * np.expm1(np.abs(logs))).astype(np.float32)
    assert np.array_equal(decode_means(low, high, mins, maxs), expected)

    files = encode_chunk(Scene(static_gaussians(500, seed=2)))
    decoded = decode_chunk(files).gaussians
    meta = json.loads(files["meta.json"])
    sh0 = decode_webp(files["sh0.webp"], where="sh0").reshape(-1, 4)[:500]
    colours = np.asarray(meta["sh0"]["codebook"], np.float32)[sh0[:, :3]]
    assert np.array_equal(decoded.sh0, colours)
    assert np.array_equal(decoded.opacities, alpha_to_logit(sh0[:, 3] / 255.0))


def test_sh_labels_past_the_palette_decode_to_zero() -> None:
    """A label at or past the palette's count gives zero SH (as splat-transform does); the
    others their palette entry's codebook values, coefficient by coefficient."""
    codebook = np.linspace(-1.0, 1.0, 256).astype(np.float32).tolist()
    entries = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(1, 6, 4) * 7  # 2 entries x 3 coeffs
    labels = np.zeros((1, 4, 4), np.uint8)
    labels[0, :, 0] = [1, 0, 2, 44]  # low bytes: 1, 0, 2 (past the count), 300 (past)
    labels[0, 3, 1] = 1
    shn = SimpleNamespace(bands=1, files=["c", "l"], codebook=codebook, count=2)
    out = decode_sh(shn, {"c": entries, "l": labels}, 4)
    table = np.asarray(codebook, np.float32)
    palette = table[entries.reshape(2, 3, 4)[:, :, :3]]
    assert out.shape == (4, 3, 3) and out.dtype == np.float32
    assert np.array_equal(out[0], palette[1]) and np.array_equal(out[1], palette[0])
    assert not out[2:].any()
    every = decode_sh(shn, {"c": entries, "l": labels[:, :2]}, 2)
    assert np.array_equal(every, palette[[1, 0]])
    empty = SimpleNamespace(bands=1, files=["c", "l"], codebook=codebook, count=0)
    assert not decode_sh(empty, {"c": entries, "l": labels}, 4).any()


def test_a_big_palette_decodes_alike_in_halves() -> None:
    """Palettes and label sets big enough to be gathered in two halves (webp.in_two) give
    every row its entry's values, and zeros for labels past the palette, as one gather does."""
    rng = np.random.default_rng(6)
    entries, count = 40_000, 50_000
    coeffs = 3
    image = rng.integers(0, 256, (entries // 64 + 1, 64 * coeffs, 4), np.uint8)
    labels = rng.integers(0, entries, count)
    labels[::7] = entries + rng.integers(0, 100, labels[::7].size)  # some past the palette
    texels = np.zeros((count, 4), np.uint8)
    texels[:, 0], texels[:, 1] = labels & 0xFF, labels >> 8
    codebook = np.sort(rng.normal(0, 1, 256)).astype(np.float32)
    shn = SimpleNamespace(bands=1, files=["c", "l"], codebook=codebook.tolist(), count=entries)
    for kept in (np.flatnonzero(labels < entries), np.arange(count)):  # all valid; some not
        out = decode_sh(shn, {"c": image, "l": texels[kept]}, kept.size)
        palette = codebook[image.reshape(-1, coeffs, 4)[:entries, :, :3]]
        expected = np.zeros((kept.size, coeffs, 3), np.float32)
        inside = labels[kept] < entries
        expected[inside] = palette[labels[kept][inside]]
        assert np.array_equal(out, expected)


def _same_scene(a: Scene, b: Scene) -> bool:
    """Whether two decoded scenes hold the same Gaussians, to the bit."""
    fields = ("means", "scales", "quats", "opacities", "sh0", "shN")
    return all(np.array_equal(getattr(a.gaussians, f), getattr(b.gaussians, f)) for f in fields)


def test_chunks_decoded_from_many_threads_at_once_equal_one_by_one() -> None:
    """The decoding pools are the process's: chunks decoded by eight threads at once (as the
    client's prefetch does) each give what decoding them alone gives."""
    chunks = [encode_chunk(Scene(static_gaussians(3000, sh_bands=k % 2, seed=k))) for k in range(8)]
    alone = [decode_chunk(files) for files in chunks]
    with ThreadPoolExecutor(8) as pool:
        together = list(pool.map(decode_chunk, chunks))
    assert all(_same_scene(a, b) for a, b in zip(alone, together, strict=True))


def test_a_forked_child_decodes_with_pools_of_its_own() -> None:
    """A process forked after its parent decoded has none of the parent's pool threads: it
    must make its own rather than queue work for threads that do not exist there."""
    files = encode_chunk(Scene(static_gaussians(2000, seed=4)))
    expected = decode_chunk(files)  # the parent's pools exist from here
    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        means = pool.apply_async(_decoded_means, (files,)).get(timeout=60)
    assert np.array_equal(means, expected.gaussians.means)


def _decoded_means(files: dict[str, bytes]) -> np.ndarray:
    """The decoded positions of a chunk (run in a child process)."""
    return decode_chunk(files).gaussians.means


def test_a_failed_decode_leaves_none_of_its_work_running() -> None:
    """Leaving a decoder by an error cancels its work not yet started and waits for the rest:
    nothing of a refused chunk runs on in the shared pools."""
    files = encode_chunk(Scene(static_gaussians(4000, seed=5)))
    images = {name: data for name, data in files.items() if name.endswith(".webp")}
    images["means_l.webp"] = images["means_l.webp"][:40]  # a header, then nothing
    futures = []
    with pytest.raises(SogError, match=r"means_l\.webp"), ImageDecoder(images, where="x") as dec:
        for name in images:
            futures.append(dec.then([name], lambda got: sum(int(a.sum()) for a in got.values())))
        futures[0].result()
    assert all(future.done() for future in futures)


def _noise_images(count: int, seed: int) -> dict[str, np.ndarray]:
    """``count`` random 64x48 RGBA images (noise: each takes libwebp a while)."""
    rng = np.random.default_rng(seed)
    return {f"img_{k}.webp": rng.integers(0, 256, (48, 64, 4), np.uint8) for k in range(count)}


def test_images_encoded_as_they_come_are_the_files_in_the_order_added() -> None:
    """An encoder given images in batches (as a chunk's attributes are made) returns every
    image's own WebP bytes in the order added, however the threads finished them."""
    first, second = _noise_images(3, seed=1), _noise_images(9, seed=2)
    second = {f"later_{name}": image for name, image in second.items()}
    with ImageEncoder() as encoder:
        encoder.add(first)
        encoder.add(second)
        files = encoder.files()
    assert list(files) == [*first, *second]
    for name, image in {**first, **second}.items():
        assert files[name] == encode_webp(image)
        assert np.array_equal(decode_webp(files[name], where=name), image)
    with ImageEncoder() as encoder, pytest.raises(ValueError, match="added twice"):
        encoder.add(first)
        encoder.add({"img_0.webp": first["img_0.webp"]})


@pytest.mark.parametrize("pillow_decoder", ["libwebp", "absent", "another"])
def test_webp_planes_decode_alike_through_libwebp_and_through_pillow(
    monkeypatch: pytest.MonkeyPatch, pillow_decoder: str
) -> None:
    """Planes are read straight from the libwebp decoder Pillow opens WebP with (no copies);
    where this Pillow has no such decoder or one of another signature, through Pillow's
    public path: both give every texel exactly (an opaque image, stored without alpha, reads
    back with alpha 255; a texel of alpha 0 keeps its RGB), and both refuse corrupt data with
    SogError."""
    rng = np.random.default_rng(4)
    opaque = rng.integers(0, 256, (40, 70, 4), np.uint8)
    opaque[..., 3] = 255
    clear = rng.integers(0, 256, (40, 70, 4), np.uint8)
    clear[::3, :, 3] = 0
    if pillow_decoder == "absent":
        monkeypatch.setattr(webp, "_pillow_webp", None)
    if pillow_decoder == "another":  # a decoder of another signature
        monkeypatch.setattr(webp, "_pillow_webp", SimpleNamespace(WebPAnimDecoder=lambda: None))
    for image in (opaque, clear, *_noise_images(2, seed=5).values()):
        data = encode_webp(image)
        decoded = decode_webp(data, where="plane")
        assert decoded.shape == image.shape and np.array_equal(decoded, image)
        with pytest.raises(SogError, match="corrupt WebP"):
            decode_webp(data[:40] + bytes(len(data) - 40), where="plane")
    direct = webp._libwebp_rgba(encode_webp(opaque), (70, 40))
    assert (direct is not None) is (pillow_decoder == "libwebp")


def test_work_split_in_two_does_every_row_once_and_keeps_the_helper_s_error() -> None:
    """in_two halves big work between the helper thread and the caller (every row once, in
    two disjoint halves), does small work at once, and raises an error of either half."""
    seen = np.zeros(webp.SPLIT_LEAST * 2 + 1, np.int64)
    calls: list[tuple[int, int]] = []

    def mark(start: int, stop: int) -> None:
        calls.append((start, stop))
        seen[start:stop] += 1

    webp.in_two(seen.size, mark)
    assert sorted(calls) == [(0, seen.size // 2), (seen.size // 2, seen.size)]
    assert (seen == 1).all()
    calls.clear()
    webp.in_two(100, mark)
    assert calls == [(0, 100)]

    def fail_first(start: int, stop: int) -> None:
        if start == 0:
            raise SogError("bad half", where="helper")

    with pytest.raises(SogError, match="bad half"):
        webp.in_two(seen.size, fail_first)


def test_leaving_an_encoder_by_an_error_leaves_none_of_its_work_running() -> None:
    """An error while a chunk is being made (after some images were handed over) cancels the
    encodes not started and waits for the rest: nothing of it runs on in the shared pool."""
    encoder = ImageEncoder()
    with pytest.raises(RuntimeError, match="palette"), encoder:
        encoder.add(_noise_images(12, seed=3))
        raise RuntimeError("the palette failed")
    futures = list(vars(encoder)["_files"].values())
    assert futures and all(future.done() for future in futures)


def test_a_chunks_files_keep_their_writing_order_while_encoded_as_they_come() -> None:
    """Images are compressed while the rest of the chunk is computed, yet the files come in
    the order they are made (the bundle's order, so its bytes), meta.json last, each the
    WebP of its image alone."""
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=1, motion_order=2, seed=8)
    files = encode_chunk(scene, quality=60)
    assert list(files) == [
        "means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp",
        "shN_centroids.webp", "shN_labels.webp", "timeline_l.webp", "timeline_u.webp",
        "temporal_means_1_l.webp", "temporal_means_1_u.webp",
        "temporal_means_2_l.webp", "temporal_means_2_u.webp", "meta.json",
    ]  # fmt: skip
    for name, data in files.items():
        if name != "meta.json":
            assert encode_webp(decode_webp(data, where=name)) == data


def _drawn_and_undrawn(seed: int) -> tuple[Scene, np.ndarray]:
    """A few big opaque Gaussians among many tiny faint ones spread over a wide range of
    sizes (a capture's floaters and dust); the mask of the big opaque ones."""
    rng = np.random.default_rng(seed)
    g = static_gaussians(20_000, sh_bands=0, seed=seed)
    drawn = np.zeros(len(g), bool)
    drawn[rng.choice(len(g), 2_000, replace=False)] = True
    g.scales[:] = np.where(
        drawn[:, None],
        rng.normal(-1.0, 0.3, g.scales.shape),
        rng.normal(-9.0, 3.0, g.scales.shape),
    ).astype(np.float32)
    g.opacities[:] = alpha_to_logit(np.where(drawn, 0.9, 0.02)).reshape(g.opacities.shape)
    return Scene(g), drawn


def test_the_scale_codebook_serves_the_gaussians_a_view_draws() -> None:
    """Weighted by what a size error shows (alpha and footprint), the codebook's entries go
    to the big opaque Gaussians: their decoded sizes are far closer than a codebook fitted
    by count gives them."""
    scene, drawn = _drawn_and_undrawn(31)
    weight = scale_importance(scene.gaussians)
    assert weight.shape == scene.gaussians.scales.shape
    assert np.median(weight[drawn]) > 1000 * np.median(weight[~drawn])
    order = texel_order(scene)
    decoded = decode_chunk(encode_chunk(scene, quality=100)).gaussians
    source = scene.gaussians.scales[order].astype(np.float64)
    error = np.abs(decoded.scales - source)[drawn[order]]
    by_count = build_codebook(scene.gaussians.scales).astype(np.float64)
    plain = np.abs(by_count[assign_codebook(source, by_count)] - source)[drawn[order]]
    assert error.mean() < 0.25 * plain.mean(), (error.mean(), plain.mean())
    assert error.max() <= plain.max()


@pytest.mark.parametrize(
    "kind", [TimelineType.FRAME, TimelineType.START_DURATION, TimelineType.CENTER_SCALE]
)
def test_a_scene_already_in_texel_order_is_encoded_without_a_copy_and_left_as_it_was(
    kind: TimelineType,
) -> None:
    """The segmenter hands the encoder its rows in texel order (the order of which is then the
    identity), so the encoder orders nothing; it writes none of the caller's arrays (all
    read-only here), and the files are those of the same scene in any other order."""
    scene = small_scene(kind, sh_bands=2, seed=8)
    ordered = scene.subset(texel_order(scene))
    np.testing.assert_array_equal(texel_order(ordered), np.arange(len(ordered)))
    arrays = ordered.arrays()
    for array in arrays:
        array.flags.writeable = False
    before = [a.copy() for a in arrays]
    held = [ordered.gaussians.means, ordered.timeline, *ordered.temporal.values()]
    assert encode_chunk(ordered, seed=4, quality=80) == encode_chunk(scene, seed=4, quality=80)
    for was, array in zip(before, ordered.arrays(), strict=True):
        np.testing.assert_array_equal(was, array)
    after = [ordered.gaussians.means, ordered.timeline, *ordered.temporal.values()]
    assert all(a is b for a, b in zip(held, after, strict=True))  # no attribute replaced
