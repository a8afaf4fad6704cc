"""The built-in demo: generate a 4D scene, encode it to TSOG, decode it, report sizes and errors."""

from __future__ import annotations

import asyncio
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .client import PlayStats, StreamClient, open_stream
from .codec.bundle import bundle_bytes
from .codec.chunk import decode_chunk, encode_chunk, texel_order
from .compare import attribute_errors
from .errors import InputError
from .io.files import atomic_write_bytes
from .io.ply import ply_bytes
from .model import Gaussians, Scene, evaluate_all
from .segment import SegmentOptions, segment_scene
from .server.app import make_app, start_server
from .synthetic import SceneSpec, generate_scene, rig_cameras
from .temporal import time_range

Progress = Callable[[str], None]


def extended_ply_size(scene: Scene) -> int:
    """Bytes of the scene as one extended PLY: every attribute, timeline and coefficient float32."""
    extra: dict[str, Any] = {}
    if scene.timeline is not None:
        extra["t_0"] = scene.timeline.t0
        extra["t_1"] = scene.timeline.t1
    for attr, coeffs in scene.temporal.items():
        flat = coeffs.reshape(len(scene), -1)
        for j in range(flat.shape[1]):
            extra[f"{attr}_c{j}"] = flat[:, j]
    return len(ply_bytes(scene.gaussians, extra))


def errors_over_time(source: Scene, decoded: Scene, times: list[float]) -> list[dict[str, Any]]:
    """Per-attribute errors of ``decoded`` against ``source`` (texel-aligned) at each time."""
    rows = []
    for t in times:
        ref, ref_mask = evaluate_all(source, t)
        got, got_mask = evaluate_all(decoded, t)
        errors = attribute_errors(ref.subset(ref_mask), got.subset(ref_mask)).as_dict()
        errors["t"] = t
        errors["visibility_flips"] = int(np.count_nonzero(ref_mask != got_mask))
        rows.append(errors)
    return rows


async def _play_over_http(
    root: Path, name: str, start: float, seconds: float
) -> tuple[str, list[tuple[float, Gaussians]], PlayStats]:
    """Serve ``root`` on loopback and play ``name`` from ``start`` at 2x; then shut down."""
    runner, port = await start_server(make_app(root))
    try:
        url = f"http://127.0.0.1:{port}/files/{name}"
        async with await StreamClient.open(url) as client:
            playback = client.play(start, speed=2.0, fps=10.0, duration=seconds)
            frames = [(f.t, f.gaussians) async for f in playback]
            return url, frames, playback.stats
    finally:
        await runner.cleanup()


def _stream_report(
    scene: Scene, out_dir: Path | None, start: float, note: Progress
) -> dict[str, Any]:
    """Segment the scene, serve it on loopback, play it over HTTP from ``start``, shut down."""
    note("segmenting into a stream container")
    with tempfile.TemporaryDirectory(prefix="tsog-demo-") as tmp:
        root = out_dir or Path(tmp)
        path = root / "demo.tsogs"
        report = segment_scene(scene, path, SegmentOptions(window_s=0.5), cameras=rig_cameras())
        note("serving on 127.0.0.1 and playing over HTTP")
        url, frames, stats = asyncio.run(_play_over_http(root, path.name, start, seconds=1.0))
        with open_stream(path) as local:
            mismatches = sum(
                1 for t, got in frames if not np.array_equal(got.means, local.frame_at(t).means)
            )
        return {
            "output": str(path) if out_dir is not None else None,
            "bytes": report.bytes,
            "windows": report.windows,
            "chunks": report.chunks,
            "url": url,
            "start_t": round(start, 3),
            "frames": len(frames),
            "mismatches": mismatches,
            "startup_ms": round(1000 * stats.startup_s, 1),
            "stalls": stats.stalls,
            "requests": stats.requests,
            "bytes_fetched": stats.bytes,
            "cache_hit_rate": round(stats.hit_rate, 3),
        }


def run_demo(
    out_dir: Path | None = None, *, seed: int = 0, progress: Progress | None = None
) -> dict[str, Any]:
    """Generate, encode, decode and measure; writes ``demo.sog`` into ``out_dir`` if given."""
    note = progress or (lambda _msg: None)
    note("generating a synthetic 4D scene")
    scene = generate_scene(SceneSpec(seed=seed, dynamic=("means", "quats")))
    files = encode_chunk(scene, seed=seed, progress=note)
    bundle = bundle_bytes(files)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out_dir / "demo.sog", bundle)
    note("decoding")
    decoded = decode_chunk(files, where="demo.sog")
    aligned = scene.subset(texel_order(scene))
    if scene.timeline is None:
        raise InputError("the demo scene must be dynamic")
    first, last = time_range(scene.timeline)
    times = [round(float(t), 3) for t in np.linspace(first, last, 5)]
    ply_size = extended_ply_size(scene)
    start = float(np.random.default_rng(seed).uniform(first, max(first, last - 2.0)))
    stream = _stream_report(scene, out_dir, start, note)
    return {
        "stream": stream,
        "gaussians": len(scene),
        "timeline_type": int(scene.timeline.type),
        "tsog_bytes": len(bundle),
        "extended_ply_bytes": ply_size,
        "saving_percent": round(100.0 * (1 - len(bundle) / ply_size), 2),
        "errors": errors_over_time(aligned, decoded, times),
        "output": str(out_dir / "demo.sog") if out_dir is not None else None,
    }
