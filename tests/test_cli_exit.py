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
    """A non-daemon thread still running when the command ends is waited for before the exit
    handlers run. The thread is released only once the command has finished (from inside
    ``_exit_now``), so the order is forced by an event, not by a sleep."""
    code = ("import threading\n"
            "import simlidar_mi.cli as cli\n"
            "done = threading.Event()\n"
            "threading.Thread(target=lambda: (done.wait(), print('thread done', flush=True))).start()\n"
            "_exit_now = cli._exit_now\n"
            "cli._exit_now = lambda rc: (done.set(), _exit_now(rc))\n"
            + AFTER_MAIN)
    proc = subprocess.run([sys.executable, "-c", code, "sensors"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-2:] == ["thread done", "atexit ran"]
    assert "recalled, not checked" in proc.stdout  # the command's own output came first


def test_the_command_runs_with_one_openblas_thread_unless_the_user_chose():
    """The program (``main()`` with its own command line) sets OPENBLAS_NUM_THREADS=1 before numpy
    loads OpenBLAS (its idle workers spin ~0.1 s of CPU each at start-up); a user's value stays,
    and importing the package or its command-line module as a library changes nothing."""
    import os
    import subprocess
    import sys
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    lib = subprocess.run([sys.executable, "-c", "import os, sys, signal, simlidar_mi, simlidar_mi.cli; "
                          "print(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules, "
                          "signal.getsignal(signal.SIGINT) is signal.default_int_handler)"],
                         capture_output=True, text=True, env=env, check=True)
    assert lib.stdout.split() == ["None", "False", "True"]  # no thread pool, no numpy, no handler
    # the program: `sensors` lists presets (loads numpy); a hook at exit reports what OpenBLAS got
    probe = ("import atexit, os, sys; from threadpoolctl import threadpool_info; "
             "atexit.register(lambda: print('BLAS', os.environ['OPENBLAS_NUM_THREADS'], "
             "[i['num_threads'] for i in threadpool_info() if i['internal_api'] == 'openblas'], "
             "file=sys.stderr)); from simlidar_mi.cli import main; "
             "sys.argv = ['simlidar-mi', 'sensors']; main()")
    for given, want in ((None, "1"), ("3", "3")):
        e = dict(env) if given is None else dict(env, OPENBLAS_NUM_THREADS=given)
        out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=e)
        line = [x for x in out.stderr.splitlines() if x.startswith("BLAS")]
        assert line, out.stderr
        assert line[0].split(maxsplit=2)[1] == want
        if given is None:
            assert line[0].split(maxsplit=2)[2] in ("[1]", "[]")