"""Benchmark of `rmbuild optimize`: accuracy vs truth, robustness, scaling.

Run from the repo root: ``python -m bench.bench_optimize [--skip-large] [--skip-real]``. Writes
bench/results/optimize.json and prints short markdown tables. Each case runs in a fresh subprocess so
peak memory (ru_maxrss) is per case. Sections:
- cases: synthetic presets, rmbuild's pipeline beside the paper preset, 30 % false pairs, large (with and
  without the chain reduction, in one run: their solve-time ratio is the reduction's gain);
- seeds / holdout: twelve `default` venues (robust, paper, 30 % false pairs) and twelve held-out ones
  (robust; seeds no default was tuned on);
- scaling: subsets of large's walks (~2k / 10k / 50k poses) with pair search / init / solve times and
  the odometry-only sparse solve as the floor;
- real: MS ILC site1/F1 and site2/F4 (when /work/shared/datasets exists): optimize -> export-map ->
  evaluate through the CLI, robust and paper, landmark (waypoint) error raw vs optimised, linked walks,
  built vs surveyed kNN.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "optimize.json"
DATASETS = Path(os.environ.get("RMBUILD_DATASETS", "/work/shared/datasets"))
ILC_FLOORS = {"F1": "msft-ilc20/data/site1/F1", "F4": "msft-ilc20/data/site2/F4"}
ANCHOR_EVERY = 5  # real "anchors" mode: one anchor (a first waypoint) on every 5th walk
SCRATCH = Path(os.environ.get("RMBUILD_BENCH_SCRATCH", "/tmp/rmbuild-bench-optimize"))


def _subset(ds, fp, target_poses: int):
    """Every k-th walk of ``ds`` so that about ``target_poses`` poses remain (node ids re-indexed)."""
    from rmbuild.types import Fingerprints

    sizes = ds.poses.groupby("walk_id", sort=False).size()
    wids = list(sizes.index)
    if target_poses >= sizes.sum():
        return ds, fp
    step = max(1, int(sizes.sum() // target_poses))
    chosen, total = [], 0
    for off in range(step):
        for w in wids[off::step]:
            if total >= target_poses:
                break
            if w not in chosen:
                chosen.append(w)
                total += int(sizes[w])
    keep_w = set(chosen)
    pm = ds.poses["walk_id"].isin(keep_w).to_numpy()
    new_id = np.cumsum(pm) - 1
    fm = pm[fp.node]
    fp2 = Fingerprints(new_id[fp.node[fm]], fp.bssids, fp.rss_dbm[fm], fp.count[fm])

    def sel(df):
        return None if df is None else df[df["walk_id"].isin(keep_w)].reset_index(drop=True)

    ds2 = dataclasses.replace(ds, walks=sel(ds.walks), poses=sel(ds.poses), wifi=sel(ds.wifi), fixes=sel(ds.fixes),
                              truth_poses=sel(ds.truth_poses))
    return ds2, fp2


def _load(preset: str, seed: int):
    from rmbuild.config import IngestConfig
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic import preset_config, simulate

    target = None
    if "@" in preset:
        preset, target = preset.split("@")
    sd = simulate(preset_config(preset, seed))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps)
    ds, fp, _ = build_dataset(raw, IngestConfig())
    if target:
        ds, fp = _subset(ds, fp, int(target))
    return ds, fp


def _config(name: str):
    """(config, candidates hook) of a mode: robust, paper, false30 (30 % of the Wi-Fi candidates replaced
    by random cross-walk pairs), full_graph (one node per step in the solve, for the chain reduction's
    time ratio)."""
    from rmbuild.config.optimize import OptimizeConfig, paper_config
    from tests.slam_venue import false_pairs

    if name == "paper":
        return paper_config(), None
    cfg = OptimizeConfig()
    if name == "full_graph":
        cfg = dataclasses.replace(cfg, solve=dataclasses.replace(cfg.solve, chain_reduction=False))
    return cfg, (false_pairs(0.3) if name == "false30" else None)


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
    cfg, hook = _config(mode)
    r = optimize(ds, fp, cfg, candidates_hook=hook)
    t_opt = time.perf_counter() - t1
    linked = r.walks.loc[r.walks["linked"].astype(bool), "walk_id"].astype(str).tolist() or None
    out = {
        "preset": preset, "mode": mode, "seed": seed, "poses": len(ds.poses), "poses_solved": r.stats["poses_solved"],
        "walks": len(ds.walks),
        "fingerprints": len(fp), "time_s": {**{k: round(v, 3) for k, v in r.stats["time_s"].items()},
                                            "optimize_total": round(t_opt, 3), "simulate_ingest": round(t_load, 3)},
        "factors": r.stats["factors"], "iterations": r.stats["iterations"], "linked_walks": r.stats["linked_walks"],
        "rejected": r.stats["rejected"], "n_warnings": len(r.stats["warnings"]),
        "raw": trajectory_metrics(ds.poses, ds), "initial": trajectory_metrics(r.initial_poses, ds, fit_walks=linked),
        "optimized": trajectory_metrics(r.poses, ds, fit_walks=linked),
        # the same, with the alignment fitted on all walks (unlinked ones too; before 2026-11-22)
        "optimized_all_walk_fit": trajectory_metrics(r.poses, ds),
        "odometry_floor_s": round(_odometry_floor(ds), 3),
        "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    out["optimized_linked_walks"] = _linked_metrics(r, ds)
    if ds.truth_poses is not None:
        tr = ds.truth_poses[["x_m", "y_m"]].to_numpy()
        td = np.linalg.norm(tr[r.pairs["node_k"]] - tr[r.pairs["node_q"]], axis=1)
        out["pairs_true_lt5m"] = float(np.mean(td < 5)) if len(td) else None
    out["solve_over_floor"] = round(out["time_s"]["solve"] / max(out["odometry_floor_s"], 1e-6), 1)
    return out


def _linked_metrics(r, ds) -> dict | None:
    """Position error (m) of linked and of unlinked walks after one SE(2) fit on the linked walks."""
    from rmbuild.evaluate.trajectory import align_se2

    if ds.truth_poses is None:
        return None
    linked = set(r.walks.loc[r.walks["linked"], "walk_id"].astype(str))
    wid = r.poses["walk_id"].astype(str).to_numpy()
    m = np.isin(wid, list(linked))
    est, tru = r.poses[["x_m", "y_m"]].to_numpy(float), ds.truth_poses[["x_m", "y_m"]].to_numpy(float)
    if m.sum() < 2:
        return None
    R, t = align_se2(est[m], tru[m])
    e = np.linalg.norm(est @ R.T + t - tru, axis=1)
    per_walk = {w: float(np.median(e[wid == w])) for w in np.unique(wid)}
    lw = np.array([per_walk[w] for w in per_walk if w in linked])
    uw = np.array([per_walk[w] for w in per_walk if w not in linked])
    return {"linked": len(lw), "unlinked": len(uw), "linked_mean_m": float(e[m].mean()),
            "linked_walk_median_m_p50": float(np.median(lw)), "linked_walks_over_5m": int((lw > 5).sum()),
            "unlinked_mean_m": float(e[~m].mean()) if (~m).any() else None}


CASES = [("default", "robust"), ("default", "paper"), ("default", "false30"),
         ("corridor12", "robust"), ("corridor12", "paper"), ("tiny", "robust"), ("large", "robust"),
         ("large", "full_graph")]
SCALING = [("large@2000", "robust"), ("large@10000", "robust")]  # + the full large case above
# seed spread: `default` is one random venue per seed; a figure from one seed says little (measured: seed 7
# is among the easiest; six seeds still moved with every knob). Each seed runs robust, paper and 30 % false
# pairs.
SEEDS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13)
SEED_MODES = ("robust", "paper", "false30")
# held-out venues: seeds no default was ever tuned on (robust pipeline only). Their figures are the honest
# estimate for an unseen venue of this kind; the twelve above have been looked at for every knob.
HOLDOUT_SEEDS = tuple(range(14, 26))


def _ilc_workspace(floor: str) -> Path | None:
    """An ingested workspace of an ILC floor (RMBUILD_BENCH_ILC_<FLOOR>, else ingested once into SCRATCH)."""
    env = os.environ.get(f"RMBUILD_BENCH_ILC_{floor}")
    if env and Path(env, "data", "poses.parquet").exists():
        return Path(env)
    src = DATASETS / ILC_FLOORS[floor]
    if not src.exists():
        return None
    ws = SCRATCH / f"ilc_{floor}"
    if not Path(ws, "data", "poses.parquet").exists():
        cli = Path(sys.executable).with_name("rmbuild")
        subprocess.run([str(cli), "ingest", str(src), "-w", str(ws), "--force", "-q"], check=True)
    return ws


def real_case(floor: str, mode: str) -> dict:
    """optimize -> export-map -> evaluate on a copy of the floor's workspace; waypoint and kNN figures."""
    from rmbuild.evaluate.trajectory import align_se2, interpolate_xy
    from rmbuild.io.workspace import Workspace

    src = _ilc_workspace(floor)
    if src is None:
        return {"floor": floor, "mode": mode, "error": "dataset not found"}
    ws = SCRATCH / f"run_{floor}_{mode}"
    shutil.rmtree(ws, ignore_errors=True)
    ws.mkdir(parents=True)
    shutil.copytree(src / "data", ws / "data")
    shutil.copy(src / "manifest.json", ws / "manifest.json")
    (ws / "reports").mkdir()
    if (src / "reports" / "ingest.json").exists():
        shutil.copy(src / "reports" / "ingest.json", ws / "reports" / "ingest.json")
    cli = str(Path(sys.executable).with_name("rmbuild"))
    preset = "paper" if mode == "paper" else "rmbuild"
    extra, n_anchors = [], 0
    if mode == "anchors":
        # a known position for one moment of every ANCHOR_EVERY-th walk (walk ids sorted): its first waypoint
        fx = Workspace.open(ws).read_dataset().fixes
        wids = sorted(fx["walk_id"].astype(str).unique())[::ANCHOR_EVERY]
        an = fx[fx["walk_id"].astype(str).isin(wids)].groupby("walk_id").head(1)
        an[["walk_id", "t_s", "x_m", "y_m"]].to_csv(ws / "anchors.csv", index=False)
        extra, n_anchors = ["--anchors", str(ws / "anchors.csv")], len(an)
    t0 = time.perf_counter()
    subprocess.run([cli, "optimize", "-w", str(ws), "--preset", preset, "--force", "-q"] + extra, check=True)
    t_opt = time.perf_counter() - t0
    subprocess.run([cli, "export-map", "-w", str(ws), "--force", "-q"], check=True)
    subprocess.run([cli, "evaluate", "-w", str(ws), "--force", "-q"], check=True)
    w = Workspace.open(ws)
    rep, ev = w.read_report("optimize"), w.read_report("evaluate")
    ds = w.read_dataset()
    walks = w.read_table("optimize.walks")
    linked = set(walks.loc[walks["linked"].astype(bool), "walk_id"].astype(str))
    poses = w.read_table("optimize.poses")
    fx = ds.fixes[ds.fixes["walk_id"].astype(str).isin(linked)]
    lm_linked = None
    if len(fx) >= 2:
        est = np.vstack([interpolate_xy(poses, wid, g["t_s"].to_numpy(float)) for wid, g in fx.groupby("walk_id")])
        tru = np.vstack([g[["x_m", "y_m"]].to_numpy(float) for _, g in fx.groupby("walk_id")])
        ok = np.isfinite(est).all(axis=1)
        R, t = align_se2(est[ok], tru[ok])
        e = np.linalg.norm(est[ok] @ R.T + t - tru[ok], axis=1)
        lm_linked = {"mean": float(e.mean()), "median": float(np.median(e)), "n": int(ok.sum())}
    knn = {m: {k: ev["maps"][m]["knn"][k] for k in ("mean", "median", "p90")} for m in ev["maps"]}
    anchored = int((walks["anchored"].astype(bool) & ~walks["linked"].astype(bool)).sum()) if "anchored" in walks else 0
    return {"floor": floor, "mode": mode, "walks": rep["walks"], "poses": rep["poses"],
            "linked_walks": rep.get("linked_walks"), "anchored_only_walks": anchored,
            "anchors": n_anchors,
            "components": rep.get("components"),
            "landmark_raw_m": rep["raw"]["landmark_error_m"],
            "landmark_optimized_m": rep["optimized"]["landmark_error_m"],
            "landmark_linked_walks_m": lm_linked, "knn": knn, "optimize_s": round(t_opt, 2)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", nargs=3, metavar=("PRESET", "MODE", "SEED"))
    ap.add_argument("--skip-large", action="store_true")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--real", nargs=2, metavar=("FLOOR", "MODE"))
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case[0], a.case[1], int(a.case[2]))))
        return
    if a.real:
        print(json.dumps(real_case(a.real[0], a.real[1])))
        return
    results = {"cases": [], "seeds": [], "holdout": [], "real": []}
    _run_seeds(results)
    _run_cases(results, a.skip_large, a.seed)
    if not a.skip_real and DATASETS.exists():
        _run_real(results)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))
    _print_cases(results)
    _print_seeds(results)
    _print_real(results)


