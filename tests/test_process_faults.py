"""Forked helpers die with their parent and hold no lock; SIGTERM is Ctrl-C's twin; an
interrupt inside a NetCDF write or the fork window still ends in one line; a study's final
files are replaced as one set."""
from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from simlidar_mi._runtime.fork import HOLD_ENV, use_fork
from simlidar_mi.cli import main
from simlidar_mi.io.atomic import LOCK_NAME
from tests.conftest import REPO, SCENES

CYLINDER = str(SCENES / "calibration_cylinder.toml")
CLI = Path(sys.executable).with_name("simlidar-mi")
needs_fork = pytest.mark.skipif(not use_fork(True), reason="no fork start method here")
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pidfd, /proc")


def _gone_within(pid: int, timeout_s: float) -> bool:
    """Whether ``pid`` ends within ``timeout_s`` (a pidfd becomes readable when it does)."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], timeout_s)[0])
    finally:
        os.close(fd)


def _visible(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# --- forked helpers: die with the parent, hold no lock --------------------------------------


def _held_child(out: Path, *extra: str, sig: int = signal.SIGKILL) -> tuple[subprocess.CompletedProcess, int]:
    """Start a scan whose forked child (the scene's generation, overlapped with Mitsuba's
    import) writes its pid to a pipe and waits; send ``sig`` to the scan then."""
    r, w = os.pipe()
    env = {**os.environ, HOLD_ENV: str(w)}
    proc = subprocess.Popen([str(CLI), "scan", CYLINDER, "--out", str(out), *extra], env=env,
                            pass_fds=(w,), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=REPO)
    os.close(w)
    with os.fdopen(r) as pipe:
        line = pipe.readline()  # the child is waiting now (or the scan ended without forking)
    assert line, proc.communicate(timeout=60)
    child = int(line)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), child


@needs_fork
@linux
def test_sigkilled_scan_leaves_no_child_and_the_folder_free(tmp_path):
    out = tmp_path / "o"
    done, child = _held_child(out)
    assert done.returncode == -signal.SIGKILL
    alive = not _gone_within(child, 60)
    if alive:
        os.kill(child, signal.SIGKILL)
    assert not alive, "the forked child outlived its SIGKILLed parent"
    rerun = subprocess.run([str(CLI), "scan", CYLINDER, "--out", str(out)], capture_output=True,
                           text=True, timeout=300, cwd=REPO)
    assert rerun.returncode == 0, rerun.stderr
    assert "in use" not in rerun.stderr and "took over" not in rerun.stderr
    assert _visible(out) == ["measures.json", "points.las", "scan.exr", "scan.png"]


@needs_fork
@linux
@pytest.mark.parametrize("sig, rc, word", [(signal.SIGTERM, 143, "terminated"),
                                           (signal.SIGINT, 130, "interrupted")])
def test_signalled_scan_ends_its_child_and_says_one_line(tmp_path, sig, rc, word):
    out = tmp_path / "o"
    done, child = _held_child(out, sig=sig)
    assert (done.returncode, done.stderr.splitlines()[-1:]) == (rc, [f"simlidar-mi scan: {word}"])
    assert "Traceback" not in done.stderr and done.stdout == ""
    assert _gone_within(child, 60)
    assert not out.exists()  # a first run: no folder, no lock, no staging folder left


_ORPHAN = textwrap.dedent("""
    import fcntl, json, os, socket, sys
    fd = os.open(os.path.join(sys.argv[1], %r), os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, json.dumps({"pid": int(sys.argv[2]), "host": socket.gethostname(),
                             "command": "simlidar-mi scan", "started": "earlier"}).encode())
    print("ready", flush=True)
    sys.stdin.readline()
