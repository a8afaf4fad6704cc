"""CPU rasterizer speed: numba against the pure-numpy fallback, in the same run.

    .venv/bin/python benchmarks/bench_render.py [--repeats 3]

Cases from the issue: the 45k-Gaussian donut (a real trained scene) at 320x240, and 1M
Gaussians (22 shifted copies of the donut, random SH degree 3) at 1280x720; each rendered from
an orbit camera after one warm-up render (numba's first call compiles, then caches). Reports
the best of ``--repeats`` wall times per backend and their ratio. Writes the "render" section
of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import time

import numpy as np

from common import sample, write_section
from tsog_stream.io.ply import read_ply
from tsog_stream.model import Gaussians
from tsog_stream.render import numba_available, render
from tsog_stream.render.camera import scene_orbit


def million(donut: Gaussians) -> Gaussians:
    """About 1M Gaussians: donut copies side by side, with random SH degree 3."""
    copies = -(-1_000_000 // len(donut))
    extent = float(np.ptp(donut.means[:, 0])) * 1.1
    parts = []
    rng = np.random.default_rng(3)
    for i in range(copies):
        offset = np.array([(i % 6 - 2.5) * extent, (i // 6 - 2) * extent, 0.0], np.float32)
        shn = rng.normal(0, 0.05, (len(donut), 15, 3)).astype(np.float32)
        parts.append(
            Gaussians.from_arrays(
                donut.means + offset, donut.scales, donut.quats, donut.opacities, donut.sh0, shN=shn
            )
        )
    return Gaussians.concat(parts)


def best_time(g: Gaussians, width: int, height: int, backend: str, repeats: int) -> float:
    """Best wall time of ``repeats`` renders after a warm-up."""
    camera = scene_orbit(g, 8, width, height)[1]
    render(g, camera, backend=backend)  # type: ignore[arg-type]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        render(g, camera, backend=backend)  # type: ignore[arg-type]
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    donut = read_ply(sample("3dgs/v3dg_donut_fused.ply")).gaussians
    cases = [("donut, 45 624 Gaussians, SH0", donut, 320, 240)]
    big = million(donut)
    cases.append((f"{len(big)} Gaussians, SH3", big, 1280, 720))
    backends = ["numba", "numpy"] if numba_available() else ["numpy"]
    lines = [
        f"## CPU rasterizer speed ({dt.date.today().isoformat()}, `benchmarks/bench_render.py`)\n",
        "Best of 3 renders after a warm-up, one orbit view, this 2-core machine (shared);",
        "`tsog_stream.render` with numba (`tsog-stream[render]`) and with its numpy fallback,",
        "which gives the same image.\n",
        "| scene | image | numba s | numpy s | numpy / numba |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for name, g, w, h in cases:
        got = {b: best_time(g, w, h, b, args.repeats) for b in backends}
        print(name, got, file=sys.stderr, flush=True)
        fast = got.get("numba")
        ratio = f"{got['numpy'] / fast:.1f}" if fast else "-"
        fast_cell = f"{fast:.3f}" if fast else "(numba not installed)"
        lines.append(f"| {name} | {w}x{h} | {fast_cell} | {got['numpy']:.3f} | {ratio} |")
    write_section("render", "\n".join(lines) + "\n\n", "bench_render.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())
