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


def _landings() -> dict[str, tuple[str, object]]:
    """Where in CPython's pool an interrupt lands: (profile event, test on the frame). Each is
    a point where the study's SIGINT/SIGTERM landed in a loop of the group test above (read
    from the interrupt's traceback) and gave a worker's traceback or leaked semaphores."""
    import concurrent.futures.process as cfp
    import multiprocessing.popen_spawn_posix as psp
    import multiprocessing.resource_tracker as rt
    import multiprocessing.util as mpu
    import threading

    def at(code, caller=None, cls=object):
        return lambda f: (code is None or f.f_code is code) and (caller is None or (
            f.f_back is not None and f.f_back.f_code is caller
            and isinstance(f.f_back.f_locals.get("self"), cls)))
    return {  # the worker read no start-up data: "EOFError: Ran out of input"
        "worker spawned, its data not yet written": ("return", at(mpu.spawnv_passfds.__code__,
                                                                   psp.Popen._launch.__code__)),
        # not in the pool's table, so never ended; it opened semaphores the parent had unlinked
        "worker started, not yet in the pool": ("return", at(None, cfp.ProcessPoolExecutor._spawn_process.__code__)),
        # the manager thread not yet the pool's: never joined, and its queues never released
        "manager thread starting": ("call", at(threading.Event.wait.__code__, threading.Thread.start.__code__,
                                               cfp._ExecutorManagerThread)),
        "the pool's queues being made": ("return", at(rt.ResourceTracker.register.__code__)),
        "the pool shutting down": ("call", at(threading.Thread.join.__code__,
                                              cfp.ProcessPoolExecutor.shutdown.__code__)),
    }


@pytest.mark.parametrize("landing", list(_landings()))
def test_an_interrupt_inside_the_pool_leaves_no_semaphore_process_or_traceback(landing, capfd):
    """Ctrl-C landing at each point of the pool's start and end (the signal's handler runs in
    the main thread at its next instruction, as when another thread of the process took the
    signal): KeyboardInterrupt out of the pool, every semaphore it made unlinked and every
    worker it spawned ended, while the interrupt's traceback (its frames) is still alive, as
    when the program reports and leaves by ``os._exit``; no worker prints anything."""
    import _thread

    from simlidar_mi._runtime.pool import worker_pool
    event, where = _landings()[landing]
    sems: list[str] = []
    pids: list[int] = []
    landed: list[bool] = []

    def profile(frame, ev, arg):
        if ev == "call" and frame.f_code.co_name == "register" and frame.f_locals.get("rtype") == "semaphore":
            sems.append(frame.f_locals["name"])
        if ev == "return" and frame.f_code.co_name == "spawnv_passfds" \
                and frame.f_back.f_code.co_name == "_launch":  # a worker, not the resource tracker
            pids.append(arg)
        if not landed and ev == event and where(frame):
            landed.append(True)
            _thread.interrupt_main()  # the handler runs at the next instruction checked

    sys.setprofile(profile)
    try:
        with pytest.raises(KeyboardInterrupt) as caught, worker_pool(2) as pool:
            for _ in range(2):
                pool.submit(os.getpid)
            assert pool.submit(os.getpid).result(60) > 0
        sys.setprofile(None)
        assert landed and sems and caught.value is not None
        err = capfd.readouterr().err
        found = {"semaphores left": [s for s in sems if Path(f"/dev/shm/sem.{s.lstrip('/')}").exists()],
                 "workers left": [p for p in pids if _status(p)],
                 "stderr": [bad for bad in ("Traceback", "Error", "Exception", "leaked") if bad in err]}
        assert found == {"semaphores left": [], "workers left": [], "stderr": []}, err
    finally:
        sys.setprofile(None)
        for pid in pids:
            if _status(pid):
                os.kill(pid, signal.SIGKILL)
