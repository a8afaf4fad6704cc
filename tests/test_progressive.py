"""Progressive and adaptive streaming (issue 19): quality layers in the container, the shaped
loopback link, and the adaptive playback through it, against a real server."""

from __future__ import annotations

import asyncio
import gc
import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tsog_stream.cli.main import main
from tsog_stream.client import StreamClient
from tsog_stream.client.adaptive import (
    Throughput,
    choose_layers,
    delay_needed,
    layers_shown,
    startup_allowance,
)
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.codec.precision import DEFAULT_QUALITY
from tsog_stream.codec.sh_bands import without_sh
from tsog_stream.container.stream_index import StreamIndex, unpacked_index
from tsog_stream.errors import InputError, MetaError
from tsog_stream.framing import default_view
from tsog_stream.io.sequence import open_sequence
from tsog_stream.io.splatv import read_splatv
from tsog_stream.model import Gaussians, Scene
from tsog_stream.render import from_capture, render, to_uint8
from tsog_stream.render.metrics import psnr
from tsog_stream.schemas.manifest import Manifest, dump_manifest, parse_manifest
from tsog_stream.segment import SegmentOptions, segment_scene, segment_sequence
from tsog_stream.segment import layers as quality_layers
from tsog_stream.segment.layers import LAYER_TARGETS_DB, LayerPlan, importance, top_share
from tsog_stream.server import make_app, start_server
from tsog_stream.server.link import (
    DELAYED_PIECES,
    MAX_CONNECTIONS,
    PIECE,
    LinkShape,
    ThrottledRelay,
    parse_bandwidth,
    parse_latency,
)
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians
from tsog_stream.throttled_play import play_through_link

HANABI = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
HANABI_S = 4.0
"""The real fireworks clip of tests/data (24k Gaussians), read as 4 s."""


