"""A held scan's files with the LAS written by a forked child (simlidar_mi/lidar/scan_files.py):
the same bytes as written here in turn, the child's failure raised with its message, the
parent's own failure raised after the child has ended, and nothing half-written."""
from __future__ import annotations

import os

import pytest

from simlidar_mi.errors import SimlidarError
from simlidar_mi.io import exr as exr_module
from simlidar_mi.io import las as las_module
from simlidar_mi.lidar import scan_files
from simlidar_mi.lidar.scan_files import write_held_scan
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES

CYLINDER = SCENES / "calibration_cylinder.toml"
KW = {"exr_kwargs": {"seed": 3, "scene_sha256": "ab"}, "las": True, "crs": None}
needs_fork = pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork on this system")


def _result():
    return run_scan(CYLINDER, None, ["scan.dy_m=0.01"]).result


@needs_fork
def test_same_bytes_forked_or_here(tmp_path, monkeypatch):
    res = _result()
    paths = {}
    for fork in (False, True):
        monkeypatch.setattr(scan_files, "FORK_LAS", fork)
        d = tmp_path / f"fork{fork}"
        d.mkdir()
        # two legs: each leg's EXR and PNG, one LAS of both; `also` runs here
        paths[fork], extra = write_held_scan([res, res], d, d, png_titles=["leg 0", "leg 1"],
                                             also=lambda: os.getpid(), **KW)
        assert extra == os.getpid()
        assert sorted(p.name for p in d.iterdir()) == ["points.las", "scan_leg0.exr", "scan_leg0.png",
                                                        "scan_leg1.exr", "scan_leg1.png"]
    assert list(paths[True]) == ["exr0", "png0", "exr1", "png1", "las"]
    for key in paths[False]:
        assert paths[False][key].read_bytes() == paths[True][key].read_bytes(), key


@needs_fork
def test_child_failure_names_the_file_and_leaves_the_folder_as_it_was(tmp_path, monkeypatch):
    out = tmp_path / "scan"
    run_scan(CYLINDER, out, ["scan.dy_m=0.01"])
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(scan_files, "FORK_LAS", True)
    monkeypatch.setattr(las_module, "write_scan_las", broken)
    with pytest.raises(SimlidarError, match=r"writing points.las failed: OSError: disk full \(simulated\)"):
        run_scan(CYLINDER, out, ["scan.dy_m=0.02"])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@needs_fork
def test_own_failure_raised_after_the_child_ended(tmp_path, monkeypatch):
    res = _result()
    seen = {}

    def broken_exr(*args, **kwargs):
        raise ValueError("bad EXR (simulated)")

    real_wait = scan_files._Child.wait

    def wait(self):
        real_wait(self)
        seen["reaped"] = self.pid

    monkeypatch.setattr(scan_files, "FORK_LAS", True)
    monkeypatch.setattr(exr_module, "write_scan_exr", broken_exr)
    monkeypatch.setattr(scan_files._Child, "wait", wait)
    with pytest.raises(ValueError, match="bad EXR"):
        write_held_scan([res], tmp_path, tmp_path, png_titles=None, **KW)
    with pytest.raises(ChildProcessError):  # reaped: no such child any more
        os.waitpid(seen["reaped"], os.WNOHANG)
    assert (tmp_path / "points.las").stat().st_size > 0  # the child had finished its file
