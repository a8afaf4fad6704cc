"""Write tests/data/conformance/: TSOG chunks whose meta.json follows the paper's examples
literally, made by this minimal writer (numpy and Pillow only, none of tsog_stream's code), so
that the library's reader is checked against an independent writer.

Each case is an unbundled chunk (meta.json + lossless WebP images, 4 Gaussians in 4x4 images)
plus ``expected.json``: for a few times, the index, position, rotation, colour (f_dc) and alpha
of every Gaussian visible then, computed here from the stored bytes by the rules of the paper,
docs/spec.md and SOG v2. Usage: ``python scripts/make_conformance_corpus.py [--check]``; with
``--check`` nothing is written and the exit status is 1 when a committed case differs (meta,
expectations or decoded pixels) from a fresh build.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "conformance"
N, SIDE = 4, 4
SCALES = np.linspace(-5.0, 0.0, 256)
SH0 = np.linspace(-2.0, 2.0, 256)
SH_C0 = 0.28209479177387814
Meta = dict[str, Any]


def image(rgba: np.ndarray) -> bytes:
    """A 4x4 lossless WebP of N texels (RGBA rows), padding texels all zero."""
    pixels = np.zeros((SIDE * SIDE, 4), np.uint8)
    pixels[: len(rgba)] = rgba
    out = io.BytesIO()
    Image.fromarray(pixels.reshape(SIDE, SIDE, 4), "RGBA").save(
        out, "WEBP", lossless=True, exact=True
    )
    return out.getvalue()


def split16(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) RGBA texels of up to 4 channels of 16-bit codes; missing channels 0, A 255."""
    low = np.zeros((N, 4), np.uint8)
    high = np.zeros((N, 4), np.uint8)
    low[:, 3] = high[:, 3] = 255
    low[:, : codes.shape[1]] = codes & 0xFF
    high[:, : codes.shape[1]] = codes >> 8
    return low, high


def codes16(values: np.ndarray, mins: np.ndarray, maxs: np.ndarray) -> np.ndarray:
    """Round-to-nearest 16-bit codes of values over [mins, maxs] (0 where the range is empty)."""
    span = np.where(maxs > mins, maxs - mins, 1.0)
    codes: np.ndarray = np.rint(np.clip((values - mins) / span, 0, 1) * 65535).astype(np.uint16)
    return codes


def decode16(codes: np.ndarray, mins: np.ndarray, maxs: np.ndarray) -> np.ndarray:
    """The paper's 16-bit dequantisation: min + (max - min) * code / 65535."""
    values: np.ndarray = mins + (maxs - mins) * codes.astype(np.float64) / 65535
    return values


