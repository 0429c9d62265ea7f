"""A local pool of spawned worker processes that Ctrl-C cannot catch half-started.

A terminal's Ctrl-C reaches the whole process group. A spawned worker is a new interpreter:
a SIGINT while it imports (or waits for its first task) printed a ``KeyboardInterrupt``
traceback. Here the parent blocks SIGINT and SIGTERM while it starts a worker (the mask
survives the exec, as for CPython's own resource tracker), so the worker starts with both
held; its first act ignores SIGINT for good (the parent decides its fate) and makes SIGTERM
end it quietly.

Blocking the signals in the parent's main thread does not keep them out of the parent: the
kernel hands a signal for the process to a thread that does not block it (the pool's manager
thread, Dask's, Mitsuba's), and Python runs the handler in the main thread at its next
instruction, wherever that is. CPython's pool is not safe against an interrupt raised inside
its own steps: between a worker's spawn and the write of its start-up data (the worker then
prints "EOFError: Ran out of input"), between a worker's start and its entry in the pool's
table (never ended: it opened semaphores that the parent had unlinked), inside the start or
the join of the pool's manager thread, or while the pool's queues are made (the interrupt's
traceback then keeps the call and result queues alive until ``os._exit``, and the resource
tracker reports "5 leaked semaphore objects"). So every call into the pool from here (its
creation, :meth:`_Pool.submit`, its shutdown) runs with interrupts deferred
(:func:`.signals.interrupts_deferred`): an interrupt is raised once the call has returned,
with the pool whole. :func:`worker_pool` then terminates and joins every worker and shuts the
pool down, which releases its semaphores. Workers also die with the parent
(:func:`.fork.die_with_parent`).
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
        except BaseException:  # a failed start (interrupts are deferred here): end it, then raise
            if getattr(self, "_popen", None) is not None:
                _end([self])
            raise
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)  # a held one reaches the deferral


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


class _Pool(ProcessPoolExecutor):
    """A :class:`ProcessPoolExecutor` whose :meth:`submit` (which spawns a worker and starts
    the manager thread) is never cut short by an interrupt (see the module)."""

    def submit(self, fn, /, *args, **kwargs):
        with interrupts_deferred():
            return super().submit(fn, *args, **kwargs)


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
    pool = None
    try:
        with interrupts_deferred():  # an interrupt while its queues are made: once it is whole
            pool = _Pool(workers, mp_context=_QuietContext(),
                         initializer=_worker_start, initargs=(os.getpid(), initializer))
        yield pool
    except BaseException:
        if pool is not None:
            with interrupts_deferred():  # a second Ctrl-C waits until the workers are gone
                _end(list((pool._processes or {}).values()))
                pool.shutdown(wait=True, cancel_futures=True)
        raise
    with interrupts_deferred():  # an interrupt here is raised once the pool is shut down
        pool.shutdown(wait=True)
