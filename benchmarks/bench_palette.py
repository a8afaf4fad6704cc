"""SH bands below quality 100: bytes and rendered PSNR with the palette merged within its slack.

    .venv/bin/python benchmarks/bench_palette.py [--views 8]

For the real SH3 captures in the samples (gsplat's ``alti`` splatfacto output, 22589
Gaussians; the fruit-drops crop of supersplat's PR 291, 4721) and a generated 100k SH3 scene:
one chunk at quality 100 and, at 90, 75 and 50, two ways in the same run: the palette merged
within the bands' colour slack (the encoder's way, docs/spec.md §5.1) and kept at its
quality-100 size K (``fit_palette``'s slack turned off, the encoder before 2026-11-28). Each
chunk is decoded and rendered with the CPU rasterizer against the source from the same orbit
cameras (640x480). Reported: palette entries, bytes per Gaussian, mean and worst PSNR, encode
seconds (one round). Writes benchmarks/results/palette.json and the "palette" section of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any
from unittest import mock

from bench_quality import score, static
from common import alti_gaussians, sample, write_section
from tsog_stream.codec import sog_encode
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import decode_chunk, encode_chunk, read_meta
from tsog_stream.codec.precision import QUALITY_MAX, without_faint
from tsog_stream.io.readers import load_scene
from tsog_stream.model import Scene
from tsog_stream.render import Camera, scene_orbit
from tsog_stream.sh_palette import fit_palette
from tsog_stream.synthetic import static_gaussians

QUALITIES = (90, 75, 50)
SIZE = (640, 480)
RESULTS = Path(__file__).parent / "results" / "palette.json"


def scenes() -> list[tuple[str, Scene]]:
    """The captures and the generated scene, by name."""
    fruit = sample("3dgs/supersplat_pr291_fruit_drops_minimal.ply", in_tree=False)
    return [
        ("alti (real, 22.6k, SH3)", Scene(alti_gaussians())),
        ("fruit drops (real, 4.7k, SH3)", load_scene(fruit).scene),
        ("generated (100k, SH3)", Scene(static_gaussians(100_000, sh_bands=3, seed=7))),
    ]


@contextlib.contextmanager
def palette_kept_whole() -> Iterator[None]:
    """The encoder with the palette's slack turned off (every entry of K kept)."""
    fit = fit_palette

    def whole(*args: Any, slack: float = 0.0, **kwargs: Any) -> Any:
        return fit(*args, **kwargs)

    with mock.patch.object(sog_encode, "fit_palette", whole):
        yield


def measure(scene: Scene, quality: int, cameras: Sequence[Camera]) -> dict[str, Any]:
    """One chunk of ``scene`` at ``quality``, as ``tsog encode`` writes it, against the source."""
    kept = without_faint(scene, quality)
    started = time.perf_counter()
    files = encode_chunk(kept, quality=quality)
    seconds = time.perf_counter() - started
    decoded = decode_chunk(files)
    size = len(bundle_bytes(files))
    palette = read_meta(files, where="bench").shN
    return {
        "entries": palette.count if palette is not None else 0,
        "bytes": size,
        "per_gaussian": size / len(scene),
        "encode_s": seconds,
        **score(static(scene), static(decoded), [0.0], cameras),
    }


def rows_of(name: str, scene: Scene, views: int) -> list[dict[str, Any]]:
    """Quality 100, then each quality both ways."""
    cameras = scene_orbit(scene.gaussians, views, *SIZE)  # the same views for every chunk
    rows = [{"scene": name, "quality": QUALITY_MAX, "way": "-", **measure(scene, 100, cameras)}]
    for quality in QUALITIES:
        with palette_kept_whole():
            whole = measure(scene, quality, cameras)
        rows.append({"scene": name, "quality": quality, "way": "K kept", **whole})
        merged = measure(scene, quality, cameras)
        rows.append({"scene": name, "quality": quality, "way": "merged", **merged})
        for row in rows[-2:]:
            print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The markdown table of every row."""
    lines = [
        "| scene | quality | palette | entries | B/Gaussian | PSNR mean | PSNR worst | encode s |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['quality']} | {r['way']} | {r['entries']} | "
            f"{r['per_gaussian']:.2f} | {r['psnr_mean']:.2f} | {r['psnr_worst']:.2f} | "
            f"{r['encode_s']:.2f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8)
    args = parser.parse_args()
    rows = [row for name, scene in scenes() for row in rows_of(name, scene, args.views)]
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(rows, indent=1))
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    body = [
        "## SH bands below quality 100: the palette within its slack",
        "",
        f"Run {stamp} (`benchmarks/bench_palette.py --views {args.views}`): one chunk per "
        "scene as `tsog encode` writes it (the Gaussians too faint for the quality left "
        "out), decoded and rendered (CPU rasterizer) against the source from "
        f"{args.views} orbit views at {SIZE[0]}x{SIZE[1]}; PSNR in dB. *merged*: the palette's "
        "entries merged while the bands' colour error stays within its quality-100 "
        "palette's + f · 0.1 (docs/spec.md §5.1); *K kept*: the same encoder with that slack "
        "turned off (the bands as at quality 100, the encoder before 2026-11-28). Encode "
        "seconds: one round, in this process.",
        "",
        *table(rows),
        "",
    ]
    write_section("palette", "\n".join(body), "bench_palette.py")


if __name__ == "__main__":
    main()
