"""Placement and optimize, before against after a change: time, profile, and compare their results.

Run from the repo root (the code imported is the checkout's):

- ``python -m bench.placement_check run CASE OUT.npz [--place-only] [--profile N]``: optimize (or only the pair
  search and placement) of CASE — a synthetic preset and seed (``default:1``, ``large:7``) or an ingested
  workspace (``ws:PATH``, e.g. bench_month's) — with the default config; writes the placement (every walk's
  frame, component, method), the initial and the optimized poses to OUT.npz and prints the phases' times and
  the machine's load; ``--profile N`` prints cProfile's N costliest functions of the placement.
- ``python -m bench.placement_check compare A.npz B.npz``: the largest difference of every array (0 = identical).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import time

import numpy as np


def load_case(case: str):
    """(dataset, fingerprints) of ``preset:seed`` or ``ws:PATH``."""
    if case.startswith("ws:"):
        from rmbuild.io.workspace import Workspace

        w = Workspace.open(case[3:])
        return w.read_dataset(readings=False), w.read_fingerprints()
    from bench.bench_optimize import _load

    preset, seed = case.split(":")
    return _load(preset, int(seed))


def place_only(ds, fp, cfg, profile: int) -> tuple[dict, dict]:
    """Pair search and placement as optimize runs them; (arrays, seconds per phase)."""
    from rmbuild.slam.evidence import default_sources
    from rmbuild.slam.pipeline import _reference_index
    from rmbuild.slam.placement import place
    from rmbuild.slam.problem import WalkSet

    t0 = time.perf_counter()
    walks, _ = WalkSet.from_dataset(ds, fp, cfg.single_step_walks, cfg.compass.default_sigma_rad)
    sources = default_sources(walks, cfg)
    t1 = time.perf_counter()
    prof = cProfile.Profile() if profile else None
    if prof:
        prof.enable()
    pl = place(walks, sources, cfg.placement, _reference_index(walks, cfg))
    if prof:
        prof.disable()
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(profile)
        print(s.getvalue())
    t2 = time.perf_counter()
    arrays = {"world_T_walk": pl.world_T_walk, "component": pl.component, "method": pl.method.astype(str),
              "initial_xyt": walks.apply_frames(pl.world_T_walk)}
    if pl.links is not None:
        arrays["link_k"], arrays["link_q"] = pl.links
    return arrays, {"pair_search_s": t1 - t0, "placement_s": t2 - t1}


def full(ds, fp, cfg) -> tuple[dict, dict]:
    """optimize as the stage runs it (no anchors, no plan); (arrays, seconds per phase)."""
    from rmbuild.slam import optimize

    r = optimize(ds, fp, cfg)
    cols = ["x_m", "y_m", "heading_rad"]
    wcols = ["world_T_walk_x_m", "world_T_walk_y_m", "world_T_walk_theta_rad", "rf_log_lr"]
    arrays = {"poses": r.poses[cols].to_numpy(float), "initial_poses": r.initial_poses[cols].to_numpy(float),
              "linked": r.poses["linked"].to_numpy(bool), "walks": r.walks[wcols].to_numpy(float),
              "walk_placement": r.walks["placement"].to_numpy(str), "component": r.walks["component"].to_numpy()}
    return arrays, {k: round(v, 2) for k, v in r.stats["time_s"].items()}


def run(case: str, out: str, only_place: bool, profile: int) -> None:
    from rmbuild.config import load_stage_config

    cfg = load_stage_config("optimize")
    ds, fp = load_case(case)
    load0 = os.getloadavg()[0]
    arrays, times = place_only(ds, fp, cfg, profile) if only_place else full(ds, fp, cfg)
    np.savez(out, **arrays)
    print(f"{case}: {times} (load {load0:.2f} -> {os.getloadavg()[0]:.2f}, {len(ds.poses):,} poses)")


def compare(a: str, b: str) -> int:
    """Print each array's largest difference; returns the number of arrays that differ."""
    A, B = np.load(a), np.load(b)
    bad = 0
    for k in sorted(set(A.files) | set(B.files)):
        if k not in A.files or k not in B.files or A[k].shape != B[k].shape:
            print(f"{k}: missing or shape differs")
            bad += 1
            continue
        x, y = A[k], B[k]
        if x.dtype.kind in "fc":
            same = np.array_equal(x, y, equal_nan=True)
            d = float(np.nanmax(np.abs(x - y))) if x.size else 0.0
        else:
            same, d = np.array_equal(x, y), float((x != y).sum())
        print(f"{k}: {'identical' if same else 'DIFFERS'} (max difference {d:.3g})")
        bad += not same
    return bad


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("case")
    r.add_argument("out")
    r.add_argument("--place-only", action="store_true")
    r.add_argument("--profile", type=int, default=0)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    a = ap.parse_args()
    if a.cmd == "run":
        run(a.case, a.out, a.place_only, a.profile)
    else:
        sys.exit(1 if compare(a.a, a.b) else 0)
