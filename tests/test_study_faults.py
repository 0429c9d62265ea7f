"""The §5 study under faults: rows of another scene or code are never reused, and worker
processes do not outlive a killed study."""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar import study
from simlidar_mi.lidar.study import (_key, _legacy_key, _ranges, paper_grid, run_study, scan_overrides,
                                    scene_table)
from tests.conftest import REPO, SCENES

GRID = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01"]]


def _scene(tmp_path: Path, h0_m: str = "0.4") -> Path:
    text = (SCENES / "apple_orchard.toml").read_text().replace("h0_m = 0.4", f"h0_m = {h0_m}")
    path = tmp_path / "orchard.toml"
    path.write_text(text)
    return path


def _rows(out: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (out / "rows").glob("*.json")}


def test_key_follows_the_resolved_scene_not_how_it_was_written(tmp_path):
    base = _scene(tmp_path)
    other = tmp_path / "other.toml"
    # Another name, another comment, 0.5 written as a float in the file vs an override.
    other.write_text(base.read_text().replace('name = "apple_orchard"', 'name = "renamed"')
                     .replace("h0_m = 0.4", "h0_m = 5e-1  # longer trunk"))
    a = _key(scene_table(load_scene(base, ["orchard.tree.h0_m=0.5"])))
    assert a == _key(scene_table(load_scene(other)))
    assert a == _key(scene_table(load_scene(other, ["orchard.n_trees=4"])))  # the file's own value
    assert a != _key(scene_table(load_scene(base)))
    assert a != _key(scene_table(load_scene(other)), version="0.0.0+other")
    assert a != _key(scene_table(load_scene(other)), readings=False)
    assert _ranges([1, 2, 3, 7, 9, 10]) == "#1–3, #7, #9–10"


def test_changed_scene_file_recomputes_its_rows_and_says_why(tmp_path, caplog):
    scene, out = _scene(tmp_path), tmp_path / "study"
    first = run_study(scene, out, GRID, readings=False).rows[0]
    old_rows = _rows(out)
    _scene(tmp_path, "0.5")  # the user edits the scene file and reruns into the same folder
    with pytest.raises(ConfigError, match=r"orchard #1 of the grid was scanned from another "
                       r"scene \(orchard\.tree\.h0_m 0\.4 → 0\.5\)") as err:
        run_study(scene, out, GRID, readings=False, on_mismatch="refuse")
    assert "--on-mismatch recompute" in str(err.value) and _rows(out) == old_rows
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.lidar.study"):
        second = run_study(scene, out, GRID, readings=False).rows[0]
    assert "recomputing 1 of 1 orchards" in caplog.text and "orchard.tree.h0_m 0.4 → 0.5" in caplog.text
    # The new row is the new scene's (longer trunk elements: more wood), the old one is kept.
    assert second["scene"]["orchard.tree.h0_m"] == 0.5 and second["A_PR_m2"] > first["A_PR_m2"]
    assert second["key"] != first["key"] and len(_rows(out)) == 2
    reg = json.loads((out / "regression.json").read_text())
    assert reg["A_PR_vs_A_IM"]["slope"] == pytest.approx(second["A_PR_m2"] / second["A_IM_m2"])
    # Back to the first scene: its row is reused as it was, and nothing is said.
    _scene(tmp_path, "0.4")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.lidar.study"):
        again = run_study(scene, out, GRID, readings=False).rows[0]
    assert again == first and "recomputing" not in caplog.text
    assert _rows(out)[f"{first['key']}.json"] == old_rows[f"{first['key']}.json"]


def test_changed_code_version_recomputes_its_rows_and_says_why(tmp_path, caplog, monkeypatch):
    scene, out = _scene(tmp_path), tmp_path / "study"
    first = run_study(scene, out, GRID, readings=False).rows[0]
    assert first["code_version"] == study.code_version()
    assert json.loads((out / "regression.json").read_text())["code_version"] == study.code_version()
    monkeypatch.setattr(study, "code_version", lambda: "9.9.9+feedfacecafe mitsuba 9 drjit 9")
    with pytest.raises(ConfigError, match=r"orchard #1 of the grid was scanned from other code"):
        run_study(scene, out, GRID, readings=False, on_mismatch="refuse")
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.lidar.study"):
        second = run_study(scene, out, GRID, readings=False).rows[0]
    assert "recomputing 1 of 1" in caplog.text and "now 9.9.9+feedfacecafe" in caplog.text
    assert "another scene" not in caplog.text  # the scene did not change
    assert second["code_version"].startswith("9.9.9") and second["key"] != first["key"]
    assert second["A_IM_m2"] == first["A_IM_m2"]  # same code in truth: same numbers


