"""Shared fixtures: paths to the real sample data and to the reference tool."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
SPLAT_TRANSFORM = REPO / "node_modules" / ".bin" / "splat-transform"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of real 3DGS/4D sample files (../shared/data beside the checkout)."""
    if not SHARED_DATA.is_dir():
        pytest.fail(f"sample data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def splat_transform() -> Path:
    """The reference SOG tool installed by scripts/setup (npm, pinned in package-lock.json)."""
    if not SPLAT_TRANSFORM.exists() or shutil.which("node") is None:
        pytest.fail("splat-transform is not installed: run scripts/setup")
    return SPLAT_TRANSFORM