@pytest.fixture(scope="module")
def scene_files(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The real clip with three quality layers and with one."""
    folder = tmp_path_factory.mktemp("progressive")
    loaded = read_splatv(samples / HANABI, duration_s=HANABI_S)
    out = {}
    for name, layers in (("layered", 3), ("single", 1)):
        out[name] = folder / f"{name}.tsogs"
        options = SegmentOptions(window_s=1.0, layers=layers)
        segment_scene(loaded.scene, out[name], options, cameras=loaded.cameras)
    return out


def _open(path: Path) -> StreamIndex:
    async def run() -> StreamIndex:
        async with await StreamClient.open(path) as client:
            return client.index

    return asyncio.run(run())


def test_layers_are_cut_where_the_measured_picture_reaches_its_targets(
    scene_files: dict[str, Path],
) -> None:
    manifest = _open(scene_files["layered"]).manifest
    layers = manifest.layers
    assert [layer.index for layer in layers] == [0, 1, 2]
    assert sum(layer.gaussians for layer in layers) == manifest.scene.stored
    assert sum(layer.bytes for layer in layers) == manifest.payload_bytes
    assert layers[-1].psnr_db is None
    for layer, target in zip(layers[:-1], LAYER_TARGETS_DB, strict=False):
        assert layer.psnr_db is not None and layer.psnr_db >= target
    assert {c.layer for c in manifest.chunks} == {0, 1, 2}
    # chunks are written layer by layer: every base chunk before any enhancement
    layer_by_offset = [c.layer for c in sorted(manifest.chunks, key=lambda c: c.offset)]
    assert layer_by_offset == sorted(layer_by_offset)


def test_all_layers_show_the_single_layer_frame_and_fewer_show_less(
    scene_files: dict[str, Path],
) -> None:
    async def run() -> None:
        async with (
            await StreamClient.open(scene_files["layered"]) as layered,
            await StreamClient.open(scene_files["single"]) as single,
        ):
            view = layered.index.manifest.view
            assert view is not None
            camera = from_capture(view, 160)
            for t in (0.4, 2.0, 3.0):
                whole = await single.frame_at(t)
                counts = [len(await layered.frame_at(t, layers=k)) for k in (1, 2, 3)]
                assert counts[0] < counts[1] < counts[2] == len(whole)
                full = await layered.frame_at(t)
                same = psnr(to_uint8(render(full, camera)), to_uint8(render(whole, camera)))
                assert same > 40.0, (t, same)  # the same Gaussians, coded in other chunks

    asyncio.run(run())


def test_the_recorded_quality_is_what_the_decoded_base_shows(
    scene_files: dict[str, Path],
) -> None:
    """The index's PSNR (measured on the source at segment time) against the decoded stream's
    base-layer frames at the same times and view."""

    async def run() -> None:
        async with await StreamClient.open(scene_files["layered"]) as client:
            m = client.index.manifest
            assert m.view is not None
            camera = from_capture(m.view, 256)
            times = [(k + 0.5) * (m.scene.end_s - m.scene.start_s) / 3 for k in range(3)]
            errors = []
            for t in times:
                base = to_uint8(render(await client.frame_at(t, layers=1), camera))
                full = to_uint8(render(await client.frame_at(t), camera))
                errors.append(np.mean((base / 255.0 - full / 255.0) ** 2))
            measured = -10 * math.log10(float(np.mean(errors)))
            recorded = m.layers[0].psnr_db
            assert recorded is not None and abs(measured - recorded) < 1.5, (measured, recorded)

    asyncio.run(run())


def test_one_layer_writes_the_index_as_before(scene_files: dict[str, Path]) -> None:
    raw = dump_manifest(_open(scene_files["single"]).manifest)
    data = json.loads(raw)
    assert "layers" not in data
    assert all("layer" not in c for c in data["chunks"])
    layered = json.loads(dump_manifest(_open(scene_files["layered"]).manifest))
    assert all(c.get("layer", 0) == c["layer"] for c in layered["chunks"] if "layer" in c)
    assert all("layer" not in c for c in layered["chunks"] if c["offset"] < 20000)  # base


MONKEY = "4d/pc_flipbook_monkey"
"""Three real flipbook frames of tests/data (31658 Gaussians each, SOG)."""


def test_a_frame_sequence_is_layered_frame_by_frame(samples: Path, tmp_path: Path) -> None:
    """Each frame's most important Gaussians are its base (a share of every frame, not of
    the sequence); every layer together is the one-layer frame; the measured PSNR is what
    the decoded base shows."""
    seq = open_sequence(samples / MONKEY, fps=30.0)
    paths = {n: tmp_path / f"{n}.tsogs" for n in (1, 3)}
    for n, path in paths.items():
        segment_sequence(seq, path, SegmentOptions(layers=n))

    async def run() -> None:
        async with (
            await StreamClient.open(paths[3]) as layered,
            await StreamClient.open(paths[1]) as single,
        ):
            m = layered.index.manifest
            assert [layer.index for layer in m.layers] == [0, 1, 2]
            assert {c.layer for c in m.chunks} == {0, 1, 2}
            assert single.index.layer_count == 1
            assert m.view is not None
            camera = from_capture(m.view, 256)
            errors = []
            for k, (count, _) in enumerate(seq.shapes):
                t = (k + 0.5) / seq.fps
                whole = await single.frame_at(t)
                full = await layered.frame_at(t)
                base = await layered.frame_at(t, layers=1)
                assert len(whole) == len(full) == count
                assert 0 < len(base) < len(await layered.frame_at(t, layers=2)) < count
                same = psnr(to_uint8(render(full, camera)), to_uint8(render(whole, camera)))
                assert same > 40.0, (t, same)
                enhancing = [c for c in layered.index.chunks_for(t) if c.layer > 0]
                rest = [s.at(t) for s in await layered.chunk_scenes(enhancing)]
                least_in_base = importance(base).min()
                assert least_in_base >= 0.9 * importance(Gaussians.concat(rest)).max()
                shown = [to_uint8(render(g, camera)) for g in (base, full)]
                errors.append(np.mean((shown[0] / 255.0 - shown[1] / 255.0) ** 2))
            measured = -10 * math.log10(float(np.mean(errors)))
            recorded = m.layers[0].psnr_db
            assert recorded is not None and abs(measured - recorded) < 1.5, (measured, recorded)

    asyncio.run(run())


def test_a_flipbook_keeps_layers_only_within_its_own_bytes(samples: Path, tmp_path: Path) -> None:
    """Layers cost a frame two more chunks (zip, meta.json) and sparser positions: where they
    would make the container larger than the flipbook (independent random frames that quality
    90 hardly shrinks), the default is one layer and says why; ``--layers`` still forces
    them. The monkey flipbook, which our encoding shrinks, keeps its layers."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        frame = Scene(static_gaussians(30_000, seed=50 + k))
        (folder / f"frame_{k:03d}.sog").write_bytes(bundle_bytes(encode_chunk(frame)))
    flipbook = sum(p.stat().st_size for p in folder.iterdir())
    seq = open_sequence(folder, fps=30.0)
    auto, forced = tmp_path / "auto.tsogs", tmp_path / "forced.tsogs"
    options = SegmentOptions(workers=1, quality=DEFAULT_QUALITY)  # the CLI's default
    report = segment_sequence(seq, auto, options)
    segment_sequence(seq, forced, replace(options, layers=3))
    assert report.layers == []
    assert "its own SOG file" in report.layers_why and "--layers" in report.layers_why
    chunk_bytes = [sum(c.length for c in _open(p).manifest.chunks) for p in (auto, forced)]
    assert chunk_bytes[0] <= flipbook < chunk_bytes[1]  # the trade exists
    monkey = tmp_path / "monkey.tsogs"
    kept = segment_sequence(open_sequence(samples / MONKEY, fps=30.0), monkey, options)
    assert len(kept.layers) > 1, kept.layers_why
    assert monkey.stat().st_size <= sum(p.stat().st_size for p in (samples / MONKEY).iterdir())