def test_code_version_follows_the_source():
    v = study.code_version()
    assert v.startswith(study.__version__ + "+") and "mitsuba" in v and "drjit" in v


def test_rows_of_the_old_format_are_not_reused_and_cli_refuses_in_one_line(tmp_path, capsys):
    # A row as simlidar-mi wrote it before keys hashed the scene: keyed by overrides only.
    out = tmp_path / "study"
    entry = ["scan.dy_m=0.05", *paper_grid()[0]]
    legacy = _legacy_key(scan_overrides() + entry, True)
    (out / "rows").mkdir(parents=True)
    (out / "rows" / f"{legacy}.json").write_text(json.dumps({"key": legacy, "A_IM_m2": 1.0,
                                                             "overrides": scan_overrides() + entry}))
    rc = main(["study", str(SCENES / "apple_orchard.toml"), "--out", str(out), "--set", "scan.dy_m=0.05",
               "--on-mismatch", "refuse"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("simlidar-mi study: error: ")
    assert "orchard #1 of the grid was scanned from an earlier row format" in err
    assert not (out / "study.csv").exists()


def _children(pid: int) -> set[int]:
    """Live processes whose parent is ``pid`` (from /proc)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.add(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting for a reaper counts as ended)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _wait_for(condition, limit_s: float, step_s: float = 0.2) -> bool:
    """Poll ``condition`` until it holds or ``limit_s`` passes (a deadline, not a timing)."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(step_s)
    return condition()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkilled_study_leaves_no_worker_running_or_writing(tmp_path):
    out = tmp_path / "study"
    rows = out / "rows"
    cmd = [sys.executable, "-m", "simlidar_mi.cli", "study", str(SCENES / "apple_orchard.toml"),
           "--out", str(out), "--workers", "2", "--no-readings",
           "--set", "scan.dtheta_deg=2.0", "--set", "scan.dy_m=0.05"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    workers: set[int] = set()
    try:
        def first_row():
            workers.update(_children(proc.pid))
            return proc.poll() is not None or any(rows.glob("*.json"))
        assert _wait_for(first_row, 240), "no row within 4 minutes"
        assert proc.poll() is None, proc.stderr.read().decode()
        workers.update(_children(proc.pid))
        assert workers, "the study started no worker process"
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
        # Each worker was mid-orchard with more queued; it must end with its parent.
        gone = _wait_for(lambda: not any(_alive(p) for p in workers), 30)
        survivors = [p for p in workers if _alive(p)]
        assert gone, f"worker processes {survivors} outlived the killed study"
        before = sorted(p.name for p in rows.iterdir())
        time.sleep(2)
        assert sorted(p.name for p in rows.iterdir()) == before
    finally:
        for p in workers | {proc.pid}:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
        proc.stderr.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("platform", ["linux", "darwin"])
def test_worker_initializer_ends_the_worker_when_its_parent_dies(platform):
    # A parent starts a "worker" that runs the Dask initializer and then sleeps; killing the
    # parent must end it: by PR_SET_PDEATHSIG on Linux, by the watchdog thread elsewhere.
    worker = ("import os, sys, time\n"
              "from simlidar_mi.lidar.study import _die_with_parent\n"
              f"sys.platform = {platform!r}\n"
              "_die_with_parent(os.getppid())\n"
              "print('armed', flush=True)\n"
              "time.sleep(120)\n")
    parent = ("import subprocess, sys, time\n"
              f"p = subprocess.Popen([sys.executable, '-c', {worker!r}], stdout=subprocess.PIPE)\n"
              "assert p.stdout.readline() == b'armed\\n'\n"
              "print(p.pid, flush=True)\n"
              "time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", parent], cwd=REPO, stdout=subprocess.PIPE)
    child = None
    try:
        child = int(proc.stdout.readline())
        assert _alive(child)
        proc.kill()
        proc.wait(30)
        assert _wait_for(lambda: not _alive(child), 30), f"worker {child} outlived its parent"
    finally:
        proc.stdout.close()
        if proc.poll() is None:
            proc.kill()
        if child is not None and _alive(child):
            os.kill(child, signal.SIGKILL)
