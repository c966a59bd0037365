"""Scaling of `rmbuild optimize` to a venue-month of walks (the `month` preset: `large`'s venue, ~500,000 poses,
1,000 walks).

Run from the repo root: ``python -m bench.bench_month [--sizes 50000,150000,500000]``. Long (the month's
simulation alone takes ~3 min, the 500k case ~4 min): ``make bench`` runs it only with
``RMBUILD_BENCH_MONTH=1``. Writes bench/results/month.json and month.md.

The month is simulated and ingested once (in a subprocess, into RMBUILD_BENCH_SCRATCH); each size is every
k-th walk of it (so the venue and its access points stay the same and only the density of walks grows) and
runs in a fresh subprocess, watched by this one: a case whose resident memory passes ``--max-gb`` (default 8,
the target) or whose wall time passes ``--max-min`` is killed, and the phase it had reached is recorded.
Figures per size: pair search, placement (init), solve, RF check, total wall and CPU time, peak memory, the
solver (direct elimination or the walk-preconditioned CG), solves and LM iterations, poses solved, factors, linked
walks and the linked walks' mean position error after one SE(2) fit (as bench_optimize's `large` case).
`large` itself runs first (``--no-large`` skips it): on the shared machine only ratios within one run compare.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench.common import RESULTS, write_result

SCRATCH = Path(os.environ.get("RMBUILD_BENCH_SCRATCH", "/tmp/rmbuild-bench-month"))
SIZES = (50_000, 150_000, 500_000)
SEED = 7
POLL_S = 0.5  # s; how often the watchdog reads the case's resident memory


def _subset_path(n: int) -> Path:
    return SCRATCH / f"month_s{SEED}_{n}.pkl"


def prepare(sizes: list[int]) -> dict:
    """Simulate + ingest the month once; pickle every size's subset of walks into SCRATCH."""
    from bench.bench_optimize import _load, _subset

    if all(_subset_path(n).exists() for n in sizes):  # a previous run's subsets (the simulation is seeded)
        return {"reused": str(SCRATCH)}
    t0 = time.perf_counter()
    ds, fp = _load("month", SEED)
    out = {"simulate_ingest_s": round(time.perf_counter() - t0, 1), "poses": len(ds.poses), "walks": len(ds.walks)}
    SCRATCH.mkdir(parents=True, exist_ok=True)
    for n in sizes:
        with open(_subset_path(n), "wb") as f:
            pickle.dump(_subset(ds, fp, n), f, protocol=pickle.HIGHEST_PROTOCOL)
    return out


