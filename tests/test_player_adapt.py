"""The web player's adaptation (player/adapt.js with manifest.js) makes the Python client's
choices (client/adaptive.py): both run on the same seeded indexes and states, in Node (the
JavaScript engine the project's npm tools already need) and in Python, every answer compared."""

from __future__ import annotations

import json
import random
import subprocess
from pathlib import Path
from typing import Any

from tsog_stream.client.adaptive import (
    Throughput,
    choose_layers,
    delay_needed,
    layers_shown,
    startup_allowance,
)
from tsog_stream.container.stream_index import StreamIndex, unpacked_index
from tsog_stream.schemas.manifest import Manifest, dump_manifest

PLAYER = Path(__file__).resolve().parents[1] / "src" / "tsog_stream" / "server" / "player"
BOX = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
RUNNER = """
import { readFileSync } from 'node:fs';
import { SceneIndex } from '%(player)s/manifest.js';
import {
    Throughput, chooseLayers, delayNeeded, layersShown, startupAllowance,
} from '%(player)s/adapt.js';
const input = JSON.parse(readFileSync(0, 'utf8'));
const out = input.cases.map(({ manifest, states, events }) => {
    const index = new SceneIndex(manifest);
    const answers = states.map((s) => {
        const have = (id) => s.have.includes(id);
        const missing = index.chunksForInterval(s.t, s.end, s.layers);
        return {
            choose: chooseLayers(index, s.t, s.end, { speed: s.speed, rate: s.rate, have,
                                                      current: s.current, allowance: s.allowance }),
            delay: delayNeeded(missing, s.t, s.speed, s.rate ?? 0),
            shown: layersShown(index, s.t, have),
            ids: missing.map((c) => c.id),
        };
    });
    let now = 0;
    const meter = new Throughput(() => now);
    const estimates = events.map(([clock, kind, nbytes]) => {
        now = clock;
        if (kind === 'start') meter.started(); else meter.finished(nbytes);
        return meter.estimate;
    });
    return { answers, estimates, allowance: [0.3, 1.7, 5].map(startupAllowance) };
});
const text = (k, v) => (v === Infinity ? 'inf' : v === -Infinity ? '-inf' : v);
process.stdout.write(JSON.stringify(out, text));
"""


