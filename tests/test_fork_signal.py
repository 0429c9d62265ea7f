"""An interrupt (Ctrl-C, or SIGTERM as the command line raises it) landing at each step of a
forked call's life (simlidar_mi._runtime.fork.Forked): its pipe, the fork, CPython's record
of the child, the result's reading, its end. The signal's handler runs in the main thread at
its next instruction wherever that is (another thread of the process took the signal), so
each landing is made exact with a profile hook calling ``_thread.interrupt_main`` (no sleeps).

Each landing must leave no child running or unreaped, no pipe read end kept for later
children, SIGINT and SIGTERM unblocked in the main thread, and nothing printed."""
from __future__ import annotations

import _thread
import contextlib
import os
import signal
import sys
import time

import pytest

from simlidar_mi._runtime import fork
from simlidar_mi._runtime.fork import Forked, use_fork
from simlidar_mi._runtime.signals import Terminated, _raise_interrupt
from tests.test_signal_fuzz import _status

pytestmark = pytest.mark.skipif(not use_fork(True) or not sys.platform.startswith("linux"),
                                reason="fork start method and /proc")
_SIGNALS = {"INT": signal.SIGINT, "TERM": signal.SIGTERM}


def _hold():
    time.sleep(600)  # ended by Forked.close, or left running: what the test looks for


def _in(frame, *names) -> bool:
    """``frame`` runs inside a method of fork.py named in ``names`` (at any depth)."""
    f = frame.f_back
    while f is not None:
        if f.f_code.co_filename == fork.__file__ and f.f_code.co_name in names:
            return True
        f = f.f_back
    return False


def _landings() -> dict[str, tuple[str, object]]:
    """(profile event, test on the frame) of each landing, inside CPython's code called by
    Forked: where a real signal's handler may run."""
    import multiprocessing.connection as mpc
    import multiprocessing.popen_fork as pf
    import multiprocessing.process as mpp
    start = ("__init__", "_start", "within")

    def at(code, *names):
        return lambda f: f.f_code is code and _in(f, *names)
    return {
        "the pipe made": ("return", at(mpc.Pipe.__code__, *start)),
        "the child forked, CPython's Popen not made": ("return", at(pf.Popen._launch.__code__, *start)),
        "the child forked, not yet recorded": ("return", at(pf.Popen.__init__.__code__, *start)),
        "the child recorded, start() returning": ("return", at(mpp.BaseProcess.start.__code__, *start)),
        "the child's end of the pipe closing": ("call", at(mpc._ConnectionBase.close.__code__, *start)),
        "the result being read": ("call", at(mpc._ConnectionBase.recv.__code__, "wait")),
        "the read end closing": ("call", at(mpc._ConnectionBase.close.__code__, "close")),
        "the child being terminated": ("call", at(mpp.BaseProcess.terminate.__code__, "close")),
        "the child being joined": ("call", at(mpp.BaseProcess.join.__code__, "close")),
    }


@contextlib.contextmanager
def _landing(event, where, sig):
    """Interrupt the main thread once, at the first profile event matching; yield the pids of
    the children forked meanwhile and whether it landed; end any child left."""
    import multiprocessing.popen_fork as pf
    parent, pids, landed = os.getpid(), [], []

    def profile(frame, ev, arg):
        if os.getpid() != parent:  # a forked child inherits the hook
            return
        if ev == "return" and frame.f_code is pf.Popen._launch.__code__:
            pids.append(frame.f_locals["self"].pid)
        if not landed and ev == event and where(frame):
            landed.append(True)
            _thread.interrupt_main(sig)  # the handler runs at the next instruction checked
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)  # as the command line's
    sys.setprofile(profile)
    try:
        yield pids, landed
    finally:
        sys.setprofile(None)
        signal.signal(signal.SIGTERM, previous)
        for pid in pids:
            if _status(pid):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)


def _left(pids, err) -> dict:
    held = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    return {"children left": [(p, _status(p).get("State")) for p in pids if _status(p)],  # running, or a zombie never joined
            "signals held": sorted(s.name for s in held if s in _SIGNALS.values()),
            "read ends kept": len(fork._parent_ends),
            "stderr": [bad for bad in ("Traceback", "Error", "Exception", "Interrupt") if bad in err]}


CLEAN = {"children left": [], "signals held": [], "read ends kept": 0, "stderr": []}


