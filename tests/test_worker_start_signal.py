"""Ctrl-C while ``study --workers 2`` is starting its worker processes (spawned, importing the
package): one line and 130 from the study, no traceback from a half-started worker, no
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


def test_ctrl_c_while_workers_start_is_one_line(tmp_path):
    err_path = tmp_path / "stderr.txt"
    rc = signal_run([str(CLI), "study", *COMMANDS["study"], "--out", str(tmp_path / "out")], err_path,
                    lambda proc: _starting_worker(proc.pid) is not None,
                    lambda proc: os.killpg(proc.pid, signal.SIGINT))  # the group, as a terminal does
    stderr = err_path.read_text()
    assert rc == 130, stderr
    for bad in ("Traceback", "KeyboardInterrupt", "leaked", "Exception"):
        assert bad not in stderr, stderr
    assert stderr.splitlines()[-1] == "simlidar-mi study: interrupted", stderr
    out = tmp_path / "out"
    assert not [p for p in out.rglob("*") if p.name == LOCK_NAME or ".partial" in p.name] if out.exists() else True
