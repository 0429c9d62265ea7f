"""Shared fixtures: the repo's scenes folder, the shared photos folder, a fixed seed."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / "scenes"
SHARED = REPO.parent / "shared"


@pytest.fixture
def scenes_dir() -> Path:
    return SCENES


@pytest.fixture
def seed() -> int:
    return 20131105