def test_a_small_scene_stays_one_layer_unless_asked(tmp_path: Path) -> None:
    scene = generate_scene(SceneSpec(background=300, objects=2, per_object=50, sh_bands=0))
    auto, asked = tmp_path / "auto.tsogs", tmp_path / "asked.tsogs"
    report = segment_scene(scene, auto, SegmentOptions(window_s=1.0))
    assert report.layers == [] and "one layer" in report.layers_why
    assert segment_scene(scene, asked, SegmentOptions(window_s=1.0, layers=2)).layers
    with pytest.raises(InputError, match="--layers"):
        segment_scene(scene, tmp_path / "bad.tsogs", SegmentOptions(layers=9))


BOX = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
THREE_LAYERS = [
    {"index": k, "gaussians": 1, "bytes": 1, "psnr_db": None if k == 2 else 20.0} for k in range(3)
]


def _one_window(
    chunks: list[tuple[int, float, float, int]], layers: list[dict[str, Any]], window_s: float
) -> dict[str, Any]:
    """An index document of one window holding ``chunks`` ((layer, start_s, end_s, length)
    each, back to back from byte 16384) and ``layers``."""
    entries, offset = [], 16384
    for i, (layer, start, end, length) in enumerate(chunks):
        entries.append(
            {
                "id": i,
                "file": f"chunks/{i:06d}.sog",
                "offset": offset,
                "length": length,
                "sha256": "0" * 64,
                "count": 1,
                "level": 0,
                "node": 0,
                "start_s": start,
                "end_s": end,
                "bbox": BOX,
                "layer": layer,
            }
        )
        offset += length
    scene = {
        "gaussians": len(chunks), "stored": len(chunks), "start_s": 0.0, "end_s": window_s,
        "timeline_type": 2, "temporal": {}, "sh_bands": 0, "bbox": BOX,
    }  # fmt: skip
    node = {
        "level": 0,
        "index": 0,
        "start_s": 0.0,
        "end_s": window_s,
        "chunks": list(range(len(entries))),
    }
    return {
        "generator": "t", "policy": "hybrid", "window_s": window_s, "max_pixels": 4096,
        "scene": scene, "nodes": [node], "chunks": entries, "payload_bytes": offset - 16384,
        "layers": layers,
    }  # fmt: skip


def _manifest_with_layers(layers: list[dict[str, Any]], chunk_layer: int) -> bytes:
    """Index JSON of one chunk in layer ``chunk_layer`` and the given ``layers``."""
    return json.dumps(_one_window([(chunk_layer, 0.0, 1.0, 10)], layers, 1.0)).encode()


@pytest.mark.parametrize(
    ("layers", "chunk_layer", "message"),
    [
        ([], 1, "layer 1 of 1"),
        ([{"index": 0, "gaussians": 1, "bytes": 10, "psnr_db": None}], 2, "layer 2 of 1"),
        ([{"index": 1, "gaussians": 1, "bytes": 10, "psnr_db": None}], 0, "has index 1"),
        ([{"index": 0, "gaussians": -1, "bytes": 10, "psnr_db": None}], 0, "gaussians"),
        ([{"index": 0, "gaussians": 1, "bytes": 10, "psnr_db": float("nan")}], 0, "psnr"),
    ],
)
def test_an_index_with_inconsistent_layers_is_refused(
    layers: list[dict[str, Any]], chunk_layer: int, message: str
) -> None:
    with pytest.raises(MetaError, match=message):
        parse_manifest(_manifest_with_layers(layers, chunk_layer))