def run_case(n: int) -> dict:
    """optimize one subset; progress phases go to stderr (the watchdog reads the last one)."""
    import resource

    from bench.bench_optimize import _linked_metrics
    from rmbuild.config.optimize import OptimizeConfig
    from rmbuild.slam import optimize

    with open(_subset_path(n), "rb") as f:
        ds, fp = pickle.load(f)
    t0, c0 = time.perf_counter(), time.process_time()
    seen: set[str] = set()

    def progress(phase: str, info: dict) -> None:
        if phase not in seen:
            seen.add(phase)
            print(f"PHASE {phase} {time.perf_counter() - t0:.1f}", file=sys.stderr, flush=True)
        if phase == "pair_search" and info.get("done") == info.get("total"):  # the search's last block
            print(f"PHASE pair_search_done {time.perf_counter() - t0:.1f}", file=sys.stderr, flush=True)

    r = optimize(ds, fp, OptimizeConfig(), progress=progress)
    total, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = r.stats
    return {"poses": len(ds.poses), "walks": len(ds.walks), "fingerprints": len(fp),
            "poses_solved": st["poses_solved"], "candidates": st["candidates"],
            "vicinity_factors": st["factors"]["vicinity"], "iterations": st["iterations"], "solves": st["solves"],
            "linked_walks": st["linked_walks"], "time_s": {k: round(v, 1) for k, v in st["time_s"].items()},
            "optimize_total_s": round(total, 1), "optimize_cpu_s": round(cpu, 1), "solver": st["ordering"],
            "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 0),
            "linked_error": _linked_metrics(r, ds)}


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def watched(n: int, max_mb: float, max_s: float) -> dict:
    """Run one size in a subprocess; kill it past ``max_mb`` resident or ``max_s`` wall time."""
    p = subprocess.Popen([sys.executable, "-m", "bench.bench_month", "--case", str(n)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(p.stderr), daemon=True)  # type: ignore[arg-type]
    reader.start()
    t0, peak, killed = time.perf_counter(), 0.0, None
    while p.poll() is None:
        peak = max(peak, _rss_mb(p.pid))
        el = time.perf_counter() - t0
        if peak > max_mb or el > max_s:
            killed = f"resident memory > {max_mb:.0f} MB" if peak > max_mb else f"wall time > {max_s:.0f} s"
            p.kill()
            break
        time.sleep(POLL_S)
    out_text = p.communicate()[0]
    reader.join(timeout=5)
    phases = {ln.split()[1]: float(ln.split()[2]) for ln in err if ln.startswith("PHASE ")}
    if killed or p.returncode != 0:
        return {"target_poses": n, "status": "killed" if killed else "error", "reason": killed or err[-1:],
                "after_s": round(time.perf_counter() - t0, 1), "peak_memory_mb_watched": round(peak),
                "phases_started_s": phases}
    res = json.loads(out_text.strip().splitlines()[-1])
    return {"target_poses": n, "status": "ok", **res, "peak_memory_mb_watched": round(peak)}


def _markdown(res: dict) -> str:
    rows = ["| poses | walks | fingerprints | poses solved | vicinity factors | solver | solves / iterations | "
            "pair search s | placement s | solve s | RF check s | total s | CPU s | peak MB | linked walks | "
            "linked mean error m |", "|" + "---|" * 16]
    for c in res["cases"]:
        if c["status"] != "ok":
            rows.append(f"| ~{c['target_poses']:,} | {c['status']}: {c['reason']} after {c['after_s']} s "
                        f"(phases started at {c['phases_started_s']}), peak {c['peak_memory_mb_watched']} MB |")
            continue
        t, e = c["time_s"], c["linked_error"] or {}
        rows.append(f"| {c['poses']:,} | {c['walks']} | {c['fingerprints']:,} | {c['poses_solved']:,} | "
                    f"{c['vicinity_factors']:,} | {c.get('solver', '')} | {c['solves']} / {c['iterations']} | "
                    f"{t['pair_search']:.1f} | {t['init']:.1f} | {t['solve']:.1f} | "
                    f"{t.get('rf_check', float('nan')):.1f} | "
                    f"{c['optimize_total_s']:.1f} | {c.get('optimize_cpu_s', float('nan')):.1f} | "
                    f"{c['peak_memory_mb']:,.0f} | {c['linked_walks']}/{c['walks']} | "
                    f"{e.get('linked_mean_m', float('nan')):.2f} |")
    return "\n".join(rows) + "\n"


def main(sizes: tuple[int, ...] = SIZES, max_gb: float = 8.0, max_min: float = 30.0, with_large: bool = True) -> dict:
    sizes = tuple(sorted(sizes))
    p = subprocess.run([sys.executable, "-m", "bench.bench_month", "--prepare", ",".join(map(str, sizes))],
                       capture_output=True, text=True, check=True)
    res: dict = {"preset": "month", "seed": SEED, "prepare": json.loads(p.stdout.strip().splitlines()[-1]),
                 "max_memory_mb": max_gb * 1024, "max_wall_s": max_min * 60, "cases": []}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    if with_large:  # `large` in the same run: the shared machine's load moves absolute times 5-10x
        q = subprocess.run([sys.executable, "-m", "bench.bench_optimize", "--case", "large", "robust", str(SEED)],
                           capture_output=True, text=True)
        c = json.loads(q.stdout.strip().splitlines()[-1]) if q.returncode == 0 else {}
        res["large_same_run"] = {"optimize_total_s": c.get("time_s", {}).get("optimize_total"),
                                 "time_s": c.get("time_s"), "peak_memory_mb": c.get("peak_memory_mb")}
    for n in sizes:
        print(f"month subset ~{n:,} poses ...", flush=True)
        load = os.getloadavg()[0]
        res["cases"].append({**watched(n, max_gb * 1024, max_min * 60), "commit": commit, "load_at_start": load})
        print(json.dumps(res["cases"][-1]), flush=True)
    old = RESULTS / "month.json"  # sizes not run this time keep their last figures (each case says its commit)
    if old.exists():
        kept = [c for c in json.loads(old.read_text()).get("cases", []) if c["target_poses"] not in sizes]
        res["cases"] = sorted(kept + res["cases"], key=lambda c: c["target_poses"])
    write_result("month", res)
    md = _markdown(res)
    (RESULTS / "month.md").write_text(md)
    print(md)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--max-gb", type=float, default=8.0)
    ap.add_argument("--max-min", type=float, default=30.0)
    ap.add_argument("--no-large", action="store_true", help="skip the `large` reference case")
    ap.add_argument("--case", type=int)
    ap.add_argument("--prepare")
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case)))
    elif a.prepare:
        print(json.dumps(prepare([int(s) for s in a.prepare.split(",")])))
    else:
        main(tuple(int(s) for s in a.sizes.split(",")), a.max_gb, a.max_min, not a.no_large)