@pytest.mark.parametrize("sig", list(_SIGNALS))
@pytest.mark.parametrize("landing", list(_landings()))
def test_an_interrupt_at_each_step_of_a_forked_call_ends_its_child(landing, sig, capfd):
    """The caller closes the job in a ``finally`` (as every caller does); the interrupt comes
    out (Terminated for SIGTERM) with the traceback still alive, as when the command reports
    and leaves by ``os._exit``."""
    event, where = _landings()[landing]
    with _landing(event, where, _SIGNALS[sig]) as (pids, landed):
        with pytest.raises(KeyboardInterrupt) as caught:
            job = Forked("holding", _hold, parallel=True)
            try:
                if landing == "the result being read":
                    job.wait()  # the child holds: only the interrupt ends the wait
                raise RuntimeError("the caller failed")  # then close() ends the child
            finally:
                job.close()
        sys.setprofile(None)
        assert landed and (pids or landing == "the pipe made") and isinstance(caught.value, Terminated) == (sig == "TERM")
        assert _left(pids, capfd.readouterr().err) == CLEAN


@pytest.mark.parametrize("sig", list(_SIGNALS))
@pytest.mark.parametrize("landing", ["the constructor returning", "its close being registered"])
def test_an_interrupt_between_the_start_and_the_close_s_registration_ends_the_child(landing, sig, capfd):
    """The window after ``Forked(...)`` returns and before the caller has put its close on an
    ExitStack (or a ``closing``): :meth:`Forked.within` holds the interrupt across both."""
    where = (("return", lambda f: f.f_code is Forked.__init__.__code__) if landing == "the constructor returning"
             else ("call", lambda f: f.f_code is contextlib.ExitStack.callback.__code__))
    with _landing(*where, _SIGNALS[sig]) as (pids, landed):
        with pytest.raises(KeyboardInterrupt) as caught, contextlib.ExitStack() as ends:
            Forked.within(ends, "holding", _hold, parallel=True)
            raise RuntimeError("not interrupted")
        sys.setprofile(None)
        assert landed and pids and isinstance(caught.value, Terminated) == (sig == "TERM")
        assert _left(pids, capfd.readouterr().err) == CLEAN


def _hold_any(*args, **kwargs):
    _hold()


CALLERS = ["forest pictures", "scan generation", "scan wood measures", "scan LAS"]


@pytest.mark.parametrize("caller", CALLERS)
def test_an_interrupt_as_a_caller_s_child_starts_ends_it_and_leaves_no_output(caller, tmp_path, monkeypatch, capfd):
    """Each caller of Forked, interrupted the instruction after the constructor returns (the
    child held): KeyboardInterrupt out of the command, the child ended, nothing in ``out``."""
    from simlidar_mi.config import load_scene
    from simlidar_mi.forest import run as forest_run
    from simlidar_mi.lidar import survey
    from tests.conftest import SCENES
    init, pids = Forked.__init__, []

    def interrupted_on_return(self, *a, **k):
        init(self, *a, **k)
        pids.append(self.child.pid)
        if len(pids) == 1:
            _thread.interrupt_main()  # raised at the caller's next instruction
    monkeypatch.setattr(Forked, "__init__", interrupted_on_return)
    monkeypatch.setattr("simlidar_mi._runtime.fork.use_fork", lambda parallel: True)
    out = tmp_path / "out"
    if caller == "forest pictures":
        monkeypatch.setattr(forest_run, "_draw_pictures", _hold_any)
        command = lambda: forest_run.run_forest(SCENES / "forest_small.toml", out)  # noqa: E731
    else:
        fn = {"scan generation": "_plan", "scan wood measures": "scene_measures"}.get(caller)
        if fn is not None:
            monkeypatch.setattr(survey, fn, _hold_any)
        else:
            monkeypatch.setattr("simlidar_mi.io.las.write_scan_las", _hold_any)
        monkeypatch.setattr(survey, "_overlap_generation", lambda cfg, scheduler: caller == "scan generation")
        monkeypatch.setattr(survey, "FORK_MEASURES_MIN", 0 if caller == "scan wood measures" else 10**9)
        command = lambda: survey.run_scan(load_scene(SCENES / "calibration_cylinder.toml"), out)  # noqa: E731
    try:
        with pytest.raises(KeyboardInterrupt):
            command()
        assert len(pids) == 1
        assert _left(pids, capfd.readouterr().err) == CLEAN
        assert not out.exists() or not list(out.iterdir())
    finally:
        for pid in pids:
            if _status(pid):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