class Chunk:
    """A chunk being written: files by name and the meta.json object."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.meta: Meta = {"version": 2, "count": N}

    def pair(self, stem: str, values: np.ndarray, mins: np.ndarray, maxs: np.ndarray) -> list[str]:
        """Write ``values`` as a 16-bit l/u image pair; returns the two file names."""
        low, high = split16(codes16(values, mins, maxs))
        names = [f"{stem}_l.webp", f"{stem}_u.webp"]
        self.files[names[0]], self.files[names[1]] = image(low), image(high)
        return names


def sog_base(chunk: Chunk, alpha_bytes: list[int]) -> dict[str, np.ndarray]:
    """The SOG v2 images of the base values; returns what a SOG reader decodes from them."""
    # means: Gaussian i at unit distance on one axis (or the origin), log-transformed
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    logs = np.sign(pos) * np.log1p(np.abs(pos))
    lo, hi = np.zeros(3), np.full(3, math.log(2.0))
    files = chunk.pair("means", logs, lo, hi)
    chunk.meta["means"] = {"mins": lo.tolist(), "maxs": hi.tolist(), "files": files}
    decoded = decode16(codes16(logs, lo, hi), lo, hi)
    means = np.sign(decoded) * np.expm1(np.abs(decoded))
    # quats: identity, smallest three of (w, x, y, z) with w dropped (tag 252 + 0)
    quat_bytes = np.tile([127, 127, 127, 252], (N, 1)).astype(np.uint8)
    chunk.files["quats.webp"] = image(quat_bytes)
    chunk.meta["quats"] = {"files": ["quats.webp"]}
    abc = (quat_bytes[:, :3] / 255 * 2 - 1) / math.sqrt(2)
    w = np.sqrt(np.maximum(0, 1 - (abc**2).sum(axis=1)))
    quats = np.concatenate([w[:, None], abc], axis=1)
    # scales and colour: codebook labels; sh0's alpha is the opacity byte
    labels = np.array([[100, 110, 120], [130, 140, 150], [160, 170, 180], [190, 200, 210]])
    chunk.files["scales.webp"] = image(np.concatenate([labels, np.full((N, 1), 255)], axis=1))
    chunk.meta["scales"] = {"codebook": SCALES.tolist(), "files": ["scales.webp"]}
    colours = labels[::-1]
    alpha = np.array(alpha_bytes)[:, None]
    chunk.files["sh0.webp"] = image(np.concatenate([colours, alpha], axis=1))
    chunk.meta["sh0"] = {"codebook": SH0.tolist(), "files": ["sh0.webp"]}
    return {"means": means, "quats": quats, "sh0": SH0[colours], "alpha": alpha[:, 0] / 255}


def timeline(
    chunk: Chunk, kind: int, r: list[float], g: list[float], **extra: float
) -> tuple[np.ndarray, np.ndarray]:
    """The ``timeline`` object and its images (R = frame/start/centre, G = duration/scale);
    returns R and G as a reader decodes them."""
    values = np.stack([r, g], axis=1).astype(np.float64)
    mins, maxs = values.min(axis=0), values.max(axis=0)
    files = chunk.pair("timeline", values, mins, maxs)
    decoded = decode16(codes16(values, mins, maxs), mins, maxs)
    chunk.meta["timeline"] = {
        "type": kind,
        **extra,
        "mins": mins.tolist(),
        "maxs": maxs.tolist(),
        "files": files,
    }
    return decoded[:, 0], decoded[:, 1]


def temporal(chunk: Chunk, attr: str, orders: list[np.ndarray]) -> list[np.ndarray]:
    """``temporal.<attr>`` with one image pair per order (values at the range ends, exactly
    representable); returns the decoded coefficients of each order."""
    entry: Meta = {"mins": [], "maxs": [], "files": []}
    decoded = []
    for k, values in enumerate(orders, start=1):
        mins, maxs = values.min(axis=0), values.max(axis=0)
        entry["files"] += chunk.pair(f"temporal_{attr}_{k}", values, mins, maxs)
        entry["mins"].append(mins.tolist())
        entry["maxs"].append(maxs.tolist())
        decoded.append(decode16(codes16(values, mins, maxs), mins, maxs))
    chunk.meta.setdefault("temporal", {})[attr] = entry
    return decoded


def poly(base: np.ndarray, orders: list[np.ndarray], dt: np.ndarray) -> np.ndarray:
    """base + sum_k c_k dt^k, per Gaussian."""
    out = base.astype(np.float64).copy()
    for k, c in enumerate(orders, start=1):
        out = out + c * (dt[:, None] ** k if out.ndim == 2 else dt**k)
    return out


def logit(alpha: np.ndarray) -> np.ndarray:
    """The opacity logit of an alpha (clamped as SOG readers do)."""
    a = np.clip(alpha, 1e-6, 1 - 1e-6)
    logits: np.ndarray = np.log(a / (1 - a))
    return logits


def frames(
    base: dict[str, np.ndarray],
    times: list[float],
    state: Callable[[float], tuple[np.ndarray, dict[str, np.ndarray]]],
) -> list[Meta]:
    """Expected Gaussians at each time: ``state(t)`` gives (visible mask, attributes at t)."""
    out = []
    for t in times:
        visible, attrs = state(t)
        quats = attrs.get("quats", base["quats"])
        quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
        idx = np.flatnonzero(visible)
        out.append(
            {
                "t": t,
                "visible": idx.tolist(),
                "means": attrs.get("means", base["means"])[idx].tolist(),
                "quats": quats[idx].tolist(),
                "sh0": attrs.get("sh0", base["sh0"])[idx].tolist(),
                "alpha": attrs.get("alpha", base["alpha"])[idx].tolist(),
            }
        )
    return out


def type0_frames() -> tuple[Chunk, list[Meta]]:
    """Type 0 (frame id) with fps: Gaussian i lives in frame i only; G unused (0, range 0)."""
    chunk = Chunk()
    base = sog_base(chunk, [255, 200, 150, 100])
    ids, _ = timeline(chunk, 0, [0, 1, 2, 3], [0, 0, 0, 0], fps=10.0)
    ids = np.rint(ids)  # frame ids are integers: a reader rounds the decoded value
    expected = frames(base, [0.0, 0.1, 0.25, 0.3], lambda t: (ids == math.floor(t * 10 + 1e-9), {}))
    return chunk, expected


def type1_start_duration(fps: float | None) -> tuple[Chunk, list[Meta]]:
    """Type 1 (start, duration), in frames with fps or in seconds without; linear means."""
    chunk = Chunk()
    base = sog_base(chunk, [255, 255, 255, 255])
    unit = 1 / fps if fps else 1.0
    extra = {"fps": fps} if fps else {}
    start, duration = timeline(chunk, 1, [0, 0, 5, 5.0], [5, 10, 5, 1.0], **extra)
    [c1] = temporal(chunk, "means", [np.array([[1, -1, 0.5], [-1, 1, -0.5]] * 2, np.float64)])

    def state(t: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        u = t / unit + 1e-9
        dt = t - start * unit
        return (start <= u) & (u < start + duration), {"means": poly(base["means"], [c1], dt)}

    times = [x * unit for x in (0.0, 2.5, 5.0, 5.5, 9.0)]
    return chunk, frames(base, times, state)


def type2_paper_example() -> tuple[Chunk, list[Meta]]:
    """Type 2 (centre, scale), the paper's temporal example to the letter: means of order 1,
    quats of orders 1 and 2 in three channels (qx, qy, qz), and opacity's coefficient in the
    A channel of sh0 (the colour static: R, G, B zero, range [0, 0])."""
    chunk = Chunk()
    base = sog_base(chunk, [230, 200, 180, 128])
    centre, scale = timeline(chunk, 2, [0.5, 0.5, 1, 1.5], [0.25, 0.5, 0.25, 1], scene_length=2.0)
    [m1] = temporal(chunk, "means", [np.array([[0.2, 0, 0], [0, -0.2, 0]] * 2)])
    q1, q2 = temporal(
        chunk,
        "quats",
        [np.array([[0.4, 0, 0], [0, 0.4, 0]] * 2), np.array([[0, 0, 0.3], [0, 0, -0.3]] * 2)],
    )
    opacity = np.array([[0, 0, 0, 1.0], [0, 0, 0, -1.0]] * 2)
    [s1] = temporal(chunk, "sh0", [opacity])

    def state(t: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        dt = t - centre
        g = np.exp(-0.5 * ((t - centre) / scale) ** 2)
        w0 = np.zeros((N, 1))
        quats = poly(base["quats"], [np.hstack([w0, q1]), np.hstack([w0, q2])], dt)
        alpha = g / (1 + np.exp(-(logit(base["alpha"]) + s1[:, 3] * dt)))
        attrs = {"means": poly(base["means"], [m1], dt), "quats": quats, "alpha": alpha}
        return g >= 1 / 255, attrs

    return chunk, frames(base, [0.0, 0.5, 0.9, 1.6], state)


def type2_separate_opacity() -> tuple[Chunk, list[Meta]]:
    """Spec 0.2's form, still read: opacity as its own one-channel attribute, and a dynamic
    colour in a three-channel sh0."""
    chunk = Chunk()
    base = sog_base(chunk, [200, 200, 200, 200])
    centre, scale = timeline(chunk, 2, [0.5, 0.5, 0.5, 0.5], [1.0, 1.0, 1.0, 1.0])
    [c1] = temporal(chunk, "sh0", [np.array([[0.5, 0, -0.5], [-0.5, 0, 0.5]] * 2)])
    [o1] = temporal(chunk, "opacity", [np.array([[2.0], [-2.0]] * 2)])

    def state(t: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        dt = t - centre
        g = np.exp(-0.5 * ((t - centre) / scale) ** 2)
        alpha = g / (1 + np.exp(-(logit(base["alpha"]) + o1[:, 0] * dt)))
        return g >= 1 / 255, {"sh0": poly(base["sh0"], [c1], dt), "alpha": alpha}

    return chunk, frames(base, [0.0, 0.5, 1.25], state)


CASES: dict[str, Callable[[], tuple[Chunk, list[Meta]]]] = {
    "type0_frames": type0_frames,
    "type1_frames": lambda: type1_start_duration(10.0),
    "type1_seconds": lambda: type1_start_duration(None),
    "type2_paper_example": type2_paper_example,
    "type2_separate_opacity": type2_separate_opacity,
}


def write(folder: Path) -> None:
    """Every case into ``folder``."""
    for name, make in CASES.items():
        chunk, expected = make()
        case = folder / name
        case.mkdir(parents=True, exist_ok=True)
        for file, data in chunk.files.items():
            (case / file).write_bytes(data)
        (case / "meta.json").write_text(json.dumps(chunk.meta, indent=1) + "\n")
        (case / "expected.json").write_text(json.dumps(expected, indent=1) + "\n")


def same_json(a: object, b: object) -> bool:
    """Equal documents, floats within 1e-12 relative: numpy's exp may differ in the last bit
    between builds and CPUs (SIMD paths), and readers are checked against them to 2e-4."""
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-300)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_json(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_json(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def same_case(a: Path, b: Path) -> bool:
    """Same files, same meta and expectations, same decoded pixels."""
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return False
    for name in names:
        if name.endswith(".json"):
            if not same_json(
                json.loads((a / name).read_text()), json.loads((b / name).read_text())
            ):
                return False
        else:
            pa = np.asarray(Image.open(a / name).convert("RGBA"))
            pb = np.asarray(Image.open(b / name).convert("RGBA"))
            if not np.array_equal(pa, pb):
                return False
    return True


def main(argv: list[str] | None = None) -> int:
    """Write the corpus, or with --check compare it with a fresh build."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args(argv)
    if not args.check:
        write(OUT)
        print(f"wrote {len(CASES)} cases to {OUT}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        write(Path(tmp))
        stale = [
            n for n in CASES if not (OUT / n).is_dir() or not same_case(OUT / n, Path(tmp) / n)
        ]
    for name in stale:
        print(f"stale: tests/data/conformance/{name} (run scripts/make_conformance_corpus.py)")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
