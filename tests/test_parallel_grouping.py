"""tests/conftest.py's collection rules for parallel runs: a docs page's `-quick` run is left out
only when its `-whole` run is selected too, and a module's tests sharing a module-scoped fixture
get that module as their xdist group."""
from __future__ import annotations

from types import SimpleNamespace

from tests.conftest import _module_scoped_group, _whole_covers_quick

PAGE = "tests/test_docs.py::test_page_code_blocks_run[guide/forests.md-{}]"


def _item(nodeid, **fixtures):
    defs = {name: [SimpleNamespace(scope=scope, baseid=baseid)] for name, (scope, baseid) in fixtures.items()}
    return SimpleNamespace(nodeid=nodeid, _fixtureinfo=SimpleNamespace(name2fixturedefs=defs))


def test_quick_is_left_out_only_beside_its_whole():
    quick, whole = _item(PAGE.format("quick")), _item(PAGE.format("whole"))
    other = _item(PAGE.replace("forests", "dask").format("quick"))
    assert _whole_covers_quick([quick, whole, other]) == [quick]
    assert _whole_covers_quick([quick, other]) == []  # -m "not slow": the quick runs stay


def test_module_fixtures_group_their_module():
    shared = _item("tests/test_scan.py::test_a", calibration=("module", "tests/test_scan.py"),
                   tmp_path=("function", ""))
    cluster = _item("tests/test_scan_tiles.py::test_b", cluster=("module", "tests"))
    alone = _item("tests/test_scan.py::test_c", tmp_path_factory=("session", ""), tmp_path=("function", ""))
    assert _module_scoped_group(shared) == "tests/test_scan.py"
    assert _module_scoped_group(cluster) == "tests/test_scan_tiles.py"
    assert _module_scoped_group(alone) is None  # pytest's own session fixtures share nothing costly
