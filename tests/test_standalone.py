"""The repository stands alone: a copy with nothing beside it (no ../shared, no
$TSOG_SAMPLE_DATA) passes the tests that read real samples, skipping only the optional ones."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, SAMPLE_DATA_ENV

SAMPLE_TESTS = [
    "tests/test_ply.py",
    "tests/test_sequence.py",
    "tests/test_splatv.py",
    "tests/test_schemas.py",
    "tests/test_compressed_ply.py",
    "tests/test_inputs_roundtrip.py",
    "tests/test_cli.py::test_encode_decode_round_trip",
    "tests/test_cli.py::test_encode_refuses_to_overwrite_without_force",
]
"""Tests that read real samples (tests/data/real, and the optional set): whole files, and the
two of test_cli.py that do (its other tests take 12 s and read none)."""


def repository_files() -> list[str]:
    """Every file a clone of this working tree holds (tracked, or new and not ignored)."""
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=REPO,
        check=True,
        capture_output=True,
    ).stdout
    return [name for name in out.decode().split("\0") if name and (REPO / name).is_file()]


@pytest.mark.slow
def test_a_clone_with_nothing_beside_it_passes(tmp_path: Path) -> None:
    clone = tmp_path / "alone" / "tsog-stream"
    for name in repository_files():
        (clone / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, clone / name)
    assert not (clone.parent / "shared").exists()
    if (REPO / "node_modules").is_dir():  # what scripts/setup installs, not sample data
        (clone / "node_modules").symlink_to(REPO / "node_modules")
    env = {k: v for k, v in os.environ.items() if k not in ("CI", SAMPLE_DATA_ENV)}
    env["PYTHONPATH"] = str(clone / "src")  # the copy's code, not the editable install's
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", *SAMPLE_TESTS],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    tail = proc.stdout[-3000:]
    assert proc.returncode == 0, tail
    passed = re.search(r"(\d+) passed", tail)
    assert passed is not None and int(passed.group(1)) > 150, tail
    reasons = re.findall(r"^SKIPPED \[\d+\] [^:]+:\d+: (.*)$", proc.stdout, re.M)
    assert reasons, "the optional samples were expected to be missing here"
    assert all(r.startswith("optional sample data not found") for r in reasons), reasons


@pytest.mark.slow
def test_ci_turns_a_missing_optional_sample_into_a_failure(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != SAMPLE_DATA_ENV}
    env.update(CI="true", **{SAMPLE_DATA_ENV: str(tmp_path / "nowhere")})
    clone = tmp_path / "alone" / "tsog-stream"
    for name in ("tests/conftest.py", "tests/test_sequence.py", "pyproject.toml"):
        (clone / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, clone / name)
    for helper in ("helpers.py", "fixtures_4d.py"):
        shutil.copy2(REPO / "tests" / helper, clone / "tests" / helper)
    env["PYTHONPATH"] = str(REPO / "src")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "tests/test_sequence.py::test_monkey_sog_sequence_count[optional_samples-50]",
        ],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 1, proc.stdout[-2000:]
    assert "1 failed" in proc.stdout and "optional sample data not found" in proc.stdout
