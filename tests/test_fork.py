"""simlidar_mi._runtime.fork: one call in a forked child (the forest's pictures, a scan's LAS file)."""
from __future__ import annotations

import copyreg
import os
import signal
import time

import numpy as np
import pytest

from simlidar_mi._runtime.fork import Forked, use_fork
from simlidar_mi.config import load_scene
from simlidar_mi.errors import SimlidarError
from simlidar_mi.lidar import survey
from tests.conftest import SCENES

needs_fork = pytest.mark.skipif(not use_fork(True), reason="no fork start method here")


def _pid_and_sum(a):
    return os.getpid(), float(a.sum())


def _fail(path):
    path.write_text("half")  # what a failing writer may leave behind in the staged folder
    raise ValueError(f"bad value in {path.name}")


def _die(code):
    os._exit(code)


def _sleep():
    time.sleep(60)


def _interrupted():
    os.kill(os.getpid(), signal.SIGINT)  # a SIGINT to the child alone
    time.sleep(5)
    return "not interrupted"


@needs_fork
def test_the_call_runs_in_another_process_and_its_value_comes_back():
    a = np.arange(1_000_000, dtype=np.float64)  # seen by the child as it is: nothing sent
    job = Forked("summing", _pid_and_sum, a, parallel=True)
    try:
        pid, total = job.wait()
    finally:
        job.close()
    assert pid != os.getpid() and total == float(a.sum())


def test_in_turn_when_not_parallel():
    job = Forked("summing", _pid_and_sum, np.ones(5), parallel=False)
    assert job.child is None and job.wait() == (os.getpid(), 5.0)
    job.close()


@needs_fork
def test_a_failure_in_the_child_raises_the_same_exception_here(tmp_path):
    job = Forked("writing x.bin", _fail, tmp_path / "x.bin", parallel=True)
    try:
        with pytest.raises(ValueError, match=r"bad value in x.bin") as err:  # as a call in turn raises
            job.wait()
    finally:
        job.close()
    if hasattr(err.value, "__notes__"):  # Python ≥ 3.11: what failed, and where
        assert "writing x.bin failed in a forked process" in err.value.__notes__[0]
        assert "_fail" in err.value.__notes__[0]


class _CannotPickle(Exception):
    def __init__(self):
        super().__init__("holds a lambda")
        self.hook = lambda: None  # not picklable: only the text goes back


def _load_fails():
    raise TypeError("cannot rebuild")


class _CannotLoad(Exception):
    def __reduce__(self):  # the class's own reduce: pickles, but fails in the parent
        return _load_fails, ()


def _raise(cls):
    raise cls()


@needs_fork
@pytest.mark.parametrize("fn, arg, message", [
    (_die, 3, r"the process writing x.bin died \(exit code 3\)"),
    (_raise, _CannotPickle, r"writing x.bin failed: _CannotPickle: holds a lambda"),
    (_raise, _CannotLoad, r"writing x.bin failed in a forked process, and its error could not be read back"),
])
def test_a_dead_child_or_an_error_that_cannot_come_back_is_a_simlidar_error(fn, arg, message, monkeypatch):
    # Dask's tblib registers every exception class in copyreg once imported: the classes' own
    # pickling is what this test is about
    monkeypatch.delitem(copyreg.dispatch_table, arg, raising=False)
    job = Forked("writing x.bin", fn, arg, parallel=True)
    try:
        with pytest.raises(SimlidarError, match=message):
            job.wait()
    finally:
        job.close()


@needs_fork
@needs_fork
def test_a_child_interrupted_alone_interrupts_the_caller():
    """A SIGINT that reaches only the child (a real Ctrl-C reaches both) ends the call as an
    interrupted call in turn would: KeyboardInterrupt here, not 'the process died'."""
    job = Forked("sleeping", _interrupted, parallel=True)
    try:
        with pytest.raises(KeyboardInterrupt):
            job.wait()
    finally:
        job.close()


def test_close_ends_a_child_still_running():
    job = Forked("sleeping", _sleep, parallel=True)
    t = time.perf_counter()
    job.close()
    assert not job.child.is_alive() and time.perf_counter() - t < 30


CALIB = SCENES / "calibration_cylinder.toml"


@needs_fork
def test_scan_files_are_the_same_bytes_with_the_las_forked_or_in_turn(tmp_path, monkeypatch):
    cfg = load_scene(CALIB)
    forked = survey.run_scan(cfg, tmp_path / "forked")
    monkeypatch.setattr("simlidar_mi._runtime.fork.use_fork", lambda parallel: False)
    in_turn = survey.run_scan(load_scene(CALIB), tmp_path / "turn")
    for k in ("exr", "png", "las"):
        assert forked.files[k].read_bytes() == in_turn.files[k].read_bytes(), k
    assert "measures" in forked.measures["seconds"]


