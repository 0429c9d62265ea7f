"""One call run in a forked child process while this process does other work.

Used where a command's outputs are independent once its data exist and one of them is long
(the forest's pictures, a scan's LAS file): the child sees the data as they are
(copy-on-write, nothing is pickled on the way in), and both cores work. Only on Linux with the
"fork" start method and two or more usable cores (macOS offers fork too, but its system
frameworks are not fork-safe); elsewhere, or with ``parallel=False``, the call runs here, in
turn, when its result is asked for. The child only runs numpy-level Python (no Mitsuba or
Dr.Jit calls), so the threads those libraries left idle in the parent are not needed there.

A child dies with its parent (:func:`die_with_parent`: the kernel's parent-death signal on
Linux, even when the parent is SIGKILLed), keeps neither the parent's output-folder locks nor
the read ends of its pipes (a write to a parent that is gone fails instead of blocking), and
ends quietly on SIGINT and SIGTERM: the parent, interrupted too, ends it and says so.

Blocking SIGINT and SIGTERM in the main thread does not keep them out of this process: the
kernel hands them to another thread (Dr.Jit's, Dask's), and Python runs the handler in the
main thread at its next instruction, which may be inside CPython's ``Process.start`` (after
the fork, before the child is recorded: never ended) or between the start and the mask's
restoration (the child never ended, both signals left blocked). So the start and
:meth:`Forked.close` run with interrupts deferred (:func:`.signals.interrupts_deferred`): an
interrupt is raised once the child is known (then ended) or ended; :meth:`Forked.within`
also registers the close before one can be raised.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
import warnings
from typing import Any, Callable

from ..errors import SimlidarError
from .signals import interrupts_deferred
from .threads import usable_cores


def use_fork(parallel: bool | None) -> bool:
    """Whether to fork: ``parallel`` True forces it where fork exists, False never, None
    when this process may use two or more cores."""
    if parallel is False or not sys.platform.startswith("linux") \
            or "fork" not in multiprocessing.get_all_start_methods():
        return False
    if parallel:
        return True
    return usable_cores() >= 2


#: Test hook: an inherited file descriptor; a forked child writes its pid there, then waits to
#: be killed (a test kills the parent at that moment, without guessing times).
HOLD_ENV = "SIMLIDAR_MI_TEST_FORK_HOLD_FD"
_INTERRUPTS = (signal.SIGINT, signal.SIGTERM)
CLOSE_WAIT_S = 5.0  # for a terminated child to end before it is killed
_parent_ends: set = set()  # this process's read ends of its children's pipes


def die_with_parent(parent_pid: int) -> None:
    """End this (forked or spawned) process as soon as ``parent_pid``, its parent, dies, even
    by SIGKILL, so that no orphan keeps working, writing or holding files.  Linux: the kernel
    sends SIGKILL at the parent's death (``PR_SET_PDEATHSIG``); elsewhere a thread watches the
    parent pid."""
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes  # noqa: PLC0415
        try:
            armed = ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before we armed
        os._exit(1)
    if not armed:
        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)
        threading.Thread(target=watch, name="simlidar-parent-watch", daemon=True).start()


def _drop_inherited() -> None:
    """In a forked child: close what belongs to the parent alone, its output-folder locks
    (simlidar_mi.io.atomic) and its pipes' read ends (its other children's included)."""
    atomic = sys.modules.get("simlidar_mi.io.atomic")
    if atomic is not None:
        atomic.forget_claims_after_fork()
    for end in list(_parent_ends):
        end.close()
    _parent_ends.clear()


def _hold_for_test() -> None:
    fd = int(os.environ[HOLD_ENV])
    os.write(fd, f"{os.getpid()}\n".encode())
    os.close(fd)
    while True:
        signal.pause()


def _child(conn, parent_pid: int, fn: Callable, args: tuple, setup: Callable | None) -> None:
    """The forked process: run, then send ("ok", value), ("error", (exception, text)) or
    ("interrupted", None).  Starts with SIGINT and SIGTERM blocked (see :class:`Forked`)."""
    try:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # Forked.close's terminate() ends it at once
        signal.signal(signal.SIGINT, signal.default_int_handler)
        die_with_parent(parent_pid)
        _drop_inherited()
        try:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, _INTERRUPTS)
            if os.environ.get(HOLD_ENV):
                _hold_for_test()
            with setup() if setup is not None else contextlib.nullcontext():
                msg = ("ok", fn(*args))
        except KeyboardInterrupt:  # Ctrl-C: the parent got it too (then nobody listens), or
            msg = ("interrupted", None)  # a SIGINT sent to this child alone: the parent's to raise
        except BaseException as exc:  # noqa: BLE001  (everything else goes back to the parent)
            text = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
            msg = ("error", (exc, text))
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the answer goes out whole, or not at all
        try:
            try:  # an exception itself, so the parent raises what an in-turn call raises
                conn.send(msg)
            except OSError:
                raise
            except Exception:  # noqa: BLE001  (not picklable: its text only)
                conn.send(("error", (None, msg[1][1])))
        except OSError:  # the parent stopped listening (it failed or was interrupted first)
            pass
        conn.close()
    except BaseException:  # noqa: BLE001  (a second Ctrl-C: the parent reports, not this child)
        pass
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)  # no exit handlers: they are the parent's (its atexit, Dask, temp folders)


class Forked:
    """``fn(*args)`` in a forked child started now (see :func:`use_fork`), else here at
    :meth:`wait`.

    :meth:`wait` returns its value (pickled back). If the call raised, :meth:`wait` raises the
    same exception (KeyboardInterrupt when the child alone was interrupted), as a call in turn would (with a note naming ``what`` and the child's
    traceback on Python ≥ 3.11); if that exception cannot be sent back, or the child died, a
    :class:`SimlidarError` naming ``what``. :meth:`close` ends a child still running (the
    caller failed or was interrupted) and must always follow (:meth:`within` registers it at
    the start). ``setup``: a context-manager
    factory entered around the call in the child only."""

    def __init__(self, what: str, fn: Callable, *args: Any, parallel: bool | None = None,
                 setup: Callable | None = None) -> None:
        self.what, self.fn, self.args = what, fn, args
        self.child = self.recv = None
        if use_fork(parallel):
            for stream in (sys.stdout, sys.stderr):  # nothing buffered is written twice
                stream.flush()
            try:
                with interrupts_deferred():  # raised here once the child is known (see the module)
                    self._start(setup)
            except BaseException:  # the fork failed, or the interrupt that waited: end the child
                self.close()
                raise

    @classmethod
    def within(cls, ends: contextlib.ExitStack, what: str, fn: Callable, *args: Any, **kw: Any) -> Forked:
        """A :class:`Forked` whose :meth:`close` is on ``ends`` before an interrupt can come
        between them (one after the constructor's return left the child running)."""
        with interrupts_deferred():
            job = cls(what, fn, *args, **kw)
            ends.callback(job.close)
        return job

    def _start(self, setup: Callable | None) -> None:
        ctx = multiprocessing.get_context("fork")
        self.recv, send = ctx.Pipe(duplex=False)
        try:
            _parent_ends.add(self.recv)  # the child closes its copy of this end too
            self.child = ctx.Process(target=_child, args=(send, os.getpid(), self.fn, self.args, setup),
                                     daemon=True)
            # The child starts with both blocked, until it has set its own handlers.
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _INTERRUPTS)
            try:
                with warnings.catch_warnings():
                    # Python ≥ 3.12 warns on every fork of a process with threads; ours are Dr.Jit's
                    # and OpenBLAS's idle workers, and the child calls neither Dr.Jit nor Mitsuba.
                    warnings.filterwarnings("ignore", r".*multi-threaded, use of fork\(\) may lead to deadlocks",
                                            DeprecationWarning)
                    self.child.start()
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        finally:
            send.close()

    def wait(self) -> Any:
        if self.child is None:
            return self.fn(*self.args)
        try:
            status, value = self.recv.recv()
        except EOFError:  # died without a word (killed, out of memory)
            self.child.join()
            raise SimlidarError(f"the process {self.what} died (exit code {self.child.exitcode})") from None
        except Exception as exc:  # noqa: BLE001  (an exception that pickles but does not unpickle)
            self.child.join()
            raise SimlidarError(f"{self.what} failed in a forked process, and its error could not be "
                                f"read back: {type(exc).__name__}: {exc}") from None
        self.child.join()
        if status == "ok":
            return value
        if status == "interrupted":  # the call was interrupted: so is the caller, as in turn
            raise KeyboardInterrupt
        exc, text = value
        if exc is None:
            raise SimlidarError(f"{self.what} failed: {text}")
        if hasattr(exc, "add_note"):
            exc.add_note(f"({self.what} failed in a forked process; its traceback:)\n{text}")
        raise exc

    def close(self) -> None:
        with interrupts_deferred():  # a (second) interrupt here is raised once the child is ended
            if self.recv is not None:
                _parent_ends.discard(self.recv)
                self.recv.close()
            child = self.child
            if child is None or getattr(child, "_popen", None) is None:  # never forked
                return
            if child.is_alive():
                child.terminate()
            child.join(CLOSE_WAIT_S)
            if child.exitcode is None:  # SIGTERM blocked or ignored by what the call runs
                child.kill()
                child.join()
