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


# --- parallel runs (pytest-xdist; `make test` runs `-n 2 --dist loadgroup`) -------------------
def _module_scoped_group(item) -> str | None:
    """The test's module when it uses a module-, package- or session-scoped fixture defined in
    tests/ (a shared scan, a docs build, a Dask cluster): all its tests then go to one worker, so
    the fixture is built once, not once per worker. None for a test that shares nothing."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return None
    for defs in info.name2fixturedefs.values():
        for d in defs:
            if d.scope != "function" and d.baseid.startswith("tests"):
                return item.nodeid.split("::", 1)[0]
    return None


def _whole_covers_quick(items) -> list:
    """A docs page with a known-slow line is collected twice: `-quick` (its other blocks) and
    `-whole` (every block, marked slow). When both are selected the whole run checks everything
    the quick one does, so the quick one is left out (it runs under -m "not slow")."""
    ids = {item.nodeid for item in items}
    return [item for item in items
            if item.nodeid.endswith("-quick]") and item.nodeid[:-len("-quick]")] + "-whole]" in ids]


@pytest.hookimpl(trylast=True)  # after -m/-k have deselected: only a selected `-whole` covers
def pytest_collection_modifyitems(config, items):
    covered = _whole_covers_quick(items)
    if covered:
        config.hook.pytest_deselected(items=covered)
        items[:] = [item for item in items if item not in covered]
    for item in items:
        group = _module_scoped_group(item)
        if group and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(group))
