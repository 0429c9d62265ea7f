"""Ctrl-C (or SIGTERM to the process group) while ``study --workers 2`` is starting its worker
processes (spawned, importing the package): one line and 130 (143) from the study, no traceback from a half-started worker, no
"leaked semaphore" warning from multiprocessing's resource tracker, nothing left running.

Deterministic: the group's SIGINT is sent the moment a worker process exists and has its
Python signal handling up (read from /proc), i.e. while it is still importing; the same
landing gave a worker's KeyboardInterrupt traceback before the fix."""
from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest

from simlidar_mi.io.atomic import LOCK_NAME
from tests.test_process_faults import _until
from tests.test_signal_fuzz import CLI, COMMANDS, _status, signal_run

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")]


def _starting_worker(parent: int) -> int | None:
    """A spawned worker of ``parent`` whose interpreter is up (SIGINT has a disposition of
    Python's: caught, blocked or ignored), else None."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        status = _status(int(d.name))
        try:
            cmdline = (d / "cmdline").read_bytes()
        except OSError:
            continue
        if status.get("PPid") != str(parent) or b"--multiprocessing-fork" not in cmdline \
                or b"resource_tracker" in cmdline:
            continue
        bit = 1 << (signal.SIGINT - 1)
        if any(int(status.get(k, "0"), 16) & bit for k in ("SigCgt", "SigBlk", "SigIgn")):
            return int(d.name)
    return None


@pytest.mark.parametrize("sig, rc_word", [(signal.SIGINT, (130, "interrupted")),
                                         (signal.SIGTERM, (143, "terminated"))], ids=["INT", "TERM"])
def test_a_signal_to_the_group_while_workers_start_is_one_line(tmp_path, sig, rc_word):
    err_path = tmp_path / "stderr.txt"
    rc = signal_run([str(CLI), "study", *COMMANDS["study"], "--out", str(tmp_path / "out")], err_path,
                    lambda proc: _starting_worker(proc.pid) is not None,
                    lambda proc: os.killpg(proc.pid, sig))  # the group, as a terminal's Ctrl-C
    stderr = err_path.read_text()
    assert rc == rc_word[0], stderr
    for bad in ("Traceback", "KeyboardInterrupt", "leaked", "Exception"):
        assert bad not in stderr, stderr
    assert stderr.splitlines()[-1] == f"simlidar-mi study: {rc_word[1]}", stderr
    out = tmp_path / "out"
    assert not [p for p in out.rglob("*") if p.name == LOCK_NAME or ".partial" in p.name] if out.exists() else True


def _announce_and_wait(folder: str) -> int:
    """A task: write this worker's pid to ``folder``/pid, wait for a line on the FIFO ``go``."""
    (Path(folder) / "pid.tmp").write_text(str(os.getpid()))
    os.replace(Path(folder) / "pid.tmp", Path(folder) / "pid")
    with open(Path(folder) / "go") as go:
        go.readline()
    return os.getpid()


def _held_worker(tmp_path: Path, pool) -> tuple[object, int]:
    os.mkfifo(tmp_path / "go")
    future = pool.submit(_announce_and_wait, str(tmp_path))
    assert _until(lambda: (tmp_path / "pid").exists() or future.done(), 60), "the worker never ran"
    return future, int((tmp_path / "pid").read_text())


def test_a_worker_ignores_ctrl_c_and_its_parent_decides(tmp_path):
    """SIGINT to a worker alone does nothing to it (its task ends and answers); an interrupt
    of the parent inside the pool ends the worker at once, not after its task."""
    from simlidar_mi._runtime.pool import worker_pool
    with worker_pool(1) as pool:
        future, pid = _held_worker(tmp_path, pool)
        os.kill(pid, signal.SIGINT)
        with open(tmp_path / "go", "w") as go:
            go.write("go\n")
        assert future.result(60) == pid
    (tmp_path / "pid").unlink()
    (tmp_path / "go").unlink()
    with pytest.raises(KeyboardInterrupt), worker_pool(1) as pool:
        future, pid = _held_worker(tmp_path, pool)  # blocked on its FIFO: it would wait forever
        raise KeyboardInterrupt
    assert not _status(pid), "the worker outlived its pool"  # ended and reaped
