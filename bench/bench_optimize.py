"""Benchmark of `rmbuild optimize` (issue 3): kernels, accuracy vs truth, robustness, scaling.

Run from the repo root: ``python -m bench.bench_optimize [--quick] [--skip-large]``. Writes
bench/results/optimize.json and prints a short markdown table. Each case runs in a fresh subprocess so
peak memory (ru_maxrss) is per case.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "optimize.json"


def _load(preset: str, seed: int):
    from rmbuild.config import IngestConfig
    from rmbuild.ingest_core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic import preset_config, simulate

    sd = simulate(preset_config(preset, seed))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps)
    ds, fp, _ = build_dataset(raw, IngestConfig())
    return ds, fp


def _config(name: str):
    from rmbuild.config.optimize import OptimizeConfig, paper_config

    if name == "paper":
        return paper_config()
    cfg = OptimizeConfig()
    if name == "false30":
        cfg = dataclasses.replace(cfg, inject_false_pairs=0.3)
    return cfg


def _odometry_floor(ds) -> float:
    """Seconds of one sparse linearise + solve of the odometry-only graph (plus a gauge per walk)."""
    import gtsam

    from rmbuild.config.optimize import OptimizeConfig
    from rmbuild.slam.factors import X, add_odometry, poses_to_values

    raw = ds.poses[["x_m", "y_m", "heading_rad"]].to_numpy(float)
    sl = ds.walk_slices()
    st = np.array([s.start for s in sl.values()])
    en = np.array([s.stop for s in sl.values()])
    g = gtsam.NonlinearFactorGraph()
    add_odometry(g, raw, st, en, OptimizeConfig().odometry)
    for s in st:
        g.add(gtsam.PriorFactorPose2(X(s), gtsam.Pose2(*raw[s]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    v = poses_to_values(raw)
    t = time.perf_counter()
    g.linearize(v).optimize()
    return time.perf_counter() - t


def run_case(preset: str, mode: str, seed: int) -> dict:
    from rmbuild.evaluate.trajectory import trajectory_metrics
    from rmbuild.slam import optimize

    t0 = time.perf_counter()
    ds, fp = _load(preset, seed)
    t_load = time.perf_counter() - t0
    t1 = time.perf_counter()
    r = optimize(ds, fp, _config(mode))
    t_opt = time.perf_counter() - t1
    out = {
        "preset": preset, "mode": mode, "seed": seed, "poses": len(ds.poses), "walks": len(ds.walks),
        "fingerprints": len(fp), "time_s": {**{k: round(v, 3) for k, v in r.stats["time_s"].items()},
                                            "optimize_total": round(t_opt, 3), "simulate_ingest": round(t_load, 3)},
        "factors": r.stats["factors"], "iterations": r.stats["iterations"], "linked_walks": r.stats["linked_walks"],
        "rejected": r.stats["rejected"], "n_warnings": len(r.stats["warnings"]),
        "raw": trajectory_metrics(ds.poses, ds), "initial": trajectory_metrics(r.initial_poses, ds),
        "optimized": trajectory_metrics(r.poses, ds),
        "odometry_floor_s": round(_odometry_floor(ds), 3),
        "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if ds.truth_poses is not None:
        tr = ds.truth_poses[["x_m", "y_m"]].to_numpy()
        td = np.linalg.norm(tr[r.pairs["node_k"]] - tr[r.pairs["node_q"]], axis=1)
        out["pairs_true_lt5m"] = float(np.mean(td < 5)) if len(td) else None
    out["solve_over_floor"] = round(out["time_s"]["solve"] / max(out["odometry_floor_s"], 1e-6), 1)
    return out


def kernel_bench(n_walks: int = 8, steps: int = 250, pairs_per_pose: int = 10) -> list[dict]:
    """Linearise and LM time of the same graph with each eq. 10 kernel (true pairs, 10 per pose)."""
    import gtsam
    from scipy.spatial import cKDTree

    from rmbuild.config.optimize import OptimizeConfig, VicinityConfig
    from rmbuild.slam.factors import X, add_odometry, poses_to_values, vicinity_factor, vicinity_noise
    from rmbuild.slam.testing import make_venue

    ds, _ = make_venue(n_walks=n_walks, steps_per_walk=steps, seed=5)
    tr = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    _, nb = cKDTree(tr).query(tr, pairs_per_pose + 1)
    pk = np.repeat(np.arange(len(tr)), pairs_per_pose)
    pq = nb[:, 1:].ravel()
    truth = np.c_[tr, ds.truth_poses["heading_rad"].to_numpy()]
    rng = np.random.default_rng(0)
    start = truth + np.c_[rng.normal(0, 1.0, (len(tr), 2)), rng.normal(0, 0.02, len(tr))]
    out = []
    for kernel in ("range_tls", "range_custom", "custom_factor"):
        vc = VicinityConfig(d_min=1.0, d_max=6.0, kernel=kernel)
        g = gtsam.NonlinearFactorGraph()
        sl = ds.walk_slices()
        add_odometry(g, truth, np.array([s.start for s in sl.values()]), np.array([s.stop for s in sl.values()]),
                     OptimizeConfig().odometry)
        g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*truth[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
        noise = vicinity_noise(vc) if kernel != "custom_factor" else None
        for k, q in zip(pk.tolist(), pq.tolist()):
            g.add(vicinity_factor(k, q, vc, noise))
        v = poses_to_values(start)
        t = time.perf_counter()
        for _ in range(3):
            g.linearize(v)
        t_lin = (time.perf_counter() - t) / 3
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(10)
        t = time.perf_counter()
        opt = gtsam.LevenbergMarquardtOptimizer(g, v, p)
        res = opt.optimize()
        t_lm = time.perf_counter() - t
        out.append({"kernel": kernel, "poses": len(tr), "vicinity_factors": len(pk), "linearize_s": round(t_lin, 4),
                    "lm_s": round(t_lm, 3), "lm_iterations": int(opt.iterations()),
                    "final_error": float(g.error(res))})
    return out


CASES = [("default", "robust"), ("default", "paper"), ("default", "false30"), ("corridor12", "robust"),
         ("corridor12", "paper"), ("tiny", "robust"), ("large", "robust")]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", nargs=3, metavar=("PRESET", "MODE", "SEED"))
    ap.add_argument("--skip-large", action="store_true")
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case[0], a.case[1], int(a.case[2]))))
        return
    results = {"kernels": kernel_bench(), "cases": []}
    for preset, mode in CASES:
        if a.skip_large and preset == "large":
            continue
        p = subprocess.run([sys.executable, "-m", "bench.bench_optimize", "--case", preset, mode, str(a.seed)],
                           capture_output=True, text=True)
        if p.returncode != 0:
            results["cases"].append({"preset": preset, "mode": mode, "error": p.stderr.strip().splitlines()[-1:]})
            continue
        results["cases"].append(json.loads(p.stdout.strip().splitlines()[-1]))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))
    print("| kernel | linearize s | LM s (10 it) |\n|---|---|---|")
    for k in results["kernels"]:
        print(f"| {k['kernel']} | {k['linearize_s']} | {k['lm_s']} |")
    print("\n| preset | mode | poses | lm err mean/max m | heading err mean/std deg | ATE mean m | "
          "pair search s | solve s | total s | floor s | peak MB |\n|" + "---|" * 11)
    for c in results["cases"]:
        if "error" in c:
            print(f"| {c['preset']} | {c['mode']} | error: {c['error']} |")
            continue
        o = c["optimized"]
        lm, hd = o["landmark_error_m"], o["heading_alignment_error_deg"]
        lm_s = "{:.2f}/{:.2f}".format(lm["mean"], lm["max"]) if lm else "-"
        hd_s = "{:.2f}/{:.2f}".format(hd["mean"], hd["std"]) if hd else "-"
        print(f"| {c['preset']} | {c['mode']} | {c['poses']} | {lm_s} | {hd_s} | "
              f"{o['ate_m']['mean']:.2f} | {c['time_s']['pair_search']:.1f} | {c['time_s']['solve']:.1f} | "
              f"{c['time_s']['optimize_total']:.1f} | {c['odometry_floor_s']:.2f} | {c['peak_memory_mb']:.0f} |")


if __name__ == "__main__":
    main()