def test_layer_plan_assigns_the_most_important_share_of_each_group() -> None:
    plan = LayerPlan((0.25, 0.5, 1.0), (20.0, 30.0, None))
    weights = np.array([0.1, 0.9, 0.5, 0.7, 0.2, 0.3, 0.8, 0.0, 0.05, 0.01])
    groups = [np.arange(8), np.arange(8, 10)]
    layer = plan.assign(weights, groups)
    # group one: 2 of 8 in the base, 2 more in layer 1; group two: its best one in the base
    assert layer.tolist() == [2, 0, 1, 1, 2, 2, 0, 2, 0, 2]
    assert top_share(weights, groups, 0.25).tolist() == [1, 6, 8]


# --- the adaptation's decisions, on a hand-made index --------------------------------------


def _index(chunks: list[tuple[int, float, float, int]]) -> StreamIndex:
    """(layer, start_s, end_s, length) per chunk, one window of 10 s, three layers."""
    manifest = Manifest.model_validate(_one_window(chunks, THREE_LAYERS, 10.0))
    return unpacked_index(dump_manifest(manifest), where="test")


def test_delay_needed_is_the_worst_lateness_in_due_order() -> None:
    index = _index([(0, 0.0, 10.0, 100), (0, 5.0, 10.0, 1000)])
    chunks = index.manifest.chunks
    # 100 B due now, then 1000 B due 5 s later: at 100 B/s the second is 6 s late
    assert delay_needed(chunks, 0.0, 1.0, 100.0) == pytest.approx(6.0)
    assert delay_needed(chunks, 0.0, 2.0, 100.0) == pytest.approx(8.5)  # twice as fast
    assert delay_needed([], 0.0, 1.0, 100.0) == -math.inf
    assert delay_needed(chunks, 0.0, 1.0, 0.0) == math.inf


def test_startup_takes_the_layers_that_arrive_within_the_allowance() -> None:
    index = _index([(0, 0.0, 10.0, 100), (1, 0.0, 10.0, 300), (2, 0.0, 10.0, 3000)])

    def pick(allowance: float) -> int:
        # throughput 1000 B/s (x SAFETY): base 0.12 s, two layers 0.47 s, three 4 s
        return choose_layers(
            index, 0.0, 10.0, speed=1.0, rate=1000.0, have=lambda cid: False, current=0,
            allowance=allowance,
        )  # fmt: skip

    assert [pick(a) for a in (0.0, 0.5, 2.0, 5.0)] == [1, 2, 2, 3]
    assert startup_allowance(0.4) == 2.0 and startup_allowance(4.0) == 16.0


def test_playing_keeps_what_can_still_arrive_and_drops_to_the_base_when_it_cannot() -> None:
    index = _index([(0, 0.0, 10.0, 100), (1, 0.0, 10.0, 300), (2, 0.0, 10.0, 3000)])

    def has_base(cid: int) -> bool:
        return cid == 0

    def keep(rate: float, current: int, have: Callable[[int], bool] = has_base) -> int:
        return choose_layers(
            index, 0.0, 10.0, speed=1.0, rate=rate, have=have, current=current, allowance=0.0
        )

    assert keep(1000.0, 2) == 3  # 3300 B in 10 s at 850 B/s: 3.9 s, within 0.8 of the rest
    assert keep(350.0, 2) == 2  # the third layer's 3300 B would not arrive before the end
    assert keep(30.0, 2) == 1  # even the second layer's 300 B would not
    assert keep(1000.0, 3, lambda cid: False) == 3  # base due now: 0.12 s late at worst
    assert keep(50.0, 3, lambda cid: False) == 1  # the base itself would be late


def test_layers_shown_counts_complete_layers_only() -> None:
    index = _index([(0, 0.0, 10.0, 100), (1, 0.0, 10.0, 300), (1, 0.0, 10.0, 10)])
    assert layers_shown(index, 1.0, lambda cid: False) == 0
    assert layers_shown(index, 1.0, lambda cid: cid == 0) == 1
    assert layers_shown(index, 1.0, lambda cid: cid in (0, 1)) == 1  # layer 1 half there
    assert layers_shown(index, 1.0, lambda cid: True) == 3


def test_throughput_counts_busy_time_once_for_parallel_requests() -> None:
    now = [0.0]
    meter = Throughput(lambda: now[0])
    meter.started()
    meter.started()  # two requests share the link from t = 0
    now[0] = 1.0
    meter.finished(500)
    now[0] = 2.0
    meter.finished(1500)
    assert meter.estimate is not None
    # 500 B over the first busy second, then 1500 B over the next: EWMA of 500 and 1500
    assert meter.estimate == pytest.approx(500 + 0.3 * (1500 - 500))


