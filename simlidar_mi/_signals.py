"""Ctrl-C ends a command with one line and exit status 130, not a traceback or an abort.

Two dangers: a ``KeyboardInterrupt`` raised while Mitsuba's and Dr.Jit's extension
modules initialise leaves them half-loaded (``ImportError``, ``SystemError``, or a C++
``terminate`` and rc 134 at exit), and one raised while the package itself imports, before
the command line's handler exists, prints a traceback.  :func:`sigint_deferred` holds an
interrupt back across such a section and delivers it afterwards;
:func:`exit_on_sigint` covers the package's own imports when run as ``simlidar-mi``.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Iterator

INTERRUPTED_RC = 130  # 128 + SIGINT, what shells report for a command ended by Ctrl-C


def _exit_130(signum, frame) -> None:  # noqa: ARG001
    mp = sys.modules.get("multiprocessing")
    if mp is None or mp.parent_process() is None:  # a worker (study) leaves the line to its parent
        os.write(2, b"simlidar-mi: interrupted\n")
    os._exit(INTERRUPTED_RC)


def exit_on_sigint() -> None:
    """Until the command line installs its own handler: Ctrl-C prints one line, exits 130.

    Only for start-up (imports), when there is nothing to clean up yet; leaves an
    inherited SIG_IGN (``nohup``, background jobs) alone."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _exit_130)


def raise_on_sigint() -> None:
    """Ctrl-C raises KeyboardInterrupt again (Python's default), replacing
    :func:`exit_on_sigint` once the command runs and has outputs to clean up."""
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is _exit_130):
        signal.signal(signal.SIGINT, signal.default_int_handler)


@contextlib.contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold back SIGINT during the block; deliver it (once) to the previous handler after.

    Outside the main thread, or when SIGINT is not handled by Python, does nothing
    (signal handlers can only be set from the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # SIG_IGN, SIG_DFL or a handler set outside Python
        yield
        return
    pending: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if pending:
            previous(signal.SIGINT, None)
