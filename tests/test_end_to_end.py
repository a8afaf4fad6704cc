"""End to end: segment a generated scene, serve it with our server, play it with our client."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np

from tsog_stream import Gaussians, TimelineType
from tsog_stream.client import open_stream
from tsog_stream.client.stream import StreamClient
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server.app import make_app, start_server
from tsog_stream.synthetic import SceneSpec, generate_scene


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a, b))


def test_play_over_http_equals_local_frames(tmp_path: Path) -> None:
    spec = SceneSpec(
        timeline_type=TimelineType.CENTER_SCALE,
        background=1500,
        objects=10,
        per_object=300,
        duration=12.0,
        sh_bands=0,
        dynamic=("means",),
        seed=4,
    )
    scene = generate_scene(spec)
    path = tmp_path / "clip.tsogs"
    segment_scene(scene, path, SegmentOptions(window_s=1.0, policy="hybrid"))
    start = float(np.random.default_rng(8).uniform(0.0, 1.5))

    async def run() -> tuple[list[tuple[float, Gaussians]], int, int, int]:
        runner, port = await start_server(make_app(tmp_path))
        try:
            url = f"http://127.0.0.1:{port}/files/clip.tsogs"
            async with await StreamClient.open(url) as client:
                playback = client.play(start, speed=4.0, fps=10.0, duration=2.5)  # 10 s of scene
                frames = [(f.t, f.gaussians) async for f in playback]
                needed = {c.id for t, _ in frames for c in client.index.chunks_for(t)}
                needed_bytes = sum(client.index.manifest.chunks[i].length for i in needed)
                return frames, playback.stats.bytes, needed_bytes, playback.stats.requests
        finally:
            await runner.cleanup()

    frames, fetched, needed_bytes, requests = asyncio.run(run())
    assert len(frames) > 20 and requests > 0
    with open_stream(path) as local:
        for t, got in frames:
            want = local.frame_at(t)
            assert _same(got.means, want.means) and _same(got.opacities, want.opacities), t
    assert fetched <= 1.25 * needed_bytes
