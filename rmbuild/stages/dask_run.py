"""The engine of `rmbuild build`: run one function over many independent items (the floors of a building)
in this process, on a Dask ``LocalCluster`` of worker processes, or on a running Dask cluster.

A task takes plain values (names, paths, TOML text) and returns a plain dict; what it builds in between
(gtsam graphs, maps) lives and dies inside its worker, and it writes its outputs itself, through the
workspace's atomic writers. A task that raises, or whose worker dies (killed, out of memory), comes back as
``{"ok": False, "error": "<one line>"}``; the others go on.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Protocol

from rmbuild.config.build import Scheduler
from rmbuild.errors import InputError, RmbuildError, one_line

#: seconds to wait for a cluster's scheduler to answer before giving up
CONNECT_TIMEOUT_S = 30
#: the environment of a local cluster's worker processes, set before they start (so before numpy loads its
#: BLAS): one BLAS / OpenMP thread per worker, as each worker runs one floor on one core (Dask's default
#: too). Dask's default also sets MALLOC_TRIM_THRESHOLD_=65536 (freed memory handed back to the system at
#: once): it doubled a floor task's system time (~1.5 s more of ~18 s of CPU on MS ILC site2 B1, paired
#: runs in docs/notes/scale-out.md): left out.
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: Dask config of a local cluster: the environment above, no statistical profiler in the workers (it
#: samples the running task's stack every 10 ms under the GIL: ~5% of a floor task's CPU time, same runs);
#: a task whose worker dies fails at once (its floor is reported failed, naming the cause, and the next
#: `build` redoes it) instead of being run again elsewhere, so that a killed worker never holds the build
#: for another whole floor's time; and each worker dies with rmbuild's process (no orphans after a kill -9)
LOCAL_CLUSTER_CONFIG = {"distributed.nanny.pre-spawn-environ": WORKER_ENV,
                        "distributed.worker.profile.enabled": False,
                        "distributed.scheduler.allowed-failures": 0,
                        "distributed.worker.preload": ["rmbuild.stages.dask_worker"]}
#: s; the first round waits at most this long for the workers' warm-up (imports) before it starts anyway
WARM_UP_WAIT_S = 120


def run_tasks(fn: Callable[..., dict], items: dict[str, tuple], scheduler: Scheduler,
              on_done: Callable[[str, dict], None] | None = None, worker_memory_gb: float = 0.0,
              on_cluster: Callable[[str], None] | None = None) -> dict[str, dict]:
    """``fn(*items[name])`` for every item; returns name -> result (in the order of ``items``).
    ``on_done(name, result)`` as each one finishes (in the order they finish); ``on_cluster(text)`` once a
    cluster is up (its workers and dashboard)."""
    with executor(scheduler, len(items), worker_memory_gb, on_cluster) as run:
        return run(fn, items, on_done)


class Runner(Protocol):
    """Runs ``fn`` over ``items`` (name -> args), returns name -> result (in the order of ``items``), calls
    ``on_done(name, result)`` as each ends. ``in_process``: the items run in this process (else in other
    processes, which hold their own workspace locks)."""

    in_process: bool

    def __call__(self, fn: Callable[..., dict], items: dict[str, tuple],
                 on_done: Callable[[str, dict], None] | None) -> dict[str, dict]: ...

    def fit(self, n_items: int) -> None:
        """The rounds to come have at most ``n_items`` items: a local cluster of the default size (started
        before they were known) lets its extra workers go."""


class _Serial:
    in_process = True

    def __call__(self, fn: Callable[..., dict], items: dict[str, tuple],
                 on_done: Callable[[str, dict], None] | None) -> dict[str, dict]:
        out = {}
        for name, args in items.items():
            out[name] = call_task(fn, *args)
            if on_done is not None:
                on_done(name, out[name])
        return out

    def fit(self, n_items: int) -> None:
        pass


class _OnDask:
    in_process = False

    def __init__(self, client: Any, shrinkable: bool, warming: list) -> None:
        self.client, self.shrinkable, self.warming = client, shrinkable, warming

    def __call__(self, fn: Callable[..., dict], items: dict[str, tuple],
                 on_done: Callable[[str, dict], None] | None) -> dict[str, dict]:
        if self.warming:
            from distributed import wait

            # a warm-up is only an optimisation: one whose worker died has failed (or runs elsewhere), and none
            # holds the round longer than WARM_UP_WAIT_S
            try:
                wait(self.warming, timeout=WARM_UP_WAIT_S)
            except TimeoutError:
                pass
            self.client.cancel([f for f in self.warming if not f.done()])
            self.warming = []
        return _submit_all(self.client, fn, items, on_done)

    def fit(self, n_items: int) -> None:
        n = len(self.client.scheduler_info().get("workers", {}))
        if self.shrinkable and 1 <= n_items < n:
            self.client.cluster.scale(n_items)


@contextmanager
def executor(scheduler: Scheduler, n_items: int | None, worker_memory_gb: float = 0.0,
             on_cluster: Callable[[str], None] | None = None,
             warm: Callable[[], None] | None = None) -> Iterator[Runner]:
    """A runner of task rounds on one scheduler (one cluster for several rounds): in this process for
    ``serial`` or a single item; else on Dask. ``n_items``: the most items a round has (None: unknown),
    which caps a ``local`` cluster's default size. ``warm()`` runs on every worker as soon as it is up, in
    the background (imports: a worker's first task then starts warm)."""
    if scheduler.kind == "serial" or (n_items is not None and n_items <= 1):
        yield _Serial()
        return
    with _client(scheduler, n_items, worker_memory_gb) as client:
        warming = _warm_up(client, warm) if warm is not None else []
        if on_cluster is not None:
            on_cluster(cluster_text(client))
        yield _OnDask(client, scheduler.kind == "local" and scheduler.workers is None, warming)


def _warm_up(client: Any, warm: Callable[[], None]) -> list:
    """``warm()`` on every worker, as a task of its own: the futures (the first round waits for them, so
    that a worker still warming does not leave every floor to the others)."""
    return [client.submit(warm, workers=[w], allow_other_workers=True, pure=False,
                          key=f"rmbuild-warm-up-{i}-{os.urandom(4).hex()}")
            for i, w in enumerate(client.scheduler_info().get("workers", {}))]


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
    from distributed.scheduler import KilledWorker

    # the items start in the order given (the caller puts the longest first): the first has the highest priority
    futures = {client.submit(call_task, fn, *args, key=f"rmbuild-{name}-{os.urandom(4).hex()}", pure=False,
                             priority=len(items) - i): name
               for i, (name, args) in enumerate(items.items())}
    out: dict[str, dict] = {}
    for fut in as_completed(list(futures)):
        name = futures.pop(fut)
        try:
            out[name] = fut.result()
        except KilledWorker:
            out[name] = {"ok": False, "error": "its Dask worker died while running it (killed, or out of memory); the "
                                               "next `rmbuild build` redoes it"}
        except Exception as e:  # the result could not come back
            out[name] = failed(e)
        # let the result go: a worker that dies holding it would otherwise make Dask run the task again (a floor
        # rewritten behind the build's back after it was recorded done)
        fut.release()
        del fut
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
    import dask

    cores = os.cpu_count() or 1
    n = scheduler.workers or max(1, min(n_items or cores, cores))
    memory: Any = int(worker_memory_gb * 1e9) if worker_memory_gb > 0 else "auto"
    # the scheduler's and nannies' own log lines (a lost worker, a restart): rmbuild reports a floor whose
    # worker died itself, on one line
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        with dask.config.set(LOCAL_CLUSTER_CONFIG):  # the nannies pass it on to the workers they start
            try:
                # the scheduler's web server (the dashboard when bokeh is installed) on a free port, not Dask's
                # 8787: another cluster on the machine may hold that one
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, memory_limit=memory,
                                       dashboard_address=":0")
            except (RuntimeError, OSError, TimeoutError) as e:  # a worker died as it started
                raise RmbuildError(f"the local Dask cluster did not start ({one_line(str(e))[:200]}); nothing was "
                                   "built: run again, or use --scheduler serial") from None
        with cluster, Client(cluster) as client:
            yield client
    finally:
        quiet.setLevel(level)


def _has_bokeh() -> bool:
    """Whether bokeh, which Dask's dashboard needs (the optional extra ``rmbuild[dashboard]``), is installed
    (run where the scheduler runs)."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def cluster_text(client: Any) -> str:
    """"Dask cluster at ADDRESS: N workers, dashboard URL", or a one-line note when the scheduler has no
    dashboard (bokeh missing where it runs)."""
    info = client.scheduler_info()
    n = len(info.get("workers", {}))
    try:
        has = bool(client.run_on_scheduler(_has_bokeh))
    except Exception:  # a scheduler that refuses to run code: say nothing of its dashboard
        has = False
    dash = f", dashboard {client.dashboard_link}" if has else \
        " (no dashboard: it needs bokeh, `pip install 'rmbuild[dashboard]'`)"
    return f"Dask cluster at {info.get('address', '?')}: {n} worker(s){dash}"
