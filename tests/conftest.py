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


@pytest.fixture(scope="module")
def cluster():
    """A Dask LocalCluster of 2 worker processes (one thread each), per test module; the
    module is skipped where one cannot start."""
    distributed = pytest.importorskip("distributed")
    try:
        lc = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                      dashboard_address=None)
    except Exception as exc:  # noqa: BLE001  (any failure to start means: no cluster here)
        pytest.skip(f"cannot start a Dask LocalCluster of 2 worker processes here: "
                    f"{type(exc).__name__}: {exc}")
    with lc:
        yield lc