def random_manifest(rng: random.Random) -> dict[str, Any]:
    """Windows of 1 s under a two-level hierarchy, chunks of 1-4 layers with random
    intervals and sizes (a layered stream's index, valid by the schema)."""
    windows = rng.randint(1, 6)
    layers = rng.randint(1, 4)
    nodes: list[dict[str, Any]] = [
        {"level": 0, "index": w, "start_s": float(w), "end_s": float(w + 1), "chunks": []}
        for w in range(windows)
    ]
    nodes += [
        {"level": 1, "index": i, "start_s": 2.0 * i, "end_s": 2.0 * i + 2, "chunks": []}
        for i in range(-(-windows // 2))
    ]
    chunks, offset = [], 16384
    for cid in range(rng.randint(1, 14)):
        node = rng.randrange(len(nodes))
        lo, hi = nodes[node]["start_s"], min(nodes[node]["end_s"], float(windows))
        start = rng.uniform(lo, hi)
        length = rng.randint(1, 50_000)
        chunks.append(
            {
                "id": cid,
                "file": f"chunks/{cid:06d}.sog",
                "offset": offset,
                "length": length,
                "sha256": "0" * 64,
                "count": 1,
                "level": nodes[node]["level"],
                "node": nodes[node]["index"],
                "start_s": start,
                "end_s": rng.uniform(start, hi),
                "bbox": BOX,
                "layer": rng.randrange(layers),
            }
        )
        nodes[node]["chunks"].append(cid)
        offset += length
    layer_list = [
        {"index": k, "gaussians": 1, "bytes": 1, "psnr_db": None if k == layers - 1 else 20.0}
        for k in range(layers)
    ]
    return {
        "generator": "test",
        "policy": "hierarchy",
        "window_s": 1.0,
        "max_pixels": 4096,
        "scene": {
            "gaussians": 1,
            "stored": 1,
            "start_s": 0.0,
            "end_s": float(windows),
            "timeline_type": 2,
            "temporal": {},
            "sh_bands": 0,
            "bbox": BOX,
        },
        "nodes": nodes,
        "chunks": chunks,
        "payload_bytes": offset - 16384,
        "layers": layer_list if layers > 1 else [],
    }


def random_states(rng: random.Random, manifest: dict[str, Any]) -> list[dict[str, Any]]:
    """Playback states: a time, an end, a throughput (or none yet), the layers held, what
    has arrived, the allowance."""
    end_s = manifest["scene"]["end_s"]
    count = max(len(manifest["layers"]), 1)
    states = []
    for _ in range(12):
        t = rng.uniform(-0.5, end_s + 0.5)
        states.append(
            {
                "t": t,
                "end": min(end_s, t + rng.uniform(0.0, 4.0)),
                "speed": rng.choice([0.5, 1.0, 2.0]),
                "rate": rng.choice([None, 0.0, 5e3, 5e4, 5e5, 5e6]),
                "current": rng.randint(0, count),
                "allowance": rng.choice([0.0, 0.5, 2.0, 8.0]),
                "have": [c["id"] for c in manifest["chunks"] if rng.random() < 0.5],
                "layers": rng.randint(1, count),
            }
        )
    return states


def random_events(rng: random.Random) -> list[list[Any]]:
    """Requests starting and finishing on a clock, some in parallel."""
    events, clock, open_requests = [], 0.0, 0
    for _ in range(20):
        clock += rng.uniform(0.0, 0.4)
        if open_requests and rng.random() < 0.5:
            events.append([clock, "finish", rng.choice([0, rng.randint(1, 10**6)])])
            open_requests -= 1
        else:
            events.append([clock, "start", 0])
            open_requests += 1
    return events


def python_answers(case: dict[str, Any]) -> dict[str, Any]:
    """What client/adaptive.py says for one case."""
    manifest = Manifest.model_validate(case["manifest"])
    index: StreamIndex = unpacked_index(dump_manifest(manifest), where="case")
    answers = []
    for s in case["states"]:
        have = set(s["have"])
        missing = index.chunks_for_interval(s["t"], s["end"], s["layers"])
        answers.append(
            {
                "choose": choose_layers(
                    index,
                    s["t"],
                    s["end"],
                    speed=s["speed"],
                    rate=s["rate"],
                    have=have.__contains__,
                    current=s["current"],
                    allowance=s["allowance"],
                ),
                "delay": delay_needed(missing, s["t"], s["speed"], s["rate"] or 0.0),
                "shown": layers_shown(index, s["t"], have.__contains__),
                "ids": [c.id for c in missing],
            }
        )
    now = [0.0]
    meter = Throughput(lambda: now[0])
    estimates = []
    for clock, kind, nbytes in case["events"]:
        now[0] = clock
        if kind == "start":
            meter.started()
        else:
            meter.finished(nbytes)
        estimates.append(meter.estimate)
    return {
        "answers": answers,
        "estimates": estimates,
        "allowance": [startup_allowance(x) for x in (0.3, 1.7, 5)],
    }


def _same(a: Any, b: Any) -> bool:
    """Equal, numbers within 1e-9 relative (infinities are the text "inf" / "-inf" on both)."""
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return abs(a - b) <= 1e-9 * max(1.0, abs(a))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def _inf_as_text(value: Any) -> Any:
    return json.loads(json.dumps(value).replace("-Infinity", '"-inf"').replace("Infinity", '"inf"'))


def test_the_player_adapts_exactly_as_the_client() -> None:
    rng = random.Random(19)
    cases: list[dict[str, Any]] = []
    for _ in range(40):
        manifest = random_manifest(rng)
        cases.append(
            {
                "manifest": manifest,
                "states": random_states(rng, manifest),
                "events": random_events(rng),
            }
        )
    script = RUNNER % {"player": PLAYER.as_posix()}
    done = subprocess.run(
        ["node", "--input-type=module", "-e", script],
        input=json.dumps({"cases": cases}),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    javascript = json.loads(done.stdout)
    choices: set[int] = set()
    for case, js in zip(cases, javascript, strict=True):
        py = _inf_as_text(python_answers(case))
        assert _same(py, js), (case["manifest"]["chunks"], py, js)
        choices.update(a["choose"] for a in py["answers"])
    assert choices == {1, 2, 3, 4}  # the cases reach every layer count
