"""A held scan's files written side by side (simlidar_mi/lidar/scan_files.py): same bytes as
one after another, every writer really concurrent, the first error raised, nothing half-written."""
from __future__ import annotations

import threading

import pytest

from simlidar_mi.io import las as las_module
from simlidar_mi.lidar import scan_files
from simlidar_mi.lidar.scan_files import run_side_by_side, write_held_scan
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES

CYLINDER = SCENES / "calibration_cylinder.toml"


def test_jobs_run_side_by_side_and_return_by_name():
    # Two jobs that can only finish together: a barrier of 2 breaks (after 10 s) unless
    # both are running at once.
    barrier = threading.Barrier(2, timeout=10)
    out = run_side_by_side([("a", lambda: barrier.wait() * 0 + 1), ("b", lambda: barrier.wait() * 0 + 2)])
    assert out == {"a": 1, "b": 2}


def test_one_thread_runs_in_order_here():
    seen = []
    out = run_side_by_side([("x", lambda: seen.append(threading.current_thread()) or "x"),
                            ("y", lambda: seen.append(threading.current_thread()) or "y")], threads=1)
    assert out == {"x": "x", "y": "y"} and seen == [threading.main_thread()] * 2


def test_first_error_in_job_order_after_every_job_stopped():
    done = []
    release = threading.Event()

    def late_ok():
        release.wait(10)
        done.append("late")

    def first_failure():
        release.set()
        raise ValueError("first")

    def second_failure():
        raise KeyError("second")

    with pytest.raises(ValueError, match="first"):
        run_side_by_side([("late", late_ok), ("f1", first_failure), ("f2", second_failure)])
    assert done == ["late"]  # the slow writer had finished before the error was raised


def _result():
    return run_scan(CYLINDER, None, ["scan.dy_m=0.01"]).result


def test_same_bytes_as_one_writer_after_another(tmp_path, monkeypatch):
    res = _result()
    kw = {"exr_kwargs": {"seed": 3, "scene_sha256": "ab"}, "las": True, "crs": None}
    paths = {}
    for threads in (1, scan_files.WRITER_THREADS):
        monkeypatch.setattr(scan_files, "WRITER_THREADS", threads)
        d = tmp_path / f"t{threads}"
        d.mkdir()
        # two legs: each leg's EXR and PNG, one LAS of both
        paths[threads], extra = write_held_scan([res, res], d, d, png_titles=["leg 0", "leg 1"],
                                                also=lambda: 7, **kw)
        assert extra == 7
    assert list(paths[1]) == ["exr0", "png0", "exr1", "png1", "las"]
    for key in paths[1]:
        assert paths[1][key].read_bytes() == paths[scan_files.WRITER_THREADS][key].read_bytes(), key


def test_failing_writer_leaves_the_folder_as_it_was(tmp_path, monkeypatch):
    out = tmp_path / "scan"
    run_scan(CYLINDER, out, ["scan.dy_m=0.01"])
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(las_module, "write_scan_las", broken)
    with pytest.raises(OSError, match="disk full"):
        run_scan(CYLINDER, out, ["scan.dy_m=0.02"])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
