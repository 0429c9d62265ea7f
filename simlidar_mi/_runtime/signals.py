"""Ctrl-C and SIGTERM end a command with one line and exit status 130 or 143, not a
traceback, an abort or a hang.

Dangers: a ``KeyboardInterrupt`` raised while Mitsuba's and Dr.Jit's extension modules
initialise leaves them half-loaded (``ImportError``, ``SystemError``, or a C++ ``terminate``
and rc 134 at exit); one raised inside a library's write (xarray's ``to_netcdf``: its
clean-up then waits on a lock it already holds) hangs the process; one raised while the
package itself imports, before the command line's handler exists, prints a traceback.
:func:`interrupts_deferred` holds SIGINT and SIGTERM back across such a section and delivers
them afterwards; :func:`exit_on_interrupt` covers the package's own imports when run as
``simlidar-mi``; :func:`raise_on_interrupt` makes both signals unwind the command (so
staging folders and locks are removed), SIGTERM as :class:`Terminated`.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from typing import Iterator

INTERRUPTED_RC = 130  # 128 + SIGINT, what shells report for a command ended by Ctrl-C
TERMINATED_RC = 143   # 128 + SIGTERM (kill PID, a batch system's stop)
_DEFERRED = (signal.SIGINT, signal.SIGTERM)
_received: list[int] = []  # the signals that reached raise_on_interrupt's handlers, in order


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt so that the same clean-up runs."""


def exit_status(exc: BaseException) -> tuple[str, int]:
    """(word, exit status) of an interrupt: ("terminated", 143) or ("interrupted", 130)."""
    return ("terminated", TERMINATED_RC) if isinstance(exc, Terminated) else ("interrupted", INTERRUPTED_RC)


def _exit_at_start(signum, frame) -> None:  # noqa: ARG001
    word, rc = exit_status(Terminated() if signum == signal.SIGTERM else KeyboardInterrupt())
    mp = sys.modules.get("multiprocessing")
    # A worker (the study's) leaves the line to its parent, also while it starts (spawned, its
    # parent_process() is set only after the imports, where Ctrl-C to the group may land).
    worker = "--multiprocessing-fork" in getattr(sys, "orig_argv", ()) \
        or (mp is not None and mp.parent_process() is not None)
    if not worker:
        os.write(2, f"simlidar-mi: {word}\n".encode())
    os._exit(rc)


def exit_on_interrupt() -> None:
    """Until the command line installs its own handlers: SIGINT or SIGTERM prints one line
    and exits 130 or 143.

    Only for start-up (imports), when there is nothing to clean up yet; leaves an
    inherited SIG_IGN (``nohup``, background jobs) alone."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _exit_at_start)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _exit_at_start)


def start_program() -> None:
    """The program's own start-up (console script, ``python -m simlidar_mi.cli``), never a
    library import: Ctrl-C or SIGTERM before the command's handlers are set exits 130 or 143
    with one line, and numpy will load OpenBLAS with one thread unless the user chose.

    One thread: our products are small (3x3 rotations, point batches), and each idle OpenBLAS
    worker spins ~0.1 s of CPU after start-up, taken from Mitsuba's import and Embree's build
    (BENCHMARKS §8a).  Must run before numpy is first imported (the package root does not)."""
    exit_on_interrupt()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _raise_interrupt(signum, frame) -> None:  # noqa: ARG001
    _received.append(signum)
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def _redeliver_swallowed(unraisable, default=sys.unraisablehook) -> None:
    """``sys.unraisablehook``: an interrupt raised where Python cannot propagate it (a weakref
    callback such as importlib's module-lock clean-up, a ``__del__``) would be printed as
    "Exception ignored … Traceback" and lost, and the command would run on.  Send the signal
    again once this hook has returned, so that its handler raises in the code that follows.

    Sent from a thread: a signal raised here would run its handler inside this hook."""
    if not (isinstance(unraisable.exc_value, KeyboardInterrupt) and _received):
        default(unraisable)
        return
    signum = signal.SIGTERM if isinstance(unraisable.exc_value, Terminated) else signal.SIGINT
    main = threading.main_thread().ident
    hook = sys._getframe().f_code

    def in_hook() -> bool | None:  # None: the main thread has ended
        frame = sys._current_frames().get(main)
        if frame is None:
            return None
        while frame is not None and frame.f_code is not hook:
            frame = frame.f_back
        return frame is not None

    def resend() -> None:
        while (inside := in_hook()):
            time.sleep(0.0005)  # until the hook has returned (a wait, not a timing)
        if inside is not None:
            signal.pthread_kill(main, signum)
    threading.Thread(target=resend, name="simlidar-mi-resend-signal", daemon=True).start()


def raise_on_interrupt() -> None:
    """SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`, replacing
    :func:`exit_on_interrupt` once the command runs and has outputs to clean up.  Forgets
    the signals an earlier command received (see :func:`received`)."""
    _received.clear()
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in _DEFERRED:  # only the program's own (a caller of cli.main keeps its handlers)
        if signal.getsignal(signum) is _exit_at_start:
            signal.signal(signum, _raise_interrupt)
            sys.unraisablehook = _redeliver_swallowed


def received() -> int | None:
    """The first SIGINT or SIGTERM raised since :func:`raise_on_interrupt`, else None.

    An exception that a library made of our KeyboardInterrupt (Mitsuba's "failed to
    instantiate plugin" when Ctrl-C lands in a plugin's constructor) is still an interrupt."""
    return _received[0] if _received else None


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold back SIGINT and SIGTERM during the block; deliver the first that came (once) to
    its previous handler after.

    Outside the main thread, or for a signal not handled by Python, does nothing for it
    (signal handlers can only be set from the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in _DEFERRED}
    held = [s for s in _DEFERRED if callable(previous[s])]  # not SIG_IGN, SIG_DFL or foreign
    pending: list[int] = []
    for s in held:
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, previous[s])
        if pending:
            previous[pending[0]](pending[0], None)
