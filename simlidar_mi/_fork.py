"""One call run in a forked child process while this process does other work.

Used where a command's outputs are independent once its data exist and one of them is long
(the forest's pictures, a scan's LAS file): the child sees the data as they are
(copy-on-write, nothing is pickled on the way in), and both cores work. Only on Linux with the
"fork" start method and two or more usable cores (macOS offers fork too, but its system
frameworks are not fork-safe); elsewhere, or with ``parallel=False``, the call runs here, in
turn, when its result is asked for. The child only runs numpy-level Python (no Mitsuba or
Dr.Jit calls), so the threads those libraries left idle in the parent are not needed there.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import traceback
import warnings
from contextlib import nullcontext
from typing import Any, Callable

from .errors import SimlidarError


def use_fork(parallel: bool | None) -> bool:
    """Whether to fork: ``parallel`` True forces it where fork exists, False never, None
    when this process may use two or more cores."""
    if parallel is False or not sys.platform.startswith("linux") \
            or "fork" not in multiprocessing.get_all_start_methods():
        return False
    if parallel:
        return True
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return cores >= 2


def _child(conn, fn: Callable, args: tuple, setup: Callable | None) -> None:
    """The forked process: run, then send ("ok", value), ("error", (exception, text)) or
    ("interrupted", None)."""
    try:
        try:
            with setup() if setup is not None else nullcontext():
                msg = ("ok", fn(*args))
        except KeyboardInterrupt:  # Ctrl-C: the parent got it too (then nobody listens), or
            msg = ("interrupted", None)  # a SIGINT sent to this child alone: the parent's to raise
        except BaseException as exc:  # noqa: BLE001  (everything else goes back to the parent)
            text = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
            try:  # the exception itself, so the parent raises what an in-turn call raises
                conn.send(("error", (exc, text)))
                return
            except Exception:  # noqa: BLE001  (not picklable: its text only)
                msg = ("error", (None, text))
        conn.send(msg)
    except OSError:  # the parent stopped listening (it failed or was interrupted first)
        pass
    finally:
        conn.close()


class Forked:
    """``fn(*args)`` in a forked child started now (see :func:`use_fork`), else here at
    :meth:`wait`.

    :meth:`wait` returns its value (pickled back). If the call raised, :meth:`wait` raises the
    same exception (KeyboardInterrupt when the child alone was interrupted), as a call in turn would (with a note naming ``what`` and the child's
    traceback on Python ≥ 3.11); if that exception cannot be sent back, or the child died, a
    :class:`SimlidarError` naming ``what``. :meth:`close` ends a child still running (the
    caller failed or was interrupted) and must always follow. ``setup``: a context-manager
    factory entered around the call in the child only."""

    def __init__(self, what: str, fn: Callable, *args: Any, parallel: bool | None = None,
                 setup: Callable | None = None) -> None:
        self.what, self.fn, self.args = what, fn, args
        self.child = self.recv = None
        if use_fork(parallel):
            for stream in (sys.stdout, sys.stderr):  # nothing buffered is written twice
                stream.flush()
            ctx = multiprocessing.get_context("fork")
            self.recv, send = ctx.Pipe(duplex=False)
            self.child = ctx.Process(target=_child, args=(send, fn, args, setup), daemon=True)
            with warnings.catch_warnings():
                # Python ≥ 3.12 warns on every fork of a process with threads; ours are Dr.Jit's
                # and OpenBLAS's idle workers, and the child calls neither Dr.Jit nor Mitsuba.
                warnings.filterwarnings("ignore", r".*multi-threaded, use of fork\(\) may lead to deadlocks",
                                        DeprecationWarning)
                self.child.start()
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
        if self.child is None:
            return
        self.recv.close()
        if self.child.is_alive():
            self.child.terminate()
        self.child.join()
