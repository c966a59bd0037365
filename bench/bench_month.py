"""Growth of `rmbuild optimize` from 50,000 to 2,000,000 poses on one venue (the `year` preset: `large`'s venue
walked by 4,000 staff walks, ~2,000,000 poses; each smaller size is every k-th walk of it, so the venue and its
access points stay the same and the density of walks grows).

Run from the repo root: ``python -m bench.bench_month [--sizes 50000,150000,500000,2000000]``. Long (the
year's simulation and ingest take ~10 min, the 2M case ~10-20 min): ``make bench`` runs it only with
``RMBUILD_BENCH_MONTH=1``. Writes bench/results/month.json and month.md.

The year is simulated and ingested once (in a subprocess) into one workspace per size under
RMBUILD_BENCH_SCRATCH. Each size then runs the command ``rmbuild optimize`` itself in a fresh subprocess,
watched by this one (a case whose resident memory passes ``--max-gb`` or whose wall time passes ``--max-min``
is killed, and the phase it had reached is recorded). Inside that process each phase of the command is timed,
wall and CPU (every thread): pair search, placement (its walk refinement apart), solve, RF check, the
predicted errors (uncertainty), the rest of the per-walk table, the trajectory metrics, and the CLI command as
a whole (reading, writing). Per size also the peak memory, the solver, the linked walks and their mean position
error after one SE(2) fit (as bench_optimize's `large` case), and the machine's load at the start; then the
growth exponent of each phase from the smallest to the largest size (log time ratio / log poses ratio).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench.common import RESULTS, write_result

SCRATCH = Path(os.environ.get("RMBUILD_BENCH_SCRATCH", "/tmp/rmbuild-bench-month"))
PRESET = "year"
SIZES = (50_000, 150_000, 500_000, 2_000_000)
SEED = 7
POLL_S = 0.5  # s; how often the watchdog reads the case's resident memory
#: the phases timed inside the command: name -> (module, function) wrapped where it is called from
PHASES = {
    "pair_search": ("rmbuild.slam.pipeline", "default_sources"),
    "placement": ("rmbuild.slam.pipeline", "place"),
    "placement_refinement": ("rmbuild.slam.placement.grow", "refine_placed"),
    "placement_refinement_merge": ("rmbuild.slam.placement.merge", "refine_placed"),
    "solve": ("rmbuild.slam.pipeline", "run_solves"),
    "rf_check": ("rmbuild.slam.pipeline", "refute"),
    "walk_table": ("rmbuild.slam.report", "walk_table"),
    "uncertainty": ("rmbuild.slam.report", "predicted_errors"),
    "metrics": ("rmbuild.stages.optimize", "trajectory_metrics"),
    "metrics_unlinked": ("rmbuild.stages.optimize", "landmark_error_unlinked_at_raw"),
}
#: the phases reported (and their growth exponents); the others are folded in
REPORTED = ("pair_search", "placement", "placement_refinement", "solve", "rf_check", "uncertainty", "walk_table",
            "metrics", "cli")
TARGETS = {500_000: {"cli_wall_s": 120, "peak_gb": 2}, 2_000_000: {"cli_wall_s": 600, "peak_gb": 6},
           "exponent": 1.15}


def workspace(n: int) -> Path:
    return SCRATCH / f"{PRESET}_s{SEED}_{n}"


def prepare(sizes: list[int]) -> dict:
    """Simulate + ingest the year once; write each size's subset of walks as an ingested workspace."""
    if all((workspace(n) / "manifest.json").exists() for n in sizes):  # a previous run's (the simulation is seeded)
        return {"reused": str(SCRATCH)}
    from bench.bench_optimize import _load, _subset
    from rmbuild.ingest import core
    from rmbuild.io.workspace import Workspace, write_dataset

    SCRATCH.mkdir(parents=True, exist_ok=True)
    # the whole year (416k nodes x 186 APs) is over ingest's fingerprint-table limit (rmbuild/limits.py); it is
    # only the source of the subsets, so this process (the bench's own ingest) lifts the limit
    core.MAX_FINGERPRINT_CELLS = max(core.MAX_FINGERPRINT_CELLS, 10**9)
    t0 = time.perf_counter()
    ds, fp = _load(PRESET, SEED)
    out = {"simulate_ingest_s": round(time.perf_counter() - t0, 1), "poses": len(ds.poses), "walks": len(ds.walks)}
    for n in sizes:
        sub, sfp = _subset(ds, fp, n)
        with Workspace.create(workspace(n), force=True) as w:
            write_dataset(w, sub, sfp)
            w.report = {"stage": "ingest", "format": "rmbuild", "inputs": [f"{PRESET} seed {SEED}, ~{n} poses"],
                        "walks": len(sub.walks), "poses": len(sub.poses), "warnings": []}
    return out


