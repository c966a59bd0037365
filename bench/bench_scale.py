"""`rmbuild build` on the MS ILC sites: serial against a Dask LocalCluster of 2 worker processes.

Run from the repo root: ``python -m bench.bench_scale [--sites site1,site2] [--schedulers serial,local:2]
[--scratch DIR]``. For each site (a building of 2 or 3 floors), ``rmbuild build`` runs through the CLI once
per scheduler, one run after the other, and the bench records the wall time of each (whole command, and
the floors part), each floor's task time and the peak memory of the process that ran it, and whether the
outputs agree (each floor's poses, radio-map cells and evaluate tracks: largest absolute difference).
Writes ``bench/results/scale.json`` and ``scale.md``. Data: ``$RMBUILD_DATASETS``, default
``<repo>/../shared/datasets``; skips cleanly when absent. A few minutes of CPU on two cores.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.bench_real import ilc_data_root
from bench.common import RESULTS, write_result

#: per floor: the tables compared between schedulers
TABLES = ("optimize.poses", "map.cells", "evaluate.tracks")


def run_build(src: Path, ws: Path, scheduler: str) -> dict:
    """One `rmbuild build` through the CLI; its wall time and the build report it wrote."""
    cmd = [sys.executable, "-m", "rmbuild", "build", str(src), "-w", str(ws), "--format", "msft-ilc",
           "--scheduler", scheduler, "--force", "-q"]
    load0 = os.getloadavg()[0]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    # CPU seconds of the command and every process it started (workers included): the work done, which
    # other jobs on the machine change less than the wall time
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip()[-500:], "wall_s": round(wall, 2)}
    rep = json.loads((ws / "building" / "build.json").read_text())
    # the machine's 1-minute load average before and after: other processes slow a run down
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 1), "time_s": rep["time_s"],
            "load_average": [load0, os.getloadavg()[0]],
            "floors": {n: {"time_s": f["time_s"], "peak_rss_mb": f["peak_rss_mb"], "worker": f["worker"],
                           "stages_s": {k: v.get("time_s") for k, v in f["stages"].items()}}
                       for n, f in rep["floors"].items()}}


def max_differences(a: Path, b: Path) -> dict:
    """Per floor and table: the largest absolute difference of the numeric columns (0.0: identical)."""
    from rmbuild.io.workspace import Workspace, building_floors

    out: dict = {}
    for name, pa in (building_floors(a) or {}).items():
        wa, wb = Workspace.open(pa), Workspace.open(b / "floors" / pa.name)
        out[name] = {}
        for key in TABLES:
            ta, tb = wa.read_table(key), wb.read_table(key)
            num = ta.select_dtypes("number").columns
            same_rest = ta.shape == tb.shape and ta.drop(columns=num).equals(tb.drop(columns=num))
            diff = np.nanmax(np.abs(ta[num].to_numpy(float) - tb[num].to_numpy(float))) if same_rest else None
            out[name][key] = None if diff is None else float(diff)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sites", default="site1,site2")
    ap.add_argument("--schedulers", default="serial,local:2")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-scale"))
    args = ap.parse_args()
    root = ilc_data_root()
    if not root.is_dir():
        print(f"skipped: {root} absent")
        return
    scheds = args.schedulers.split(",")
    result: dict = {"schedulers": scheds, "sites": {}}
    for site in args.sites.split(","):
        ws = {s: args.scratch / f"{site}-{s.replace(':', '')}" for s in scheds}
        runs = {s: run_build(root / site, ws[s], s) for s in scheds}
        ok = all("error" not in r for r in runs.values())
        diff = max_differences(ws[scheds[0]], ws[scheds[1]]) if ok and len(scheds) > 1 else None
        result["sites"][site] = {"runs": runs, "max_abs_difference": diff}
    write_result("scale", result)
    (RESULTS / "scale.md").write_text(markdown(result))
    print(markdown(result))


def makespan(times: list[float], workers: int) -> float:
    """When the last of ``times`` ends on ``workers`` workers, the longest started first (as `build` does)."""
    ends = [0.0] * workers
    for t in sorted(times, reverse=True):
        ends[ends.index(min(ends))] += t
    return max(ends)


def ideal_ratio(serial: dict, workers: int) -> tuple[float, float]:
    """The best serial / parallel ratio the floor sizes allow (whole command, floors part): the serial run
    with its floors part replaced by their schedule on ``workers`` workers and nothing else changed."""
    times = [f["time_s"] for f in serial["floors"].values()]
    part = makespan(times, workers)
    return serial["wall_s"] / (serial["wall_s"] - sum(times) + part), sum(times) / part


def markdown(result: dict) -> str:
    s0, s1 = (result["schedulers"] + [None])[:2]
    lines = ["# `rmbuild build`: serial vs a local Dask cluster (`python -m bench.bench_scale`)", "",
             f"| site | floors | {s0} wall s (floors part) | {s1} wall s (floors part) | ratio (floors part) | "
             "ideal ratio from the serial floor times (floors part) | CPU s | load average | peak MB per floor task | "
             "outputs equal |", "|---|---|---|---|---|---|---|---|---|---|"]
    for site, r in result["sites"].items():
        a, b = r["runs"][s0], r["runs"].get(s1, {})
        if "error" in a or "error" in b:
            lines.append(f"| {site} | | {a.get('error', '')} | {b.get('error', '')} | | | | | | |")
            continue
        ratio = a["wall_s"] / b["wall_s"] if b else float("nan")
        part = a["time_s"]["floors"] / b["time_s"]["floors"] if b else float("nan")
        workers = len({f["worker"] for f in b["floors"].values()}) if b else 1
        ideal, ideal_part = ideal_ratio(a, workers)
        peaks = ", ".join(f"{n} {f['peak_rss_mb']:.0f}" for n, f in (b or a)["floors"].items())
        diff = r["max_abs_difference"] or {}
        equal = all(v == 0.0 for d in diff.values() for v in d.values()) if diff else None
        lines.append(f"| {site} | {len(a['floors'])} | {a['wall_s']:.1f} ({a['time_s']['floors']:.1f}) | "
                     f"{b['wall_s']:.1f} ({b['time_s']['floors']:.1f}) | {ratio:.2f}× ({part:.2f}×) | "
                     f"{ideal:.2f}× ({ideal_part:.2f}×) | {a.get('cpu_s', '?')} / {b.get('cpu_s', '?')} | "
                     f"{_load(a)} / {_load(b)} | {peaks} | {equal} |")
    return "\n".join(lines) + "\n"


def _load(run: dict) -> str:
    lo = run.get("load_average") or [float("nan")] * 2
    return f"{lo[0]:.1f}-{lo[1]:.1f}"


if __name__ == "__main__":
    main()