@needs_fork
def test_a_las_writer_failing_in_the_child_leaves_no_folder(tmp_path, monkeypatch):
    def broken(result, path, crs=None):
        path.write_bytes(b"LASF half")
        raise OSError(28, "No space left on device")
    monkeypatch.setattr("simlidar_mi.io.las.write_scan_las", broken)
    out = tmp_path / "out"
    with pytest.raises(OSError, match=r"No space left on device"):  # what writing in turn raises
        survey.run_scan(load_scene(CALIB), out)
    assert not out.exists()


def _strip_seconds(m: dict) -> dict:
    return {k: v for k, v in m.items() if k != "seconds"}


@needs_fork
def test_generation_and_wood_measures_forked_give_the_same_files(tmp_path, monkeypatch):
    """A fresh CLI process generates in a child while it imports Mitsuba, and measures the wood in
    a child while it builds (survey._overlap_generation, FORK_MEASURES_MIN): forced on here."""
    cfg_path, sets = SCENES / "apple_orchard.toml", ["scan.dtheta_deg=2", "scan.dy_m=0.05"]
    pids = tmp_path / "pids.txt"
    plan, measures = survey._plan, survey.scene_measures

    def spy(fn):
        def run(*a):
            with open(pids, "a") as fh:
                fh.write(f"{fn.__name__} {os.getpid()}\n")
            return fn(*a)
        return run
    monkeypatch.setattr(survey, "_plan", spy(plan))
    monkeypatch.setattr(survey, "scene_measures", spy(measures))
    monkeypatch.setattr(survey, "_overlap_generation", lambda cfg, scheduler: True)
    monkeypatch.setattr(survey, "FORK_MEASURES_MIN", 0)
    forked = survey.run_scan(load_scene(cfg_path, sets), tmp_path / "forked")
    ran = dict(line.split() for line in pids.read_text().splitlines())
    assert set(ran) == {"_plan", "scene_measures"}
    assert all(int(pid) != os.getpid() for pid in ran.values())  # both in children
    monkeypatch.setattr("simlidar_mi._runtime.fork.use_fork", lambda parallel: False)
    in_turn = survey.run_scan(load_scene(cfg_path, sets), tmp_path / "turn")
    for k in ("exr", "png", "las"):
        assert forked.files[k].read_bytes() == in_turn.files[k].read_bytes(), k
    assert _strip_seconds(forked.measures) == _strip_seconds(in_turn.measures)
    assert forked.measures["A_PR_swept_share"] > 0 and forked.measures["V_L_m3"] > 0


@needs_fork
def test_a_generation_error_in_the_child_is_raised_here_as_itself(tmp_path, monkeypatch):
    from simlidar_mi.errors import ConfigError

    def bad(cfg):
        raise ConfigError("bad grammar", file="x.toml", key="orchard.tree.axiom", value="A[")
    monkeypatch.setattr(survey, "generate", bad)
    monkeypatch.setattr(survey, "_overlap_generation", lambda cfg, scheduler: True)
    with pytest.raises(ConfigError, match="bad grammar") as err:
        survey.run_scan(load_scene(CALIB), tmp_path / "out")
    assert err.value.key == "orchard.tree.axiom"
    assert not (tmp_path / "out").exists()


def test_generation_overlaps_only_a_fresh_local_process(monkeypatch):
    from simlidar_mi._runtime.cluster import ENV, may_use_cluster
    from simlidar_mi._runtime.mitsuba import mitsuba, variant_ready
    cfg = load_scene(CALIB)
    mitsuba(cfg["scene"]["variant"])
    assert variant_ready(cfg["scene"]["variant"])
    assert not survey._overlap_generation(cfg, None)  # Mitsuba is already here: nothing to overlap
    monkeypatch.delenv(ENV, raising=False)
    assert may_use_cluster("tcp://127.0.0.1:1") and not may_use_cluster("local")
    monkeypatch.setenv(ENV, "tcp://127.0.0.1:1")
    assert may_use_cluster(None) and not may_use_cluster("local")


def _sleep_and_tell(pid_file):
    pid_file.write_text(str(os.getpid()))
    time.sleep(60)


@needs_fork
def test_a_failed_build_ends_the_measuring_child(tmp_path, monkeypatch):
    from simlidar_mi.errors import ConfigError
    pid_file = tmp_path / "pid"
    monkeypatch.setattr(survey, "FORK_MEASURES_MIN", 0)
    monkeypatch.setattr(survey, "scene_measures", lambda cfg, geometry, patterns: _sleep_and_tell(pid_file))

    def broken(*a, **k):
        for _ in range(500):  # until the child has started
            if pid_file.exists() and pid_file.read_text():
                break
            time.sleep(0.01)
        raise ConfigError("cannot build", key="scene.representation", value="x")
    monkeypatch.setattr(survey, "build", broken)
    with pytest.raises(ConfigError, match="cannot build"):
        survey.run_scan(load_scene(CALIB), tmp_path / "out")
    pid = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):  # terminated and reaped, not left sleeping
        os.kill(pid, 0)
