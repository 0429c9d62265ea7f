"""Interrupts at random points of scan, truth, evaluate and study: whenever SIGINT (to the
process group, as a terminal sends it) or SIGTERM (to the process, as ``kill`` sends it)
lands, the run ends in 0, 130 or 143 with at most one line about it, no traceback, no process
left in its group, and no lock or staged file in its folder.

The points are seeded random delays counted from the moment the process handles both signals
(read from /proc, not guessed); every delay must give one of the valid outcomes, so nothing
here depends on how fast the machine is."""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simlidar_mi.io.atomic import LOCK_NAME
from tests.conftest import REPO, SCENES
from tests.test_process_faults import _group, _until

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")]
CLI = Path(sys.executable).with_name("simlidar-mi")
CYLINDER = str(SCENES / "calibration_cylinder.toml")
COMMANDS = {  # small scenes; each run takes a few seconds when not interrupted
    "scan": [CYLINDER, "--set", "scan.dtheta_deg=0.5"],
    "scan-streamed": [CYLINDER, "--set", "scan.chunk_beams=20000"],
    "truth": [CYLINDER, "--voxel", "0.05"],
    "evaluate": [CYLINDER, "--voxel", "0.1"],
    "study": [str(SCENES / "apple_orchard.toml"), "--workers", "2", "--no-readings",
              "--set", "scan.dtheta_deg=2.0", "--set", "scan.dy_m=0.05"],
}
RUNS_PER_COMMAND = 6
MAX_DELAY_S = 3.0
SEED = 20260420
WAIT_S = 120  # a run that has not ended this long after its signal hangs


def _status(pid: int) -> dict[str, str]:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return {}
    return dict(line.split(":\t", 1) for line in text.splitlines() if ":\t" in line)


SYNC_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _handles_both(pid: int) -> bool:
    caught = int(_status(pid).get("SigCgt", "0"), 16)
    return all(caught >> (s - 1) & 1 for s in SYNC_SIGNALS)


def _plan() -> list[tuple[str, int, float]]:
    rng = random.Random(SEED)
    return [(name, sig, round(rng.uniform(0.0, MAX_DELAY_S), 3))
            for name in COMMANDS for sig in [signal.SIGINT, signal.SIGTERM] * (RUNS_PER_COMMAND // 2)]


def signal_run(argv: list[str], err_path: Path, ready, send) -> int:
    """Exit status of ``argv`` run in its own process group (stderr to ``err_path``), after
    ``send(proc)`` once ``ready(proc)`` holds; asserts that it gets there and that nothing of
    its group is left running."""
    with open(err_path, "w") as err, open(os.devnull, "w") as devnull:
        proc = subprocess.Popen(argv, cwd=REPO, stdout=devnull, stderr=err, start_new_session=True)
    try:
        assert _until(lambda: ready(proc) or proc.poll() is not None, WAIT_S)
        assert proc.poll() is None, "the run ended before the moment to signal it"
        send(proc)
        rc = proc.wait(WAIT_S)
        assert _until(lambda: not _group(proc.pid), 30), f"left running: {_group(proc.pid)}"
    finally:
        for pid in _group(proc.pid):
            os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return rc


@pytest.mark.parametrize("name, sig, delay_s", _plan())
def test_an_interrupt_anywhere_ends_cleanly(tmp_path, name, sig, delay_s):
    command = name.split("-")[0]
    out = tmp_path / "out"
    err_path = tmp_path / "stderr.txt"

    def send(proc: subprocess.Popen) -> None:
        time.sleep(delay_s)  # where the signal lands: any point must end cleanly
        if proc.poll() is None:
            if sig == signal.SIGINT:
                os.killpg(proc.pid, signal.SIGINT)  # the whole group, as a terminal does
            else:
                proc.send_signal(signal.SIGTERM)
    # from its first moments on (before any work) the program handles both signals
    rc = signal_run([str(CLI), command, *COMMANDS[name], "--out", str(out)], err_path,
                    lambda proc: _handles_both(proc.pid), send)
    stderr = err_path.read_text()
    word = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}[sig]
    assert rc in (0, 130 if sig == signal.SIGINT else 143), stderr
    for bad in ("Traceback", "Exception ignored", "leaked", "Error", "error:"):
        assert bad not in stderr, stderr
    lines = stderr.splitlines()
    if rc:
        assert lines[-1] in (f"simlidar-mi {command}: {word}", f"simlidar-mi: {word}"), stderr
        assert not any(ln.startswith("simlidar-mi") for ln in lines[:-1]), stderr  # progress only
    left = [p for p in out.rglob("*") if p.name == LOCK_NAME or ".partial" in p.name] if out.exists() else []
    assert not left
