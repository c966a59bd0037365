"""One BLAS thread for many small dense operations.

On the shared 2-core machine a multi-threaded BLAS was 3-8x slower on products of a few thousand entries
(thread wake-ups dominate; bench/bench_map.py, bench/bench_localizers.py); the localizers' own work is small
products, so they run them on one thread (the kNN runs two worker threads of its own over query chunks).
The placement's refinement factors its dense normal matrix (a few hundred unknowns, hundreds of times) on
one thread too: with the other core busy, two BLAS threads made a venue-month's 150k placement 11x slower
(6.0 s -> 68 s).
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from functools import cache

from threadpoolctl import ThreadpoolController


@cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager:
    """Context manager limiting BLAS to one thread (threadpoolctl; ~30-70 µs to enter)."""
    return _controller().limit(limits=1, user_api="blas")