""" % LOCK_NAME)


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait(timeout=60)
    return p.pid


def test_a_lock_naming_a_dead_process_is_taken_over_with_one_warning(tmp_path, capsys):
    """An orphan that inherited a run's lock (as forked helpers once did) still holds it; the
    process the lock names is gone: the next run takes the folder over and says so."""
    out = tmp_path / "o"
    out.mkdir()
    dead = _dead_pid()
    orphan = subprocess.Popen([sys.executable, "-c", _ORPHAN, str(out), str(dead)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert orphan.stdout.readline().strip() == "ready"
        assert main(["scan", CYLINDER, "--out", str(out), "--no-las", "--no-png"]) == 0
        err = [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("scan: ")]
        assert len(err) == 1 and "took over the lock of output folder" in err[0]
        assert f"names, {dead}, is gone" in err[0]
        assert _visible(out) == ["measures.json", "scan.exr"]
    finally:
        orphan.communicate("\n", timeout=60)


def test_a_lock_naming_a_live_process_is_still_refused(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", _ORPHAN, str(out), str(os.getpid())],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        assert main(["scan", CYLINDER, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"in use by process {os.getpid()} on {socket.gethostname()}" in err
        assert json.loads((out / LOCK_NAME).read_text())["pid"] == os.getpid()
    finally:
        holder.communicate("\n", timeout=60)


# --- interrupts inside libraries: held back, or still taken for interrupts ----------------

# Patches a method of a class when its module is first imported, so that the method sends
# SIGNAL to the process itself at its start and, if the method returned, writes MARKER: the
# interrupt lands inside xarray's to_netcdf, or inside Mitsuba's call of a plugin constructor.
_SITECUSTOMIZE = textwrap.dedent("""
    import importlib.machinery, os, signal, sys
    _module, _qualname = os.environ["SIMLIDAR_TEST_PATCH"].split(":")
    _cls_name, _method = _qualname.split(".")

    def _patch(module):
        cls = getattr(module, _cls_name)
        original = getattr(cls, _method)

        def interrupted(*args, **kwargs):
            if os.environ.pop("SIMLIDAR_TEST_SIGNAL_ONCE", None):
                os.kill(os.getpid(), getattr(signal, os.environ["SIMLIDAR_TEST_SIGNAL"]))
                result = original(*args, **kwargs)
                with open(os.environ["SIMLIDAR_TEST_MARKER"], "w") as fh:
                    fh.write("returned")
                return result
            return original(*args, **kwargs)
        setattr(cls, _method, interrupted)

    class _Finder:
        def find_spec(self, name, path=None, target=None):
            if name != _module:
                return None
            sys.meta_path.remove(self)
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                _patch(module)
            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, _Finder())
""")


def _patched_run(tmp_path: Path, argv: list[str], patch: str, sig: str) -> subprocess.CompletedProcess:
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(_SITECUSTOMIZE)
    env = {**os.environ, "PYTHONPATH": str(site), "SIMLIDAR_TEST_PATCH": patch,
           "SIMLIDAR_TEST_SIGNAL": sig, "SIMLIDAR_TEST_SIGNAL_ONCE": "1",
           "SIMLIDAR_TEST_MARKER": str(tmp_path / "returned")}
    return subprocess.run([str(CLI), *argv], env=env, capture_output=True, text=True, timeout=300,
                          cwd=REPO)


def _one_line_end(proc: subprocess.CompletedProcess, command: str, rc: int, word: str) -> None:
    lines = proc.stderr.splitlines()
    assert (proc.returncode, lines[-1:]) == (rc, [f"simlidar-mi {command}: {word}"]), proc.stderr
    assert all(ln.startswith(f"{command}: ") for ln in lines[:-1]), proc.stderr  # piped progress


@pytest.mark.parametrize("sig, rc, word", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_an_interrupt_inside_the_netcdf_write_waits_for_its_end(tmp_path, sig, rc, word):
    """Raised inside xarray's to_netcdf an interrupt deadlocked it: it is held until the write
    returns, then ends the run with one line; the earlier truth stays as it was."""
    out = tmp_path / "t"
    assert main(["truth", CYLINDER, "--out", str(out), "--voxel", "0.1"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = _patched_run(tmp_path, ["truth", CYLINDER, "--out", str(out), "--voxel", "0.05"],
                        "xarray:Dataset.to_netcdf", sig)
    _one_line_end(proc, "truth", rc, word)
    assert (tmp_path / "returned").read_text() == "returned"  # the write was not cut short
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no lock, no .partial


@pytest.mark.parametrize("sig, rc, word", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_an_interrupt_inside_a_plugin_constructor_is_still_an_interrupt(tmp_path, sig, rc, word):
    """Mitsuba turns a KeyboardInterrupt raised in a Python plugin's constructor into its own
    "failed to instantiate plugin" error (exit 1 with a traceback): still exit 130 or 143."""
    out = tmp_path / "o"
    proc = _patched_run(tmp_path, ["scan", CYLINDER, "--out", str(out)],
                        "simlidar_mi.plugins.tractor_lidar:TractorLidar.__init__", sig)
    _one_line_end(proc, "scan", rc, word)
    assert not (tmp_path / "returned").exists() and not out.exists()


@needs_fork
@linux
def test_ctrl_c_to_the_process_group_in_the_fork_window_is_one_line(tmp_path):
    """As a terminal does: SIGINT to the scan and its forked child together, while the child
    generates the scene."""
    r, w = os.pipe()
    out = tmp_path / "o"
    proc = subprocess.Popen([str(CLI), "scan", CYLINDER, "--out", str(out)], env={**os.environ, HOLD_ENV: str(w)},
                            pass_fds=(w,), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO, start_new_session=True)
    os.close(w)
    with os.fdopen(r) as pipe:
        child = int(pipe.readline())
    os.killpg(proc.pid, signal.SIGINT)
    done = subprocess.CompletedProcess(proc.args, proc.wait(timeout=120), *proc.communicate(timeout=60))
    _one_line_end(done, "scan", 130, "interrupted")
    assert "Traceback" not in done.stderr and _gone_within(child, 60) and not out.exists()


# --- a study's final files: replaced as one set ---------------------------------------------

STUDY_GRID = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=2.0", "scan.dy_m=0.05"]]


def test_a_study_interrupted_in_its_final_writes_keeps_the_earlier_set(tmp_path, monkeypatch):
    from simlidar_mi.lidar import study
    out = tmp_path / "study"
    first = study.run_study(SCENES / "apple_orchard.toml", out, STUDY_GRID, readings=False)
    final = {p.name: (p.stat().st_ino, p.read_bytes()) for p in first.files.values()}
    assert sorted(final) == ["correlations.png", "regression.json", "study.csv"]

    def interrupted(rows, regression, path):  # Ctrl-C while the picture, the last file, is drawn
        Path(path).write_bytes(b"half a picture")
        raise KeyboardInterrupt
    monkeypatch.setattr(study, "_plot", interrupted)
    with pytest.raises(KeyboardInterrupt):
        study.run_study(SCENES / "apple_orchard.toml", out, STUDY_GRID, readings=False)
    # the same files, not rewritten (inode and bytes): study.csv and regression.json of the new
    # run never sit beside the old picture
    assert {n: (p.stat().st_ino, p.read_bytes()) for n in final if (p := out / n)} == final
    assert sorted(p.name for p in out.iterdir()) == ["correlations.png", "regression.json", "rows",
                                                     "study.csv"]


def _group(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``."""
    found = []
    for d in Path("/proc").iterdir():
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split() if d.name.isdigit() else None
        except OSError:
            continue
        if fields and fields[0] != "Z" and int(fields[2]) == pgid:
            found.append(int(d.name))
    return found