def _sub(args: list[str]) -> tuple[dict | None, list[str]]:
    """One case in a fresh process: (its JSON result, None) or (None, the last line of its error)."""
    p = subprocess.run([sys.executable, "-m", "bench.bench_optimize", *args], capture_output=True, text=True)
    if p.returncode != 0:
        return None, p.stderr.strip().splitlines()[-1:]
    return json.loads(p.stdout.strip().splitlines()[-1]), []


def _run_seeds(results: dict) -> None:
    runs = [(seed, mode, "seeds") for seed in SEEDS for mode in SEED_MODES]
    runs += [(seed, "robust", "holdout") for seed in HOLDOUT_SEEDS]
    for seed, mode, section in runs:
        c, err = _sub(["--case", "default", mode, str(seed)])
        if c is None:
            results[section].append({"seed": seed, "mode": mode, "error": err})
            continue
        o = c["optimized"]
        results[section].append({"seed": seed, "mode": mode, "linked_walks": c["linked_walks"],
                                 "walks": c["walks"], "landmark_error_m": o["landmark_error_m"],
                                 "heading_alignment_error_deg": o["heading_alignment_error_deg"],
                                 "all_walk_fit": {k: c["optimized_all_walk_fit"][k] for k in
                                                  ("landmark_error_m", "heading_alignment_error_deg")},
                                 "raw_landmark_error_m": c["raw"]["landmark_error_m"],
                                 "pairs_true_lt5m": c.get("pairs_true_lt5m"),
                                 "optimize_s": c["time_s"]["optimize_total"]})


