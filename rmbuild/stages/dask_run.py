"""The engine of `rmbuild build`: run one function over many independent items (the floors of a building)
in this process, on a Dask ``LocalCluster`` of worker processes, or on a running Dask cluster.

A task takes plain values (names, paths, TOML text) and returns a plain dict; what it builds in between
(gtsam graphs, maps) lives and dies inside its worker, and it writes its outputs itself, through the
workspace's atomic writers. A task that raises, or whose worker dies (killed, out of memory), comes back as
``{"ok": False, "error": "<one line>"}``; the others go on.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rmbuild.config.build import Scheduler
from rmbuild.errors import InputError, RmbuildError, one_line

#: seconds to wait for a cluster's scheduler to answer before giving up
CONNECT_TIMEOUT_S = 30


def run_tasks(fn: Callable[..., dict], items: dict[str, tuple], scheduler: Scheduler,
              on_done: Callable[[str, dict], None] | None = None, worker_memory_gb: float = 0.0,
              on_cluster: Callable[[str], None] | None = None) -> dict[str, dict]:
    """``fn(*items[name])`` for every item; returns name -> result (in the order of ``items``).
    ``on_done(name, result)`` as each one finishes (in the order they finish); ``on_cluster(text)`` once a
    cluster is up (its workers and dashboard)."""
    with executor(scheduler, len(items), worker_memory_gb, on_cluster) as run:
        return run(fn, items, on_done)


#: runs ``fn`` over ``items`` (name -> args), returns name -> result, calls ``on_done(name, result)`` as each ends
Runner = Callable[[Callable[..., dict], dict[str, tuple], Callable[[str, dict], None] | None], dict[str, dict]]


@contextmanager
def executor(scheduler: Scheduler, n_items: int | None, worker_memory_gb: float = 0.0,
             on_cluster: Callable[[str], None] | None = None) -> Iterator[Runner]:
    """A runner of task rounds on one scheduler (one cluster for several rounds): in this process for
    ``serial`` or a single item; else on Dask. ``n_items``: the most items a round has (None: unknown),
    which caps a ``local`` cluster's default size."""
    if scheduler.kind == "serial" or (n_items is not None and n_items <= 1):
        yield _serial
        return
    with _client(scheduler, n_items, worker_memory_gb) as client:
        if on_cluster is not None:
            on_cluster(cluster_text(client))
        yield lambda fn, items, on_done: _submit_all(client, fn, items, on_done)


def _serial(fn: Callable[..., dict], items: dict[str, tuple],
            on_done: Callable[[str, dict], None] | None) -> dict[str, dict]:
    out = {}
    for name, args in items.items():
        out[name] = call_task(fn, *args)
        if on_done is not None:
            on_done(name, out[name])
    return out


def call_task(fn: Callable[..., dict], *args: Any) -> dict:
    """``fn(*args)``; an exception becomes a failed result with its one-line message."""
    try:
        return fn(*args)
    except Exception as e:  # any failure of one item is that item's, reported, never the others'
        return failed(e)


def failed(e: BaseException) -> dict:
    """A failed result: the error's one-line message (an unexpected one's with its type)."""
    text = str(e) if isinstance(e, RmbuildError) else f"{type(e).__name__}: {e}"
    return {"ok": False, "error": one_line(text)}


def _submit_all(client: Any, fn: Callable[..., dict], items: dict[str, tuple],
                on_done: Callable[[str, dict], None] | None) -> dict[str, dict]:
    from distributed import as_completed

    futures = {client.submit(call_task, fn, *args, key=f"rmbuild-{name}-{os.urandom(4).hex()}", pure=False): name
               for name, args in items.items()}
    out: dict[str, dict] = {}
    for fut in as_completed(list(futures)):
        name = futures[fut]
        try:
            out[name] = fut.result()
        except Exception as e:  # the worker died (KilledWorker) or the result could not come back
            out[name] = failed(e)
        if on_done is not None:
            on_done(name, out[name])
    return {name: out[name] for name in items}


@contextmanager
def _client(scheduler: Scheduler, n_items: int | None, worker_memory_gb: float) -> Iterator[Any]:
    """A Dask client: of a new LocalCluster (closed on exit) or connected to ``scheduler.address``."""
    from distributed import Client, LocalCluster

    if scheduler.kind == "address":
        try:
            client = Client(scheduler.address, timeout=CONNECT_TIMEOUT_S)
        except OSError as e:
            raise InputError(f"--scheduler {scheduler.address}: cannot reach the Dask scheduler ({e})") from None
        with client:
            yield client
        return
    cores = os.cpu_count() or 1
    n = scheduler.workers or max(1, min(n_items or cores, cores))
    memory: Any = int(worker_memory_gb * 1e9) if worker_memory_gb > 0 else "auto"
    with (LocalCluster(n_workers=n, threads_per_worker=1, processes=True, memory_limit=memory,
                       dashboard_address=":0" if _has_dashboard() else None) as cluster,
          Client(cluster) as client):
        yield client


def _has_dashboard() -> bool:
    """Dask's dashboard needs bokeh (an optional package)."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def cluster_text(client: Any) -> str:
    """"Dask cluster at ADDRESS: N workers, dashboard URL" (the dashboard when bokeh is installed)."""
    info = client.scheduler_info()
    n = len(info.get("workers", {}))
    dash = f", dashboard {client.dashboard_link}" if _has_dashboard() else " (no dashboard: `pip install bokeh`)"
    return f"Dask cluster at {info.get('address', '?')}: {n} worker(s){dash}"
