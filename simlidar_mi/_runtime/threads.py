"""Ordered maps over a few threads, for numpy work that releases the GIL.

Used where independent items each take numpy time (a species' trees' leaves, the prototypes'
crown hulls, a forest's leaf table beside its meshes): the results come back in input order and
are those of the plain loop, bit for bit, since each item's arithmetic runs whole in one
thread. One thread (the plain loop, in this thread) where the process may use one core.
"""
from __future__ import annotations

import os
from collections import deque
from typing import Callable, Iterable, Iterator, TypeVar

__all__ = ["usable_cores", "ordered_map"]

T = TypeVar("T")
R = TypeVar("R")

#: Threads at most: the machine this package is tuned on has two cores (BENCHMARKS.md §16).
MAX_THREADS = 2


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def ordered_map(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> Iterator[R]:
    """``fn(item)`` for each item, in order, computed by up to ``threads`` threads (default:
    the usable cores, at most :data:`MAX_THREADS`) and at most ``threads`` items ahead of the
    consumer, so a stream of large results is not all held at once. An exception is raised
    at its item; items already started finish first."""
    n = min(MAX_THREADS, usable_cores()) if threads is None else int(threads)
    if n < 2:
        yield from map(fn, items)
        return
    from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

    with ThreadPoolExecutor(n, thread_name_prefix="simlidar-map") as pool:
        pending: deque = deque()
        try:
            for item in items:
                pending.append(pool.submit(fn, item))
                if len(pending) > n:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for f in pending:
                f.cancel()