# --- the shaped link ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "bits"),
    [("20Mbit", 20e6), ("500kbit", 5e5), ("1.5 Mbps", 1.5e6), ("2MB/s", 16e6), ("8bit", 8.0)],
)
def test_bandwidths_parse_in_bits_per_second(text: str, bits: float) -> None:
    assert parse_bandwidth(text) == pytest.approx(bits)


@pytest.mark.parametrize("text", ["", "20", "fast", "-1Mbit", "0Mbit", "1e999Mbit", "nan"])
def test_a_bad_bandwidth_is_refused(text: str) -> None:
    with pytest.raises(InputError, match="--bandwidth"):
        parse_bandwidth(text)


def test_latencies_parse_and_are_bounded() -> None:
    assert parse_latency("50ms") == pytest.approx(0.05)
    assert parse_latency("0.2s") == pytest.approx(0.2)
    for bad in ("50", "-5ms", "61s", "soon"):
        with pytest.raises(InputError, match="--latency"):
            parse_latency(bad)


async def _timed_get(url: str, nbytes: int) -> float:
    """Seconds to GET the first ``nbytes`` of ``url`` over a fresh connection (raw HTTP/1.1)."""
    host, rest = url.removeprefix("http://").split("/", 1)
    name, port = host.split(":")
    began = time.monotonic()
    reader, writer = await asyncio.open_connection(name, int(port))
    request = f"GET /{rest} HTTP/1.1\r\nHost: {host}\r\nRange: bytes=0-{nbytes - 1}\r\n"
    writer.write((request + "Connection: close\r\n\r\n").encode())
    body = await asyncio.wait_for(reader.read(), timeout=30)
    writer.close()
    assert b" 206 " in body.split(b"\r\n", 1)[0] and len(body) > nbytes
    return time.monotonic() - began


def test_the_link_carries_its_bandwidth_shared_and_adds_its_latency(tmp_path: Path) -> None:
    blob = tmp_path / "blob.bin"
    blob.write_bytes(np.random.default_rng(0).bytes(600_000))

    async def run() -> tuple[float, float, float, float]:
        runner, port = await start_server(make_app(tmp_path))
        try:
            async with ThrottledRelay(port, LinkShape(4e6, 0.0)) as relay:
                one = await _timed_get(relay.url("/files/blob.bin"), 250_000)  # 0.5 s of link
                two = await asyncio.gather(
                    *[_timed_get(relay.url("/files/blob.bin"), 250_000) for _ in range(2)]
                )
            async with ThrottledRelay(port, LinkShape(1e9, 0.2)) as relay:
                small = await _timed_get(relay.url("/files/blob.bin"), 100)
            return one, max(two), small, relay.bytes_down
        finally:
            await runner.cleanup()

    one, both, small, _ = asyncio.run(run())
    assert 0.45 < one < 0.75, one  # 250 kB at 500 kB/s
    assert 0.9 < both < 1.4, both  # two at once share the one link
    assert 0.2 <= small < 0.45, small  # the added round trip, at a bandwidth that costs nothing


def _socket_buffers_max() -> int:
    """The most bytes one loopback socket pair may hold in the kernel (send + receive)."""
    total = 0
    for name, fallback in (("tcp_wmem", 4 << 20), ("tcp_rmem", 6 << 20)):
        try:
            total += int(Path(f"/proc/sys/net/ipv4/{name}").read_text().split()[2])
        except (OSError, IndexError, ValueError):
            total += fallback
    return total


