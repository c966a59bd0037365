"""Config of `rmbuild build` (docs/scale-out.md): where the floors of a building run."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NamedTuple

from rmbuild.config.base import bounded, check_ranges

#: ``local`` / ``local:N`` and ``tcp://HOST:PORT`` (Dask's scheduler address; tls:// for a secured cluster)
_LOCAL = re.compile(r"^local(?::(\d+))?$")
_ADDRESS = re.compile(r"^(tcp|tls)://[A-Za-z0-9_.\-\[\]:]+:\d+$")
#: worker processes a ``local:N`` scheduler may start (a sanity bound: far above any one machine's cores)
MAX_LOCAL_WORKERS = 512


class Scheduler(NamedTuple):
    """A parsed scheduler value: kind "serial", "local" (``workers`` None: one per core) or "address"."""

    kind: str
    workers: int | None = None
    address: str | None = None


def parse_scheduler(text: str) -> Scheduler:
    """``serial`` | ``local`` | ``local:N`` | ``tcp://HOST:PORT``; ValueError naming the forms otherwise."""
    s = text.strip()
    if s == "serial":
        return Scheduler("serial")
    m = _LOCAL.match(s)
    if m:
        n = int(m.group(1)) if m.group(1) else None
        if n is not None and not 1 <= n <= MAX_LOCAL_WORKERS:
            raise ValueError(f"scheduler {text!r}: local:N needs 1 <= N <= {MAX_LOCAL_WORKERS}")
        return Scheduler("local", workers=n)
    if _ADDRESS.match(s):
        return Scheduler("address", address=s)
    raise ValueError(f"scheduler {text!r}: expected serial, local, local:N or tcp://HOST:PORT")


@dataclass(frozen=True)
class BuildConfig:
    # where the floors run (each floor's optimize, export-map, evaluate, report is one task): "serial" (in
    # this process, one after the other); "local" or "local:N" (a Dask cluster of N worker processes on this
    # machine; N default: one per core, at most one per floor); "tcp://HOST:PORT" (a running Dask scheduler,
    # `dask scheduler` / `dask worker`). A single-floor input (without --venues) runs in this process.
    # Default serial: it starts no processes and on a small shared machine local is hardly faster, while it
    # needs a worker's memory per floor (docs/notes/scale-out.md); a cluster pays with free cores and many
    # floors.
    scheduler: str = "serial"
    # GB; memory limit of each local worker process (Dask restarts a worker above it and the floor fails);
    # 0: the machine's memory shared equally by the workers. Cluster workers set theirs (`dask worker
    # --memory-limit`).
    worker_memory_gb: float = bounded(0.0, 0.0, 4096.0)

    def validate(self) -> None:
        check_ranges(self)
        parse_scheduler(self.scheduler)
