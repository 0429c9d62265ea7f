"""The command line ends without the interpreter's teardown (cli._exit_now): exit handlers
still run, everything printed arrives, the status is the command's; callers of main() get
its return value instead."""
from __future__ import annotations

import json
import subprocess
import sys

from simlidar_mi.cli import main
from tests.conftest import SCENES

AFTER_MAIN = """
import atexit, sys
atexit.register(print, "atexit ran", flush=True)
sys.argv = ["simlidar-mi", *sys.argv[1:]]
from simlidar_mi.cli import main
main()
print("not reached")
"""


def _run(*args, cwd):
    return subprocess.run([sys.executable, "-c", AFTER_MAIN, *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def test_finished_run_runs_exit_handlers_and_flushes(tmp_path):
    proc = _run("sensors", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[-1] == "atexit ran" and "not reached" not in proc.stdout
    assert len(lines) > 5 and "recalled, not checked" in proc.stdout  # the whole table came out


def test_error_status_and_message_survive(tmp_path):
    proc = _run("scan", tmp_path / "missing.toml", "--out", tmp_path / "o", cwd=tmp_path)
    assert proc.returncode == 2
    assert "simlidar-mi scan: error:" in proc.stderr and "missing.toml" in proc.stderr
    assert proc.stdout.splitlines() == ["atexit ran"]


def test_scan_files_complete_before_the_process_ends(tmp_path):
    out = tmp_path / "scan"
    proc = _run("scan", SCENES / "calibration_cylinder.toml", "--out", out, "--set", "scan.dy_m=0.01",
                cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["measures.json", "points.las", "scan.exr", "scan.png"]
    assert json.loads((out / "measures.json").read_text())["hits"]["wood"] > 0


def test_main_with_argv_returns(capsys):
    assert main(["sensors"]) == 0
    assert "recalled, not checked" in capsys.readouterr().out


def test_other_threads_finish_first(tmp_path):
    code = ("import threading, time\n"
            "threading.Thread(target=lambda: (time.sleep(0.3), print('thread done', flush=True))).start()\n"
            + AFTER_MAIN)
    proc = subprocess.run([sys.executable, "-c", code, "sensors"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-2:] == ["thread done", "atexit ran"]