def _run_cases(results: dict, skip_large: bool, seed: int) -> None:
    for preset, mode in CASES + SCALING:
        if skip_large and preset.startswith("large"):
            continue
        c, err = _sub(["--case", preset, mode, str(seed)])
        results["cases"].append(c if c is not None else {"preset": preset, "mode": mode, "error": err})


def _run_real(results: dict) -> None:
    for floor in ILC_FLOORS:
        for mode in ("robust", "paper") + (("anchors",) if floor == "F1" else ()):
            c, err = _sub(["--real", floor, mode])
            results["real"].append(c if c is not None else {"floor": floor, "mode": mode, "error": err})


def _print_cases(results: dict) -> None:
    print("| preset | mode | poses | lm err mean/max m | heading err mean/std deg | ATE mean m | "
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
    by = {(c["preset"], c["mode"]): c for c in results["cases"] if "error" not in c}
    if ("large", "robust") in by and ("large", "full_graph") in by:
        red, full = by[("large", "robust")], by[("large", "full_graph")]
        print(f"\nchain reduction on large: {red['poses_solved']} of {red['poses']} poses solved, solve "
              f"{red['time_s']['solve']:.1f} s vs {full['time_s']['solve']:.1f} s for the full graph "
              f"({full['time_s']['solve'] / max(red['time_s']['solve'], 1e-9):.1f}x)")


def _print_seeds(results: dict) -> None:
    print("\n| default seed | mode | linked | landmark err mean / max m | heading err mean deg |\n"
          "|---|---|---|---|---|")
    for c in results["seeds"]:
        if "error" in c:
            print(f"| {c['seed']} | {c['mode']} | error: {c['error']} |")
            continue
        lm, hd = c["landmark_error_m"], c["heading_alignment_error_deg"]
        print(f"| {c['seed']} | {c['mode']} | {c['linked_walks']}/{c['walks']} | {lm['mean']:.2f} / {lm['max']:.2f} | "
              f"{hd['mean']:.2f} |")
    for mode in SEED_MODES:
        ok = [c for c in results["seeds"] if c["mode"] == mode and "error" not in c]
        if ok:
            lmm = np.mean([c["landmark_error_m"]["mean"] for c in ok])
            lmx = np.median([c["landmark_error_m"]["max"] for c in ok])
            hdm = np.mean([c["heading_alignment_error_deg"]["mean"] for c in ok])
            print(f"| all {len(ok)} | {mode} | | {lmm:.2f} / median max {lmx:.2f} | {hdm:.2f} |")
            aw = [c["all_walk_fit"] for c in ok if c.get("all_walk_fit", {}).get("landmark_error_m")]
            if aw:
                print(f"| all {len(aw)}, alignment fitted on all walks | {mode} | | "
                      f"{np.mean([a['landmark_error_m']['mean'] for a in aw]):.2f} / median max "
                      f"{np.median([a['landmark_error_m']['max'] for a in aw]):.2f} | "
                      f"{np.mean([a['heading_alignment_error_deg']['mean'] for a in aw]):.2f} |")
    clean = {c["seed"]: c["landmark_error_m"]["mean"] for c in results["seeds"]
             if c["mode"] == "robust" and "error" not in c}
    ratio = {c["seed"]: c["landmark_error_m"]["mean"] / clean[c["seed"]] for c in results["seeds"]
             if c["mode"] == "false30" and "error" not in c and clean.get(c["seed"])}
    if ratio:
        print("30 % false pairs / clean landmark mean per seed: "
              + ", ".join(f"{s}: {r:.2f}x" for s, r in ratio.items()) + f"; worst {max(ratio.values()):.2f}x")
    hold = [c for c in results["holdout"] if "error" not in c]
    if hold:
        print(f"held-out seeds {HOLDOUT_SEEDS[0]}-{HOLDOUT_SEEDS[-1]} (robust, never tuned on): landmark mean "
              f"{np.mean([c['landmark_error_m']['mean'] for c in hold]):.2f} m, median max "
              f"{np.median([c['landmark_error_m']['max'] for c in hold]):.2f} m, heading mean "
              f"{np.mean([c['heading_alignment_error_deg']['mean'] for c in hold]):.2f} deg, "
              f"{sum(c['linked_walks'] for c in hold)} of {sum(c['walks'] for c in hold)} walks linked")


def _print_real(results: dict) -> None:
    print("\n| floor | mode | linked | landmark raw / opt / linked-only mean m | built / surveyed kNN median m |\n"
          "|---|---|---|---|---|")
    for c in results["real"]:
        if "error" in c:
            print(f"| {c['floor']} | {c['mode']} | error: {c['error']} |")
            continue
        ll = c["landmark_linked_walks_m"]
        plus = f" + {c['anchored_only_walks']} by anchors" if c.get("anchored_only_walks") else ""
        print(f"| {c['floor']} | {c['mode']} | {c['linked_walks']}/{c['walks']}{plus} | "
              f"{c['landmark_raw_m']['mean']:.1f} / {c['landmark_optimized_m']['mean']:.1f} / "
              f"{ll['mean'] if ll else float('nan'):.1f} | "
              f"{c['knn']['built']['median']:.1f} / {c['knn']['surveyed']['median']:.1f} |")


if __name__ == "__main__":
    main()
