"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("ISA_SHARED_DATA", ROOT.parent / "shared" / "data"))

# Rendering must pick its headless GL platform before pyrender is first imported.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real ModelNet10 and SUN RGB-D); skips the test when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (set ISA_SHARED_DATA or check out ../shared)")
    return SHARED_DATA