class _Timer:
    """Wall and CPU seconds spent inside wrapped functions, per phase (nested calls of one phase counted once)."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.depth: dict[str, int] = {}

    def wrap(self, phase: str, f):
        def timed(*a, **k):
            self.depth[phase] = self.depth.get(phase, 0) + 1
            t, c = time.perf_counter(), time.process_time()
            try:
                return f(*a, **k)
            finally:
                self.depth[phase] -= 1
                if not self.depth[phase]:
                    self.wall[phase] = self.wall.get(phase, 0.0) + time.perf_counter() - t
                    self.cpu[phase] = self.cpu.get(phase, 0.0) + time.process_time() - c
                    self.calls[phase] = self.calls.get(phase, 0) + 1
        return timed

    def install(self) -> None:
        import importlib

        for phase, (mod, name) in PHASES.items():
            m = importlib.import_module(mod)
            setattr(m, name, self.wrap(phase, getattr(m, name)))


def run_case(n: int) -> dict:
    """``rmbuild optimize`` on the size-n workspace in this process, every phase timed (module docstring)."""
    import resource

    t0, c0 = time.perf_counter(), time.process_time()
    timer = _Timer()
    timer.install()
    from rmbuild.cli import main

    ws = workspace(n)
    try:
        main(["optimize", "-w", str(ws), "--force", "-q"])
    except SystemExit as e:
        if e.code:
            raise RuntimeError(f"rmbuild optimize exited with {e.code}") from None
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    timer.wall["cli"], timer.cpu["cli"] = wall, cpu
    for d in (timer.wall, timer.cpu):  # the refinement inside growth and inside merges, as one
        d["placement_refinement"] = d.get("placement_refinement", 0.0) + d.pop("placement_refinement_merge", 0.0)
        d["walk_table"] = d.get("walk_table", 0.0) - d.get("uncertainty", 0.0)  # the table without the errors
        d["metrics"] = d.get("metrics", 0.0) + d.pop("metrics_unlinked", 0.0)
    from rmbuild.io.workspace import Workspace

    w = Workspace.open(ws)
    rep = w.read_report("optimize")
    return {"poses": rep["poses"], "walks": rep["walks"], "fingerprints": rep.get("fingerprints"),
            "poses_solved": rep["poses_solved"], "vicinity_factors": rep["factors"]["vicinity"],
            "solver": rep.get("ordering"), "solves": rep.get("solves"), "iterations": rep.get("iterations"),
            "linked_walks": rep.get("linked_walks"),
            "wall_s": {k: round(v, 2) for k, v in timer.wall.items()},
            "cpu_s": {k: round(v, 2) for k, v in timer.cpu.items()},
            "stage_time_s": rep["time_s"], "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                                                   / 1024),
            "linked_error": linked_error(w)}


def linked_error(w) -> dict | None:
    """Position error (m) of the linked and of the unlinked walks after one SE(2) fit on the linked walks."""
    import numpy as np

    from rmbuild.evaluate.trajectory import align_se2

    ds = w.read_dataset(readings=False)
    if ds.truth_poses is None:
        return None
    poses = w.read_table("optimize.poses")
    m = poses["linked"].to_numpy(bool)
    est, tru = poses[["x_m", "y_m"]].to_numpy(float), ds.truth_poses[["x_m", "y_m"]].to_numpy(float)
    if m.sum() < 2:
        return None
    R, t = align_se2(est[m], tru[m])
    e = np.linalg.norm(est @ R.T + t - tru, axis=1)
    return {"linked_mean_m": float(e[m].mean()), "linked_median_m": float(np.median(e[m])),
            "unlinked_mean_m": float(e[~m].mean()) if (~m).any() else None}


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
    if killed or p.returncode != 0:
        return {"target_poses": n, "status": "killed" if killed else "error", "reason": killed or err[-1:],
                "after_s": round(time.perf_counter() - t0, 1), "peak_memory_mb_watched": round(peak)}
    res = json.loads(out_text.strip().splitlines()[-1])
    return {"target_poses": n, "status": "ok", **res, "process_wall_s": round(time.perf_counter() - t0, 1),
            "peak_memory_mb_watched": round(peak)}


def exponents(cases: list[dict]) -> dict:
    """Per phase, the growth exponent log(t_large / t_small) / log(poses_large / poses_small) between the
    smallest and the largest size that ran, and between consecutive sizes."""
    ok = sorted((c for c in cases if c["status"] == "ok"), key=lambda c: c["poses"])
    if len(ok) < 2:
        return {}

    def exp(a: dict, b: dict, phase: str) -> float | None:
        ta, tb = a["wall_s"].get(phase), b["wall_s"].get(phase)
        if not ta or not tb or ta <= 0 or tb <= 0:
            return None
        return round(math.log(tb / ta) / math.log(b["poses"] / a["poses"]), 2)

    out = {"from_to": [ok[0]["poses"], ok[-1]["poses"]],
           "end_to_end": {p: exp(ok[0], ok[-1], p) for p in REPORTED},
           "steps": [{"from_to": [a["poses"], b["poses"]], **{p: exp(a, b, p) for p in REPORTED}}
                     for a, b in zip(ok, ok[1:])]}
    return out


def _markdown(res: dict) -> str:
    head = ["poses", "walks", "load", "solver", "linked walks", "linked mean error m", "peak MB", "CLI wall s",
            "CLI CPU s"] + [f"{p} wall / CPU s" for p in REPORTED if p != "cli"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in res["cases"]:
        if c["status"] != "ok":
            rows.append(f"| ~{c['target_poses']:,} | {c['status']}: {c['reason']} after {c['after_s']} s, "
                        f"peak {c['peak_memory_mb_watched']} MB |")
            continue
        e = c.get("linked_error") or {}
        w, u = c["wall_s"], c["cpu_s"]
        cells = [f"{c['poses']:,}", str(c["walks"]), f"{c.get('load_at_start', float('nan')):.1f}", str(c["solver"]),
                 f"{c['linked_walks']}/{c['walks']}", f"{e.get('linked_mean_m', float('nan')):.2f}",
                 f"{max(c['peak_memory_mb'], c['peak_memory_mb_watched']):,}", f"{w['cli']:.1f}", f"{u['cli']:.1f}"]
        cells += [f"{w.get(p, 0.0):.1f} / {u.get(p, 0.0):.1f}" for p in REPORTED if p != "cli"]
        rows.append("| " + " | ".join(cells) + " |")
    ex = res.get("exponents", {})
    if ex:
        rows += ["", f"growth exponent per phase, {ex['from_to'][0]:,} -> {ex['from_to'][1]:,} poses (target <= "
                 f"{TARGETS['exponent']}), and between consecutive sizes:", "",
                 "| poses | " + " | ".join(REPORTED) + " |", "|" + "---|" * (len(REPORTED) + 1),
                 "| all | " + " | ".join(str(ex["end_to_end"][p]) for p in REPORTED) + " |"]
        rows += [f"| {s['from_to'][0]:,} -> {s['from_to'][1]:,} | " + " | ".join(str(s[p]) for p in REPORTED) + " |"
                 for s in ex["steps"]]
    return "\n".join(rows) + "\n"


def main(sizes: tuple[int, ...] = SIZES, max_gb: float = 8.0, max_min: float = 40.0) -> dict:
    sizes = tuple(sorted(sizes))
    p = subprocess.run([sys.executable, "-m", "bench.bench_month", "--prepare", ",".join(map(str, sizes))],
                       capture_output=True, text=True, check=True)
    res: dict = {"preset": PRESET, "seed": SEED, "prepare": json.loads(p.stdout.strip().splitlines()[-1]),
                 "max_memory_mb": max_gb * 1024, "max_wall_s": max_min * 60, "targets": TARGETS, "cases": []}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    for n in sizes:
        print(f"{PRESET} subset ~{n:,} poses ...", flush=True)
        load = os.getloadavg()[0]
        res["cases"].append({**watched(n, max_gb * 1024, max_min * 60), "commit": commit, "load_at_start": load,
                             "load_at_end": os.getloadavg()[0]})
        print(json.dumps(res["cases"][-1]), flush=True)
    old = RESULTS / "month.json"  # sizes not run this time keep their last figures (each case says its commit)
    if old.exists():
        prev = json.loads(old.read_text())
        if prev.get("preset") == PRESET:
            kept = [c for c in prev.get("cases", []) if c["target_poses"] not in sizes]
            res["cases"] = sorted(kept + res["cases"], key=lambda c: c["target_poses"])
    res["exponents"] = exponents(res["cases"])
    write_result("month", res)
    md = _markdown(res)
    (RESULTS / "month.md").write_text(md)
    print(md)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--max-gb", type=float, default=8.0)
    ap.add_argument("--max-min", type=float, default=40.0)
    ap.add_argument("--case", type=int)
    ap.add_argument("--prepare")
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case)))
    elif a.prepare:
        print(json.dumps(prepare([int(s) for s in a.prepare.split(",")])))
    else:
        main(tuple(int(s) for s in a.sizes.split(",")), a.max_gb, a.max_min)