def _until(condition, timeout_s: float) -> bool:
    """Whether ``condition()`` holds within ``timeout_s`` (checked every 20 ms)."""
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


@linux
def test_sigterm_to_a_study_with_workers_is_one_line_and_leaks_nothing(tmp_path):
    """SIGTERM once the first row is written (the two workers are scanning): exit 143, one
    line, no "leaked semaphore" warning from multiprocessing, no worker left."""
    out = tmp_path / "study"
    proc = subprocess.Popen([str(CLI), "study", str(SCENES / "apple_orchard.toml"), "--out", str(out),
                             "--workers", "2", "--no-readings", "--set", "scan.dtheta_deg=2.0",
                             "--set", "scan.dy_m=0.05"], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert _until(lambda: proc.poll() is not None or any((out / "rows").glob("*.json")), 240)
        assert proc.poll() is None, "the study ended before its first row"
        proc.send_signal(signal.SIGTERM)
        stderr = proc.communicate(timeout=120)[1]
        # its workers and multiprocessing's resource tracker end with it
        assert _until(lambda: not _group(proc.pid), 30), f"left running: {_group(proc.pid)}"
    finally:
        for pid in _group(proc.pid):
            os.kill(pid, signal.SIGKILL)
    lines = stderr.splitlines()
    assert (proc.returncode, lines[-1]) == (143, "simlidar-mi study: terminated"), stderr
    assert "leaked" not in stderr and "Traceback" not in stderr
    assert not any(ln.startswith("simlidar-mi") for ln in lines[:-1]), stderr
    assert not (out / LOCK_NAME).exists() and not list(out.glob(".partial*"))


_SWALLOWED = """
import signal, sys, weakref
from simlidar_mi._runtime.signals import exit_on_interrupt, raise_on_interrupt
exit_on_interrupt(); raise_on_interrupt()  # as the command line sets them
class Thing: pass
thing = Thing()
def callback(_):  # as importlib's module-lock clean-up: Python cannot raise out of it
    signal.raise_signal(getattr(signal, sys.argv[1]))
    x = 1  # the handler runs here, inside the callback
ref = weakref.ref(thing, callback)
try:
    del thing
    for _ in range(10**9):  # ~30 s: the resent signal ends it long before
        pass
    print("not interrupted")
except KeyboardInterrupt as exc:
    print(type(exc).__name__)
"""


@pytest.mark.parametrize("sig, name", [("SIGINT", "KeyboardInterrupt"), ("SIGTERM", "Terminated")])
def test_an_interrupt_swallowed_by_a_weakref_callback_is_sent_again(sig, name):
    """Landing in a weakref callback (importlib's module locks, in the signal fuzz), the
    interrupt was printed as "Exception ignored ... Traceback" and lost; the run went on.
    It is now sent again once the callback is over, and unwinds the code that follows."""
    proc = subprocess.run([sys.executable, "-c", _SWALLOWED, sig], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert (proc.stdout, proc.stderr) == (f"{name}\n", "")
