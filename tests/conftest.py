"""Shared fixtures: the real sample data (in the repository, and optional larger sets) and the
reference tool.

``samples`` is ``tests/data/real/``: small permissively licensed real files carried by the
repository (tests/data/README.md lists them with provenance and licence), so a clone tests
itself. ``optional_samples`` is a larger set with the same layout (``../shared/data``, see its
PROVENANCE.md): found through ``$TSOG_SAMPLE_DATA``, else ``../shared/data`` beside the
checkout. When it is absent its tests skip, saying how to provide it; with ``CI=true`` a missing
optional sample fails instead, so CI keeps proving them.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "tests" / "data" / "real"
SAMPLE_DATA_ENV = "TSOG_SAMPLE_DATA"
SHARED_DATA = REPO.parent / "shared" / "data"
SPLAT_TRANSFORM = REPO / "node_modules" / ".bin" / "splat-transform"


def optional_data_dir() -> Path | None:
    """The optional sample set: ``$TSOG_SAMPLE_DATA``, else ``../shared/data``; None if absent."""
    chosen = os.environ.get(SAMPLE_DATA_ENV)
    for candidate in ([Path(chosen)] if chosen else []) + [SHARED_DATA]:
        if candidate.is_dir():
            return candidate
    return None


def missing_optional(what: str) -> None:
    """Skip (fail under CI=true) a test whose optional sample is not here, saying how to get it."""
    message = (
        f"optional sample data not found ({what}): set {SAMPLE_DATA_ENV}=/path/to/data (the "
        f"layout of ../shared/data, see its PROVENANCE.md) or put shared/data beside the checkout"
    )
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(message)
    pytest.skip(message)


@pytest.fixture(scope="session")
def samples() -> Path:
    """The real samples carried by the repository (tests/data/real, same layout as
    ../shared/data)."""
    return SAMPLES


@pytest.fixture(scope="session")
def optional_samples() -> Path:
    """The optional, larger real sample set (``$TSOG_SAMPLE_DATA`` or ``../shared/data``)."""
    found = optional_data_dir()
    if found is None:
        missing_optional(f"${SAMPLE_DATA_ENV} unset and {SHARED_DATA} missing")
    assert found is not None
    return found


@pytest.fixture(scope="session")
def splat_transform() -> Path:
    """The reference SOG tool installed by scripts/setup (npm, pinned in package-lock.json)."""
    if not SPLAT_TRANSFORM.exists() or shutil.which("node") is None:
        pytest.fail("splat-transform is not installed: run scripts/setup")
    return SPLAT_TRANSFORM
