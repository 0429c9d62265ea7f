"""A local pool of spawned worker processes that Ctrl-C cannot catch half-started.

A terminal's Ctrl-C reaches the whole process group. A spawned worker is a new interpreter:
a SIGINT while it imports (or waits for its first task) printed a ``KeyboardInterrupt``
traceback, and the pool's semaphores were left to the resource tracker ("leaked semaphore").
Here the parent blocks SIGINT and SIGTERM while it starts a worker (the mask survives the
exec, as for CPython's own resource tracker), so the worker starts with both held; its first
act ignores SIGINT for good (the parent decides its fate) and makes SIGTERM end it quietly.
The signal the parent held is raised in the parent once the worker is known, and
:func:`worker_pool` then terminates and joins every worker and shuts the pool down, which
releases its semaphores. Workers also die with the parent (:func:`.fork.die_with_parent`).
"""
from __future__ import annotations

import contextlib
import os
import signal
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.context import SpawnContext, SpawnProcess
from typing import Callable, Iterator

from .fork import CLOSE_WAIT_S, die_with_parent
from .signals import interrupts_deferred

_INTERRUPTS = (signal.SIGINT, signal.SIGTERM)


class _QuietProcess(SpawnProcess):
    """A spawned process started with SIGINT and SIGTERM blocked in it (see the module)."""

    def start(self) -> None:
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _INTERRUPTS)
        try:
            super().start()
        except BaseException:  # an interrupt that another thread of ours took: end it, then raise
            if getattr(self, "_popen", None) is not None:
                _end([self])
            raise
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)  # a held interrupt is raised here


class _QuietContext(SpawnContext):
    Process = _QuietProcess


def _leave_quietly(signum, frame) -> None:  # noqa: ARG001
    os._exit(0)  # no traceback, no exit handlers: the parent reports


def _worker_start(parent_pid: int, initializer: Callable | None) -> None:
    """First call in each worker, with SIGINT and SIGTERM still blocked from its start."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a held SIGINT is dropped with it
    signal.signal(signal.SIGTERM, _leave_quietly)
    die_with_parent(parent_pid)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _INTERRUPTS)  # a held SIGTERM ends it here
    if initializer is not None:
        initializer()


def _end(processes) -> None:
    for p in processes:
        if p.exitcode is None:
            p.terminate()
    for p in processes:
        p.join(CLOSE_WAIT_S)
        if p.exitcode is None:  # SIGTERM held by a section that defers it, longer than we wait
            p.kill()
            p.join()


@contextlib.contextmanager
def worker_pool(workers: int, initializer: Callable | None = None) -> Iterator[ProcessPoolExecutor]:
    """A :class:`ProcessPoolExecutor` of ``workers`` spawned processes, shut down at the end.
    When the block raises (Ctrl-C, SIGTERM, a failure) its workers are terminated first, so
    the shutdown does not wait for their tasks."""
    if os.environ.get("PYTHONHASHSEED") in (None, "0"):  # as Dask's own pool sets it: the
        os.environ["PYTHONHASHSEED"] = "6640"  # same hashes (Dask's tokens) in every worker
    pool = ProcessPoolExecutor(workers, mp_context=_QuietContext(),
                               initializer=_worker_start, initargs=(os.getpid(), initializer))
    try:
        yield pool
    except BaseException:
        with interrupts_deferred():  # a second Ctrl-C waits until the workers are gone
            _end(list((pool._processes or {}).values()))
            pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
