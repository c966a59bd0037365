"""Threads on purpose: one BLAS thread for small dense operations, and independent blocks on worker threads.

On the shared 2-core machine a multi-threaded BLAS was 3-8x slower on products of a few thousand entries
(thread wake-ups dominate; bench/bench_map.py, bench/bench_localizers.py); the localizers' own work is small
products, so they run them on one thread (the kNN runs two worker threads of its own over query chunks).
With the other core busy, two BLAS threads made a venue-month's 150k placement 11x slower (6.0 s -> 68 s).
Where the work is many independent blocks (the pair search's distance blocks) it runs on one worker thread per
free core instead, each block on one BLAS thread: the threads never wait on each other inside a product, the
CPU time stays that of one thread and the speed-up follows the free cores; on the shared machine, with its
other core busy, a second worker did not pay (docs/notes/scale.md).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractContextManager
from functools import cache
from typing import TypeVar

from threadpoolctl import ThreadpoolController

T = TypeVar("T")
R = TypeVar("R")

#: worker threads of :func:`blocks_in_parallel`; None: one per core the machine's load leaves free (at least one)
WORKERS: int | None = None


def free_cores() -> int:
    """Cores not taken by other processes: the cores less the 1-minute load average (this process's own running
    thread counted back in), at least 1."""
    cores = os.cpu_count() or 1
    return int(max(1, min(cores, round(cores - os.getloadavg()[0] + 1))))


@cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager:
    """Context manager limiting BLAS to one thread (threadpoolctl; ~30-70 µs to enter)."""
    return _controller().limit(limits=1, user_api="blas")


def blocks_in_parallel(fn: Callable[[T], R], items: Iterable[T], on_done: Callable[[int], None] | None = None,
                       workers: int | None = None) -> list[R]:
    """``[fn(item) for item in items]`` on ``workers`` threads (default WORKERS) with BLAS on one thread (numpy
    releases the GIL in its products and array loops); ``on_done(i)`` in the calling thread as results come in,
    in order. Each block's arithmetic is the same as on one thread: the results do not depend on the threads."""
    items = list(items)
    workers = workers or WORKERS or free_cores()
    out: list[R] = []
    with one_blas_thread():
        if workers <= 1 or len(items) <= 1:
            for i, item in enumerate(items):
                out.append(fn(item))
                if on_done:
                    on_done(i)
            return out
        with ThreadPoolExecutor(workers) as ex:
            for i, r in enumerate(ex.map(fn, items)):
                out.append(r)
                if on_done:
                    on_done(i)
    return out
