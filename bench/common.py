"""Helpers for benchmarks: where results go, peak memory, timing."""

from __future__ import annotations

import json
import platform
import resource
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def machine() -> dict:
    import os

    # the 1-minute load average when the result is written: timings from runs at different loads (other
    # jobs on the machine) are not comparable, ratios within one run are
    return {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform(),
            "load_1min": round(os.getloadavg()[0], 2)}


def write_result(name: str, data: dict) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    p = RESULTS / f"{name}.json"
    p.write_text(json.dumps({"machine": machine(), **data}, indent=2) + "\n")
    return p