def test_a_viewer_flooding_the_link_is_held_back_not_buffered() -> None:
    """Request bytes the origin does not read wait in the kernel and in the relay's bounded
    queue: the viewer's writes stop, the relay does not take whatever it is sent."""
    bound = 2 * _socket_buffers_max() + DELAYED_PIECES * PIECE + (2 << 20)
    flood = bound + (64 << 20)

    async def run() -> tuple[int, list[dict[str, Any]]]:
        errors: list[dict[str, Any]] = []
        asyncio.get_running_loop().set_exception_handler(lambda _, context: errors.append(context))
        release = asyncio.Event()

        async def never_read(_: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await release.wait()
            writer.close()

        origin = await asyncio.start_server(never_read, "127.0.0.1", 0)
        try:
            async with ThrottledRelay(
                origin.sockets[0].getsockname()[1], LinkShape(1e9, 0.01)
            ) as relay:
                _, writer = await asyncio.open_connection("127.0.0.1", relay.port)
                block, sent = bytes(1 << 20), 0
                while sent < flood:
                    writer.write(block)
                    try:
                        await asyncio.wait_for(writer.drain(), timeout=1.0)
                    except TimeoutError:
                        break
                    sent += len(block)
                writer.transport.abort()
            gc.collect()  # a relay task whose failure nobody read reports it when collected
            return sent, errors
        finally:
            release.set()
            origin.close()

    sent, errors = asyncio.run(run())
    assert sent < bound, (sent, bound)
    assert errors == []


def test_connections_beyond_the_bound_are_closed_on_arrival() -> None:
    async def run() -> tuple[int, int]:
        runner, port = await start_server(make_app(Path(".")))
        try:
            async with ThrottledRelay(port, LinkShape(1e9, 0.0)) as relay:
                held = [
                    await asyncio.open_connection("127.0.0.1", relay.port)
                    for _ in range(MAX_CONNECTIONS + 8)
                ]

                async def closed(reader: asyncio.StreamReader) -> bool:
                    try:
                        return await asyncio.wait_for(reader.read(), timeout=1.0) == b""
                    except TimeoutError:
                        return False  # relayed: open, waiting for a request

                ends = await asyncio.gather(*[closed(reader) for reader, _ in held])
                for _, writer in held:
                    writer.close()
                return sum(ends), relay.connections
        finally:
            await runner.cleanup()

    closed, relayed = asyncio.run(run())
    assert closed == 8
    assert relayed == MAX_CONNECTIONS


def test_adaptive_playback_over_half_the_bitrate_starts_sooner_and_never_stalls(
    scene_files: dict[str, Path],
) -> None:
    """Through the real server and the shaped link: adaptive playback draws a first picture
    well before full quality alone can, then plays without a stall on the layers the link
    keeps up with; full quality alone at the same link waits for everything."""
    path = scene_files["layered"]
    size = path.stat().st_size
    rate = 0.5 * size * 8 / HANABI_S  # half the full-quality bitrate

    async def run(adaptive: bool) -> tuple[float, float, int, dict[int, int], float]:
        report = await play_through_link(
            path, LinkShape(rate, 0.02), start=1.0, duration=2.0, fps=10.0, adaptive=adaptive
        )
        s = report.stats
        return s.first_picture_s, s.startup_s, s.stalls, s.layers_shown, report.worst_psnr

    first, startup, stalls, shown, worst = asyncio.run(run(True))
    full_first, _, _, full_shown, full_worst = asyncio.run(run(False))
    assert first < 0.5 * full_first, (first, full_first)
    assert stalls == 0
    assert startup >= first
    assert sum(shown.values()) == 21 and min(shown) >= 1
    assert worst > 15.0  # a picture, not an empty frame (inf: all layers shown)
    assert full_shown == {3: 21} and math.isinf(full_worst)


def test_a_playback_queues_the_base_then_its_layers_then_one_more(
    scene_files: dict[str, Path],
) -> None:
    """What adaptive playback queues for [t, t + ahead] keeping two layers: the base alone
    until it is in; the second layer once it is; and the third once both are (the spare link
    fetches the next layer before the plan counts on it)."""
    t, ahead = 1.0, 2.0

    async def run() -> list[set[int]]:
        async with await StreamClient.open(scene_files["layered"]) as client:

            def layers(n: int) -> set[int]:
                return {c.id for c in client.index.chunks_for_interval(t, t + ahead, n)}

            queued = []
            for have in (0, 1, 2):
                if have:
                    await client.prefetch(t, ahead, layers=have)
                client._prefetch_layers(t, ahead, 2)
                queued.append(set(client._pending))
                await asyncio.gather(*[job.futures[cid] for cid, job in client._pending.items()])
                assert all(cid in client.cache for cid in layers(have + 1))
            return [*queued, layers(1), layers(2), layers(3)]

    got = asyncio.run(run())
    queued, (base, two, three) = got[:3], got[3:]
    assert queued == [base, two - base, three - two]
    assert base and two - base and three - two


def test_importance_orders_by_opacity_and_size() -> None:
    scene = generate_scene(SceneSpec(background=50, objects=1, per_object=10, sh_bands=0))
    g = scene.gaussians
    weights = importance(g)
    assert weights.shape == (len(g),) and np.all(weights >= 0)
    bigger = g.scales.astype(np.float64) + 1.0  # every axis e times larger: sqrt(area) x e
    grown = importance(replace(g, scales=bigger.astype(np.float32)))
    assert np.allclose(grown, weights * math.e, rtol=1e-5)


def test_a_bad_input_over_the_link_is_one_line_naming_it(
    scene_files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    junk = tmp_path / "junk.tsogs"
    junk.write_bytes(np.random.default_rng(1).bytes(5000))
    cut = tmp_path / "cut.tsogs"
    cut.write_bytes(scene_files["layered"].read_bytes()[:30000])
    cases = {
        str(junk): f"tsog: error: {junk}: not a .tsogs container",
        str(cut): f"tsog: error: {cut}: header says the file has",
        str(tmp_path / "none.tsogs"): f"tsog: error: {tmp_path / 'none.tsogs'}: no such file",
        "https://127.0.0.1:9/x.tsogs": "tsog: error: a shaped link relays plain http",
    }
    for target, start in cases.items():
        assert main(["play", target, "--bandwidth", "50Mbit", "-q"]) == 1
        err = capsys.readouterr().err
        assert err.startswith(start) and err.count("\n") == 1, err
    assert main(["play", str(junk), "--latency", "5ms", "-q"]) == 1
    assert "give --bandwidth too" in capsys.readouterr().err


def test_play_over_the_link_reports_what_a_viewer_saw(
    scene_files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    target = str(scene_files["layered"])
    args = ["play", target, "--start", "1", "--duration", "1", "--bandwidth", "2Mbit"]
    assert main([*args, "--latency", "20ms", "-q"]) == 0
    out = capsys.readouterr().out
    for line in ("link:            2 Mbit/s, 20 ms", "first picture:", "layers shown:", "quality:"):
        assert line in out, out
    assert "0 frames late" in out


def test_a_size_spread_skews_importance_like_a_capture_and_changes_only_sizes() -> None:
    spec = SceneSpec(background=4000, objects=4, per_object=500, sh_bands=0, seed=5)
    plain = generate_scene(spec)
    spread = generate_scene(replace(spec, size_spread=1.0))
    np.testing.assert_array_equal(plain.gaussians.means, spread.gaussians.means)
    np.testing.assert_array_equal(plain.gaussians.opacities, spread.gaussians.opacities)
    assert not np.array_equal(plain.gaussians.scales, spread.gaussians.scales)

    def top_fifth(scene: Scene) -> float:
        weights = np.sort(importance(scene.gaussians))[::-1]
        return float(weights[: len(weights) // 5].sum() / weights.sum())

    assert top_fifth(plain) < 0.45 and top_fifth(spread) > 0.55  # captures: 0.65-0.86
    with pytest.raises(InputError, match="size_spread"):
        SceneSpec(size_spread=-1.0)


@pytest.mark.parametrize("bare", [False, True])
def test_a_share_drawn_from_one_projection_is_the_picture_of_its_rows_alone(bare: bool) -> None:
    """Each sampled time is projected once and a share's picture selects rows of it: pixel
    for pixel the render of the chosen rows' scene at t (its SH bands dropped for a base)."""
    scene = generate_scene(SceneSpec(background=600, objects=3, per_object=80, sh_bands=1))
    groups = [np.arange(0, 300), np.arange(300, len(scene))]
    picked = top_share(importance(scene.gaussians), groups, 0.4)
    chosen = np.zeros(len(scene), bool)
    chosen[picked] = True
    view = default_view(scene.gaussians, [])
    assert view is not None
    camera = from_capture(view, quality_layers.MEASURE_WIDTH)
    for t in (0.1, 0.5, 0.9):
        part = scene.subset(picked)
        expected = to_uint8(render((without_sh(part) if bare else part).at(t), camera))
        sample = quality_layers._sampled(scene, t, camera, bare=True)
        got = quality_layers._share_picture(sample, chosen, bare)
        assert 0 < int(chosen[sample.rows].sum()) < len(picked)
        assert expected.any() and np.array_equal(got, expected)
        assert np.array_equal(sample.full, to_uint8(render(scene.at(t), camera)))


def test_the_layer_measure_tells_each_step_and_the_shares_it_chose() -> None:
    """Measuring layers is the default path's longest serial phase: each sampled time drawn
    and each share measured is told, and the shares the plan keeps are among those told."""
    scene = generate_scene(SceneSpec(background=20000, objects=4, per_object=2000, sh_bands=1))
    view = default_view(scene.gaussians, [])
    told: list[str] = []
    groups = [np.arange(len(scene))]
    plan = quality_layers.plan_layers(scene, groups, view, 3, told=told.append)
    drawn = [line for line in told if line.endswith("times drawn")]
    assert drawn == [f"measuring quality layers: {k}/3 times drawn" for k in (1, 2, 3)]
    measured = told[3:]
    assert measured and all(line.endswith(" dB") for line in measured)
    base, middle = plan.shares[0], plan.shares[1]
    assert (
        f"measuring quality layers: {base:.0%}, DC colour only: {plan.psnr_db[0]:.1f} dB"
        in measured
    )
    assert f"measuring quality layers: {middle:.0%}: {plan.psnr_db[1]:.1f} dB" in measured


def _lie(manifest: dict[str, Any], shape: str) -> None:
    """Make the layer table of ``manifest`` (index JSON) lie in the way ``shape`` says."""
    layers = manifest["layers"]
    if shape == "5000 layers":
        layers += [
            {"index": k, "gaussians": 0, "bytes": 0, "psnr_db": 30.0} for k in range(3, 5000)
        ]
    elif shape == "one layer too many":
        layers.append({"index": 3, "gaussians": 0, "bytes": 0, "psnr_db": None})
        layers[2]["psnr_db"] = 50.0
    elif shape == "10^18 bytes":
        layers[1]["bytes"] = 10**18
    elif shape == "one Gaussian more":
        layers[0]["gaussians"] += 1
    elif shape in ("+1e300 dB", "-1e300 dB", "-1 dB", "1000 dB"):
        layers[0]["psnr_db"] = float(shape.split(maxsplit=1)[0])
    elif shape == "no PSNR below the top":
        layers[1]["psnr_db"] = None
    elif shape == "a PSNR on the top layer":
        layers[2]["psnr_db"] = 45.0
    elif shape == "an empty middle layer":
        for chunk in manifest["chunks"]:
            chunk["layer"] = 2 if chunk.get("layer") == 1 else chunk.get("layer", 0)


LYING_TABLES = {
    "one layer too many": "layers: the table has 4 entries, the chunks are in 3",
    "10^18 bytes": "layers[1]: says 1000000000000000000 bytes, its",
    "one Gaussian more": "layers[0]: says {gaussians} Gaussians, its",
    "no PSNR below the top": "layers[1]: no PSNR, expected the measured quality of layers 0..1",
    "a PSNR on the top layer": "layers[2]: the last layer (the full scene) has a PSNR of 45 dB",
    "an empty middle layer": "layers[1]: no chunk is in this layer",
}
"""Ways a layer table can lie, and the line ``tsog verify`` prints for each."""


@pytest.mark.parametrize("shape", list(LYING_TABLES))
def test_verify_checks_the_layer_table_against_the_chunks(
    shape: str,
    scene_files: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A layer table that lies (counts, bytes, PSNR, entries without chunks) is an index
    problem (exit 6) named by its entry; the honest one is OK."""
    folder = tmp_path / "unpacked"
    assert main(["unpack", str(scene_files["layered"]), "-o", str(folder), "-q"]) == 0
    assert main(["verify", str(folder), "-q"]) == 0
    assert capsys.readouterr().out.strip().endswith("OK")
    manifest = json.loads((folder / "manifest.json").read_bytes())
    assert len(manifest["layers"]) == 3
    expected = LYING_TABLES[shape].format(gaussians=manifest["layers"][0]["gaussians"] + 1)
    _lie(manifest, shape)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["verify", str(folder), "-q"]) == 6
    out = capsys.readouterr().out
    assert f"container: index: {expected}" in out, out
    assert len(out.splitlines()) <= 4  # one line per lie, then the total


ABSURD_TABLES = {
    "5000 layers": "field 'layers': expected at most 16 items, found 5000",
    "+1e300 dB": "field 'layers[0].psnr_db': expected",
    "-1e300 dB": "field 'layers[0].psnr_db': expected",
    "-1 dB": "field 'layers[0].psnr_db': expected",
    "1000 dB": "field 'layers[0].psnr_db': expected",
}
"""Layer tables no writer makes: refused when the index is read (the schema's bounds), by
every command, with the field named."""


@pytest.mark.parametrize("shape", list(ABSURD_TABLES))
@pytest.mark.parametrize("command", ["verify", "info"])
def test_an_absurd_layer_table_is_refused_when_the_index_is_read(
    shape: str,
    command: str,
    scene_files: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder = tmp_path / "unpacked"
    assert main(["unpack", str(scene_files["layered"]), "-o", str(folder), "-q"]) == 0
    manifest = json.loads((folder / "manifest.json").read_bytes())
    _lie(manifest, shape)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main([command, str(folder), "-q"]) == 1
    err = capsys.readouterr().err
    assert ABSURD_TABLES[shape] in err, err
    assert len(err.splitlines()) == 1
