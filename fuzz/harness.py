"""One atheris process for one target.

Usage: ``harness.py TARGET --stats FILE --crashes DIR -- [libFuzzer arguments]``.

Every input goes through :func:`fuzz.targets.outcome`. A crash (any exception that is not a
TsogError, or a warning: the suite runs with warnings as errors) is written to the crash
folder once per distinct signature (type, message head, innermost tsog_stream frame) and the
run goes on, so one campaign reports every distinct crash. Hangs and memory blow-ups are
caught by libFuzzer itself (-timeout, -rss_limit_mb), which writes its own artifact and stops.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path

import atheris

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

with atheris.instrument_imports(include=["tsog_stream"]):
    import tsog_stream.client
    import tsog_stream.codec.chunk
    import tsog_stream.io.cameras
    import tsog_stream.io.ply
    import tsog_stream.io.splatv
    import tsog_stream.render.camera
    import tsog_stream.render.project
    import tsog_stream.render.raster
    import tsog_stream.schemas.validate
    import tsog_stream.server.conditional
    import tsog_stream.server.ranges  # noqa: F401

from fuzz.targets import TARGETS, digest, outcome  # noqa: E402

REPLAY_FLUSH = 1000
"""Figures are written after each of the first inputs (a replay exits right after them)."""


def signature(exc: BaseException) -> str:
    """What identifies a crash: its type, message head and innermost frame in our package."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if "tsog_stream" in f.filename] or frames
    place = f"{Path(ours[-1].filename).name}:{ours[-1].lineno}" if ours else "?"
    return f"{type(exc).__name__} at {place}: {str(exc)[:80]}"


class Recorder:
    """Counts outcomes, stores one input per distinct crash, flushes figures once a second."""

    def __init__(self, target: str, stats: Path, crashes: Path) -> None:
        self.target = target
        self.stats = stats
        self.crashes = crashes
        self.counts: Counter[str] = Counter()
        self.signatures: dict[str, str] = {}
        self.flushed = 0.0

    def __call__(self, data: bytes) -> None:
        self.counts["inputs"] += 1
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                self.counts[outcome(TARGETS[self.target], data)] += 1
        except Exception as exc:  # a crash: anything but a TsogError
            self.counts["crashing_inputs"] += 1
            self.record(exc, data)
        if self.counts["inputs"] <= REPLAY_FLUSH or time.monotonic() - self.flushed > 1.0:
            self.flush()

    def record(self, exc: BaseException, data: bytes) -> None:
        """Keep the first input of each distinct crash, with its traceback."""
        sig = signature(exc)
        if sig in self.signatures:
            return
        name = f"{self.target}-{digest(data)}"
        self.signatures[sig] = name
        self.crashes.mkdir(parents=True, exist_ok=True)
        (self.crashes / f"{name}.bin").write_bytes(data)
        text = "".join(traceback.format_exception(exc))
        (self.crashes / f"{name}.txt").write_text(f"{sig}\n\n{text}")
        print(f"CRASH {sig} -> {name}.bin", file=sys.stderr, flush=True)

    def flush(self) -> None:
        """Write the figures so far (the process may end inside libFuzzer at any time)."""
        self.flushed = time.monotonic()
        doc = {"counts": dict(self.counts), "crashes": self.signatures}
        self.stats.write_text(json.dumps(doc, indent=1, sort_keys=True))


def main() -> None:
    """Parse our options, hand the rest to libFuzzer."""
    parser = argparse.ArgumentParser()
    parser.add_argument("target", choices=sorted(TARGETS))
    parser.add_argument("--stats", type=Path, required=True)
    parser.add_argument("--crashes", type=Path, required=True)
    args, rest = parser.parse_known_args()
    recorder = Recorder(args.target, args.stats, args.crashes)
    recorder.flush()
    atheris.Setup([sys.argv[0], *[a for a in rest if a != "--"]], recorder)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
