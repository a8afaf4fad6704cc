"""Every hand-made bad file of tests/data/invalid/ is refused with the right TsogError.

The reader follows from the extension (fuzz/targets.py); the expected error class and the
defect come from ``expected.tsv``, written with the files by scripts/make_invalid_corpus.py.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tracemalloc
from pathlib import Path
from types import ModuleType

import pytest

from tsog_stream import errors

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "data" / "invalid"
MAX_PEAK_BYTES = 64 * 1024 * 1024
"""No corpus file (each < 20 KB) may make a reader allocate more than this."""


def load(relative: str, name: str) -> ModuleType:
    """Import a module of the repository that is not part of the package (fuzz/, scripts/)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    spec = importlib.util.spec_from_file_location(name, ROOT / relative)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


targets = load("fuzz/targets.py", "fuzz_targets")


def expected() -> dict[str, tuple[str, str]]:
    """File name -> (error class name, what is wrong)."""
    lines = (CORPUS / "expected.tsv").read_text().splitlines()[1:]
    return {name: (error, what) for name, error, what in (line.split("\t") for line in lines)}


CASES = expected()


def test_the_corpus_is_up_to_date() -> None:
    script = ROOT / "scripts" / "make_invalid_corpus.py"
    done = subprocess.run(
        [sys.executable, str(script), "--check"],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr


def test_the_corpus_is_small_and_every_file_is_listed() -> None:
    files = {p.name: p.stat().st_size for p in CORPUS.iterdir()}
    assert set(files) == {*CASES, "expected.tsv"}
    assert sum(files.values()) < 200_000
    assert len(CASES) >= 40


@pytest.mark.parametrize("name", sorted(CASES))
def test_each_bad_file_raises_its_tsog_error(name: str) -> None:
    error_name, what = CASES[name]
    path = CORPUS / name
    target = targets.TARGETS[targets.target_for(path)]
    data = path.read_bytes()
    tracemalloc.start()
    try:
        with pytest.raises(errors.TsogError) as info:
            target(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert type(info.value).__name__ == error_name, f"{what}: {info.value!r}"
    assert isinstance(info.value, getattr(errors, error_name))
    assert info.value.message.strip()
    assert peak < MAX_PEAK_BYTES, f"{name} made the reader allocate {peak} bytes"
