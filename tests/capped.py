"""Run the CLI in a child process with a memory cap, so that a blow-up fails the test instead of the machine."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

#: bytes of address space the child may map: scipy alone maps ~1.5 GB of address space at import (not
#: memory), so the cap sits above that and well below what the bugs it guards against asked for (4-587 GiB)
ADDRESS_SPACE_LIMIT = 3 << 30

_CHILD = """
import resource, sys
lim = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
from rmbuild.cli import main
try:
    main(sys.argv[2:])
finally:
    # this process's own high-water mark: ru_maxrss also counts the parent's memory at the fork before exec
    try:
        peak = next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:"))
    except (OSError, StopIteration):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    sys.stderr.write(f"\\nPEAK_RSS_KB={peak}\\n")
"""


@dataclass
class Capped:
    code: int
    err: str
    peak_rss_mb: float


def run_capped(*args: str | Path, timeout_s: float = 120.0) -> Capped:
    """``rmbuild ARGS`` in a child process under :data:`ADDRESS_SPACE_LIMIT`; exit code, stderr (without
    the peak line) and the child's peak resident memory in MB."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    p = subprocess.run([sys.executable, "-c", _CHILD, str(ADDRESS_SPACE_LIMIT), *map(str, args)],
                       capture_output=True, text=True, timeout=timeout_s, env=env)
    lines = p.stderr.splitlines()
    peak = [ln for ln in lines if ln.startswith("PEAK_RSS_KB=")]
    err = "\n".join(ln for ln in lines if ln and not ln.startswith("PEAK_RSS_KB="))
    return Capped(p.returncode, err, int(peak[-1].split("=")[1]) / 1024 if peak else float("nan"))
