"""A bounded fuzz campaign: each target in its own atheris process, one after another.

Seeds are the valid inputs of :func:`fuzz.targets.valid_seeds` plus the files of
``tests/data/invalid/`` that the target reads. Crashes go to ``fuzz/crashes/`` (gitignored);
figures to ``benchmarks/results/fuzz.json`` and to the ``## Fuzzing`` section of
``docs/reliability.md`` (between the fuzz markers, which are regenerated).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fuzz.targets import TARGETS, target_for, valid_seeds  # noqa: E402

INVALID = ROOT / "tests" / "data" / "invalid"
WORK = ROOT / "fuzz" / "work"
CRASHES = ROOT / "fuzz" / "crashes"
RESULTS = ROOT / "benchmarks" / "results" / "fuzz.json"
DOC = ROOT / "docs" / "reliability.md"
FINDINGS = ROOT / "fuzz" / "findings.md"
BEGIN, END = "<!-- fuzz:begin -->", "<!-- fuzz:end -->"
MAX_RESTARTS = 5
"""A target whose process dies (hang, memory) is restarted at most this often."""
LIBFUZZER = ("-timeout=10", "-rss_limit_mb=1024", "-print_final_stats=1", "-max_len=65536")


def prepare(target: str) -> tuple[Path, Path]:
    """A fresh writable corpus folder and a seed folder for ``target``."""
    corpus, seeds = WORK / target / "corpus", WORK / target / "seeds"
    for folder in (corpus, seeds):
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
    for name, data in valid_seeds(target).items():
        (seeds / name).write_bytes(data)
    for path in sorted(INVALID.glob("*")) if INVALID.is_dir() else []:
        if path.is_file() and path.suffix and target_for_safe(path) == target:
            shutil.copy(path, seeds / path.name)
    return corpus, seeds


def target_for_safe(path: Path) -> str | None:
    """The target of a corpus file, or None for an extension no target reads."""
    try:
        return target_for(path)
    except KeyError:
        return None


def run_target(target: str, seconds: int, seed: int) -> dict[str, Any]:
    """Fuzz one target for about ``seconds``; its figures."""
    corpus, seeds = prepare(target)
    stats = WORK / target / "stats.json"
    deadline = time.monotonic() + seconds
    runs, deaths, executions = 0, [], 0
    while runs <= MAX_RESTARTS and (left := int(deadline - time.monotonic())) > 0:
        stats_run = stats.with_suffix(f".{runs}.json")
        command = [
            sys.executable,
            str(ROOT / "fuzz" / "harness.py"),
            target,
            "--stats",
            str(stats_run),
            "--crashes",
            str(CRASHES),
            "--",
            str(corpus),
            str(seeds),
            f"-max_total_time={left}",
            f"-seed={seed + runs}",
            f"-artifact_prefix={CRASHES}/{target}-",
            *LIBFUZZER,
        ]
        CRASHES.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "PYTHONHASHSEED": "0"}
        done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
        log = done.stderr + done.stdout
        (WORK / target / f"log.{runs}.txt").write_text(log)
        executions += _executions(log)
        if done.returncode != 0:
            deaths.append(_death(log, done.returncode))
        runs += 1
        if done.returncode == 0:
            break
    return _figures(target, seconds, executions, deaths, corpus=corpus, runs=runs)


def _executions(log: str) -> int:
    """Executed inputs reported by libFuzzer (final stats, or the last status line)."""
    found = re.findall(r"stat::number_of_executed_units: *(\d+)", log)
    if found:
        return int(found[-1])
    lines = re.findall(r"^#(\d+)\s", log, re.MULTILINE)
    return int(lines[-1]) if lines else 0


def _death(log: str, code: int) -> str:
    """Why a harness process stopped early (timeout, out of memory, other)."""
    for pattern, what in (
        (r"ERROR: libFuzzer: timeout", "hang (timeout)"),
        (r"out-of-memory", "out of memory"),
    ):
        if re.search(pattern, log):
            return what
    return f"exit code {code}"


def _figures(
    target: str, seconds: int, executions: int, deaths: list[str], *, corpus: Path, runs: int
) -> dict[str, Any]:
    """Merge the per-process stats files of a target."""
    counts: dict[str, int] = {}
    crashes: dict[str, str] = {}
    for path in sorted((WORK / target).glob("stats.*.json")):
        doc = json.loads(path.read_text())
        for key, value in doc["counts"].items():
            counts[key] = counts.get(key, 0) + value
        crashes.update(doc["crashes"])
    return {
        "seconds": seconds,
        "processes": runs,
        "executions": executions,
        "decoded": counts.get("decoded", 0),
        "rejected": counts.get("rejected", 0),
        "crashing_inputs": counts.get("crashing_inputs", 0),
        "distinct_crashes": sorted(crashes),
        "process_deaths": deaths,
        "corpus_files": len(list(corpus.iterdir())),
    }


def section(results: dict[str, dict[str, Any]]) -> str:
    """The generated Markdown of the fuzz section."""
    rows = [
        "| target | seconds | inputs executed | decoded | rejected (TsogError) | crashes "
        "| hangs / OOM | new corpus files |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        doc = (TARGETS[name].__doc__ or "").split("\n")[0].rstrip(".")
        rows.append(
            f"| `{name}`: {doc} | {r['seconds']} | {r['executions']:,} | {r['decoded']:,} "
            f"| {r['rejected']:,} | {len(r['distinct_crashes'])} | {len(r['process_deaths'])} "
            f"| {r['corpus_files']} |"
        )
    total = sum(r["executions"] for r in results.values())
    seconds = max((r["seconds"] for r in results.values()), default=0)
    when = RESULTS.stat().st_mtime if RESULTS.exists() else time.time()
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(when))
    lines = [
        BEGIN,
        "",
        "Generated by `scripts/fuzz` (atheris 3.0, libFuzzer; seeds: valid files built by "
        "`fuzz/targets.py` plus `tests/data/invalid/`). A crash is any exception other than a "
        "`TsogError` with a message, or any warning; hangs (`-timeout=10`) and memory "
        "blow-ups (`-rss_limit_mb=1024`) stop the process and are counted separately. "
        "Each distinct crash is kept as `fuzz/crashes/TARGET-HASH.bin` with its traceback "
        "in `.txt`; replay one with `.venv/bin/python fuzz/harness.py TARGET --stats "
        "/tmp/s.json --crashes /tmp/c -- FILE`.",
        "",
        "In the suite, the same targets run under hypothesis (`tests/test_fuzz_parsers.py`: "
        "derandomized mutations of valid files, a few hundred inputs per target, plus "
        "tiny hostile inputs checked with tracemalloc) and over the hand-made corpus "
        "(`tests/test_invalid_corpus.py`: every file of `tests/data/invalid/`, made by "
        "`scripts/make_invalid_corpus.py`, raises the `TsogError` listed in its "
        "`expected.tsv`).",
        "",
        f"Last campaign ({stamp}): `scripts/fuzz --seconds {seconds}`, one target after "
        f"another on a 2-core machine, {total:,} inputs in all. Decoded and rejected "
        "counts come from the harness's last flush (at most a second behind libFuzzer's "
        "count of inputs executed).",
        "",
        *rows,
        "",
    ]
    crashes = [(n, c) for n, r in results.items() for c in r["distinct_crashes"]]
    crashes += [(n, d) for n, r in results.items() for d in r["process_deaths"]]
    lines.append(
        "Open crashes in this campaign: "
        + ("none." if not crashes else "; ".join(f"`{n}`: {c}" for n, c in crashes))
    )
    lines.append("")
    if FINDINGS.exists():
        lines.extend([FINDINGS.read_text().rstrip(), ""])
    lines.append(END)
    return "\n".join(lines)


def write_doc(text: str) -> None:
    """Replace (or add) the fuzz section of docs/reliability.md."""
    doc = DOC.read_text() if DOC.exists() else "# Reliability and security\n"
    if BEGIN in doc and END in doc:
        head, rest = doc.split(BEGIN, 1)
        doc = head + text + rest.split(END, 1)[1]
    elif "## Fuzzing" in doc:
        head, rest = doc.split("## Fuzzing", 1)
        doc = head + "## Fuzzing\n\n" + text + "\n" + rest.lstrip("\n")
    else:
        doc = doc.rstrip("\n") + "\n\n## Fuzzing\n\n" + text + "\n"
    DOC.write_text(doc)


def main(argv: list[str] | None = None) -> int:
    """``scripts/fuzz [--seconds N] [--target NAME]...``; exit 1 when a crash was found."""
    parser = argparse.ArgumentParser(prog="scripts/fuzz", description=__doc__)
    parser.add_argument("--seconds", type=int, default=60, help="per target (default 60)")
    parser.add_argument("--target", action="append", choices=sorted(TARGETS))
    parser.add_argument("--seed", type=int, default=1, help="libFuzzer seed")
    parser.add_argument("--no-doc", action="store_true", help="do not rewrite the docs section")
    parser.add_argument(
        "--report", action="store_true", help="only rewrite the docs section from the results"
    )
    args = parser.parse_args(argv)
    names = [] if args.report else (args.target or list(TARGETS))
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    for name in names:
        print(f"fuzz: {name} for {args.seconds} s", file=sys.stderr, flush=True)
        results[name] = run_target(name, args.seconds, args.seed)
        r = results[name]
        print(
            f"fuzz: {name}: {r['executions']} inputs, {len(r['distinct_crashes'])} crashes, "
            f"{len(r['process_deaths'])} hangs/OOM",
            file=sys.stderr,
            flush=True,
        )
    results = {n: results[n] for n in TARGETS if n in results}
    if names:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    if not args.no_doc:
        write_doc(section(results))
    bad = any(results[n]["distinct_crashes"] or results[n]["process_deaths"] for n in names)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
