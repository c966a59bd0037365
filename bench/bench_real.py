"""`make bench-real`: the whole pipeline on every real floor that has ground truth, one table.

Run from the repo root: ``python -m bench.bench_real [--floors F1,F4,ipin] [--out real] [--scratch DIR]
[--jobs 1]``. Each stage (``ingest → optimize → export-map → evaluate``) runs through the CLI as a
subprocess of this Python, so the code measured is whatever ``rmbuild`` is on ``PYTHONPATH``; the figures
are then read back from the workspace (reports and tables, defensively: columns and report keys may come
and go as the back end changes). Writes ``bench/results/<out>.json`` (everything) and ``<out>.md`` (one
table + notes). Data: ``$RMBUILD_DATASETS``, default ``<repo>/../shared/datasets``; skips cleanly when
absent. Ground truth (surveyed waypoints) is used for scoring only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common import write_result

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATASETS = REPO.parent / "shared" / "datasets"


def ilc_data_root() -> Path:
    """The MS ILC 2.0 floors' directory under $RMBUILD_DATASETS (default: DEFAULT_DATASETS)."""
    return Path(os.environ.get("RMBUILD_DATASETS", DEFAULT_DATASETS)) / "msft-ilc20" / "data"
DEFAULT_SCRATCH = Path("/tmp/rmbuild-bench-real")
#: floor -> (folder under the dataset root, ingest --format)
FLOORS = {
    "site1/F1": ("msft-ilc20/data/site1/F1", "msft-ilc"),
    "site1/F2": ("msft-ilc20/data/site1/F2", "msft-ilc"),
    "site1/B1": ("msft-ilc20/data/site1/B1", "msft-ilc"),
    "site2/B1": ("msft-ilc20/data/site2/B1", "msft-ilc"),
    "site2/F1": ("msft-ilc20/data/site2/F1", "msft-ilc"),
    "site2/F4": ("msft-ilc20/data/site2/F4", "msft-ilc"),
    "site2/F6": ("msft-ilc20/data/site2/F6", "msft-ilc"),
    "ipin/-2": ("ipin2023/logs", "ipin"),
}
STAGES = ("ingest", "optimize", "export-map", "evaluate")
LINK_RADII_M, LINK_SHARED_M = (8.0, 12.0), 10.0  # "linkable": ≥ LINK_SHARED_M of true path within a radius
LINK_GAP_S = 60.0  # ... or the same device's next recording within this gap (starting within the radius)
SHARED_RADIUS_M = 5.0  # "shares its path": a point of the true path within this distance of another walk's
PATH_STEP_M = 0.5  # resampling step of the waypoint polylines (distance error ≤ a quarter of it)
RIGHT_M = 8.0  # a linked walk "placed right": its mean waypoint error in the consensus frame is within this
CONSENSUS_HYPOTHESES = 4000  # triples of linked walks tried for the consensus frame (all of them when fewer)
WORSE_THAN_M = 10.0  # a linked walk "placed badly": its mean waypoint error after optimisation exceeds this
#: per-walk columns that hold a predicted placement error (metres, larger = worse), in order of preference
PREDICTED_ERROR_COLUMNS = ("predicted_error_m", "placement_error_m", "confidence_m", "predicted_error")


# ---------------------------------------------------------------------------------------------- running
def rmbuild_root() -> Path:
    """The directory holding the ``rmbuild`` package this process imports (PYTHONPATH, else installed)."""
    import rmbuild

    return Path(rmbuild.__file__).resolve().parents[1]


def run_cli(args: list[str], log_path: Path) -> dict:
    """One ``python -m rmbuild ARGS`` subprocess: wall time (s), its own peak RSS (MB), return code.

    The subprocess imports the same ``rmbuild`` as this process (its root first on PYTHONPATH, and a
    working directory without a package of that name), so the code run is the code recorded."""
    path = os.pathsep.join(p for p in (str(rmbuild_root()), os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": path}
    t0 = time.perf_counter()
    with log_path.open("w") as log:
        p = subprocess.Popen([sys.executable, "-m", "rmbuild", *args], stdout=log, stderr=subprocess.STDOUT,
                             env=env, cwd=log_path.parent)
        _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return {"s": round(time.perf_counter() - t0, 2), "peak_mb": round(usage.ru_maxrss / 1024, 1),
            "rc": p.returncode}


def stage_args(stage: str, src: Path, fmt: str, ws: Path, config: Path | None = None) -> list[str]:
    if stage == "ingest":
        return ["ingest", str(src), "-w", str(ws), "--format", fmt, "--force", "-q"]
    extra = ["--config", str(config)] if config and stage == "optimize" else []
    return [stage, "-w", str(ws), "--force", "-q", *extra]


def run_pipeline(src: Path, fmt: str, ws: Path, config: Path | None = None) -> dict:
    """All stages in order on one floor; stops at the first failure (its log's last lines in ``error``)."""
    ws.parent.mkdir(parents=True, exist_ok=True)
    logs = ws.parent / f"{ws.name}.logs"
    logs.mkdir(exist_ok=True)
    out: dict = {}
    for stage in STAGES:
        log = logs / f"{stage}.log"
        r = run_cli(stage_args(stage, src, fmt, ws, config), log)
        out[stage] = r
        if r["rc"] != 0:
            out["error"] = f"{stage} exit {r['rc']}: " + " | ".join(log.read_text().strip().splitlines()[-3:])
            break
    return out


# ---------------------------------------------------------------------------------------------- geometry
def fit_se2(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid 2-D transform (no scale; Umeyama) with dst ≈ R @ src + t."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s))
    r = u @ np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    return r, mu_d - r @ mu_s


def at_fix_times(poses: pd.DataFrame, fixes: pd.DataFrame) -> np.ndarray:
    """(n_fixes, 2): each fix's walk position at the fix's time, linear between poses; NaN outside."""
    out = np.full((len(fixes), 2), np.nan)
    by_walk = {str(w): g for w, g in poses.groupby(poses["walk_id"].astype(str), sort=False)}
    fw = fixes["walk_id"].astype(str).to_numpy()
    ft = fixes["t_s"].to_numpy(float)
    for wid in np.unique(fw):
        g = by_walk.get(wid)
        if g is None or len(g) == 0:
            continue
        g = g.sort_values("t_s")
        tt = g["t_s"].to_numpy(float)
        m = (fw == wid) & (ft >= tt[0]) & (ft <= tt[-1])
        for j, col in enumerate(("x_m", "y_m")):
            out[m, j] = np.interp(ft[m], tt, g[col].to_numpy(float))
    return out


def aligned_errors(est: np.ndarray, truth: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """‖R est + t − truth‖ per point after one SE(2) fit on the finite points selected by ``fit``."""
    return np.linalg.norm(aligned_error_vectors(est, truth, fit), axis=1)


def aligned_error_vectors(est: np.ndarray, truth: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """(n, 2): R est + t − truth per point after one SE(2) fit on the finite points selected by ``fit``."""
    ok = np.isfinite(est).all(axis=1)
    use = fit & ok if (fit & ok).sum() >= 2 else ok
    if use.sum() < 2:
        return np.full((len(est), 2), np.nan)
    r, t = fit_se2(est[use], truth[use])
    return est @ r.T + t - truth


def resample_path(xy: np.ndarray, step: float = PATH_STEP_M) -> np.ndarray:
    """Points every ``step`` metres along the polyline ``xy`` (its vertices kept)."""
    if len(xy) < 2:
        return xy
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    ss = np.union1d(np.arange(0.0, s[-1], step), s)
    return np.c_[np.interp(ss, s, xy[:, 0]), np.interp(ss, s, xy[:, 1])]


def shared_path_share(fixes: pd.DataFrame) -> dict[str, float]:
    """Per walk: the share of its true path (waypoints joined by straight lines in time order) within
    SHARED_RADIUS_M of another walk's true path."""
    from scipy.spatial import cKDTree

    paths = {str(w): resample_path(g.sort_values("t_s")[["x_m", "y_m"]].to_numpy(float))
             for w, g in fixes.groupby(fixes["walk_id"].astype(str), sort=False)}
    out = {}
    for wid, pts in paths.items():
        others = [p for w, p in paths.items() if w != wid and len(p)]
        if not others or not len(pts):
            out[wid] = 0.0
            continue
        d, _ = cKDTree(np.vstack(others)).query(pts)
        out[wid] = float(np.mean(d <= SHARED_RADIUS_M))
    return out


def _true_at(g: pd.DataFrame, t: float) -> np.ndarray:
    return np.array([np.interp(t, g["t_s"], g["x_m"]), np.interp(t, g["t_s"], g["y_m"])])


def _device_joins(fixes: pd.DataFrame, walks: pd.DataFrame, poses: pd.DataFrame,
                  radius: float) -> list[tuple[str, str]]:
    """Consecutive recordings of one device (gap 0..LINK_GAP_S) whose true end and start lie within
    ``radius`` metres (true positions clamped to the first/last waypoint)."""
    span = poses.groupby(poses["walk_id"].astype(str))["t_s"].agg(["min", "max"])
    fx = {str(w): g.sort_values("t_s") for w, g in fixes.groupby(fixes["walk_id"].astype(str))}
    out = []
    for _, g in walks.groupby("device_id"):
        ids = sorted((w for w in g["walk_id"].astype(str) if w in span.index and w in fx),
                     key=lambda w: span.loc[w, "min"])
        for a, b in zip(ids, ids[1:]):
            gap = span.loc[b, "min"] - span.loc[a, "max"]
            near = np.linalg.norm(_true_at(fx[a], span.loc[a, "max"]) - _true_at(fx[b], span.loc[b, "min"]))
            if 0 <= gap <= LINK_GAP_S and near <= radius:
                out.append((a, b))
    return out


def linkable_walks(fixes: pd.DataFrame, walks: pd.DataFrame | None, poses: pd.DataFrame, radius: float) -> int:
    """What evidence of about ``radius`` metres' range can link at most: the walks of the largest group of
    the truth graph whose edges are walk pairs sharing ≥ LINK_SHARED_M of true path within ``radius``
    (both ways), or a device's consecutive recordings that truly continue nearby (:func:`_device_joins`)."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    paths = {str(w): resample_path(g.sort_values("t_s")[["x_m", "y_m"]].to_numpy(float))
             for w, g in fixes.groupby(fixes["walk_id"].astype(str), sort=False)}
    ids = [w for w, p in paths.items() if len(p)]
    if not ids:
        return 0
    index = {w: i for i, w in enumerate(ids)}
    trees = {w: cKDTree(paths[w]) for w in ids}
    adj = np.zeros((len(ids), len(ids)), bool)
    for i, a in enumerate(ids):
        for k in range(i + 1, len(ids)):
            b = ids[k]
            ab = (trees[b].query(paths[a])[0] <= radius).sum()
            ba = (trees[a].query(paths[b])[0] <= radius).sum()
            adj[i, k] = min(ab, ba) * PATH_STEP_M >= LINK_SHARED_M
    if walks is not None and "device_id" in walks:
        for a, b in _device_joins(fixes, walks, poses, radius):
            if a in index and b in index:
                adj[index[a], index[b]] = True
    _, label = connected_components(adj, directed=False)
    return int(np.bincount(label).max())


# ---------------------------------------------------------------------------------------------- reading
def read_table(ws: Path, key: str) -> pd.DataFrame | None:
    """A workspace table by its artefact key (file names belong to rmbuild.io.workspace); None if absent."""
    from rmbuild.io.workspace import ARTEFACTS

    rel = ARTEFACTS.get(key, key.replace(".", "/", 1) + ".parquet")
    p = ws / rel
    return pd.read_parquet(p) if p.is_file() else None


def need_table(ws: Path, key: str) -> pd.DataFrame:
    """A table every version writes (ingest's data, the optimised poses); FileNotFoundError otherwise."""
    df = read_table(ws, key)
    if df is None:
        raise FileNotFoundError(f"{ws}: no {key} table")
    return df


def read_report(ws: Path, stage: str) -> dict:
    """The stage's report where this rmbuild's workspace keeps it (or where earlier versions did)."""
    from rmbuild.io.workspace import Workspace

    for p in (Workspace(ws).report_path(stage), ws / "reports" / f"{stage}.json"):
        if p.is_file():
            return json.loads(p.read_text())
    return {}


def linked_walks(walks: pd.DataFrame | None, poses: pd.DataFrame) -> set[str]:
    """Walks the optimiser says it placed: optimize/walks ``linked``, else a ``linked`` column of the poses,
    else every walk (a back end that does not say)."""
    if walks is not None and "linked" in walks:
        return set(walks.loc[walks["linked"].astype(bool), "walk_id"].astype(str))
    if "linked" in poses:
        return set(poses.loc[poses["linked"].astype(bool), "walk_id"].astype(str))
    return set(poses["walk_id"].astype(str))


def nested(d: dict | None, *keys):
    """d[k1][k2]... or None when any level is missing."""
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


# ---------------------------------------------------------------------------------------------- metrics
def waypoint_errors(ws: Path, linked: set[str]) -> pd.DataFrame:
    """Per waypoint: walk_id, linked, err_raw (raw poses, one SE(2) fit on all walks), err_opt (optimised
    poses, one SE(2) fit on the linked walks' waypoints, as rmbuild's report fits them), err_all (err_opt
    for linked walks, err_raw for unlinked ones: unlinked walks counted at their raw placement)."""
    fixes = need_table(ws, "data.fixes")
    raw, opt = need_table(ws, "data.poses"), need_table(ws, "optimize.poses")
    truth = fixes[["x_m", "y_m"]].to_numpy(float)
    wid = fixes["walk_id"].astype(str).to_numpy()
    is_linked = np.isin(wid, list(linked))
    e_raw = aligned_errors(at_fix_times(raw, fixes), truth, np.ones(len(fixes), bool))
    est_opt = at_fix_times(opt, fixes)
    v_opt = aligned_error_vectors(est_opt, truth, is_linked)
    df = pd.DataFrame({"walk_id": wid, "linked": is_linked, "err_raw": e_raw, "err_opt": np.linalg.norm(v_opt, axis=1),
                       "dx_opt": v_opt[:, 0], "dy_opt": v_opt[:, 1], "ex": est_opt[:, 0], "ey": est_opt[:, 1],
                       "tx": truth[:, 0], "ty": truth[:, 1],
                       # no fit: meaningful only when the back end put the walks in the building frame itself
                       "err_opt_unaligned": np.linalg.norm(est_opt - truth, axis=1)})
    df["err_all"] = np.where(df["linked"], df["err_opt"], df["err_raw"])
    return df[np.isfinite(df["err_raw"])].reset_index(drop=True)


def consensus_errors(wp: pd.DataFrame, seed: int = 0) -> pd.Series:
    """Per linked walk with waypoints: its mean waypoint error (m) in the one rigid frame that puts the most
    linked walks within RIGHT_M of their waypoints. The frame is a RANSAC over triples of walks (each triple's
    waypoints fitted rigidly, Umeyama; all triples when there are at most CONSENSUS_HYPOTHESES, else as many
    drawn at random), the best refitted on its inlier walks until they no longer change: wrongly placed
    walks or groups cannot drag it, as they drag a least-squares fit of the whole map."""
    lk = wp[wp["linked"] & wp["ex"].notna()]
    codes, ids = pd.factorize(lk["walk_id"])
    n = len(ids)
    if n == 0:
        return pd.Series(dtype=float)
    est, tru = lk[["ex", "ey"]].to_numpy(float), lk[["tx", "ty"]].to_numpy(float)
    cnt = np.bincount(codes, minlength=n)

    def per_walk(on: np.ndarray) -> np.ndarray:
        m = on[codes]
        if m.sum() < 2:
            return np.full(n, np.inf)
        r, t = fit_se2(est[m], tru[m])
        return np.bincount(codes, np.linalg.norm(est @ r.T + t - tru, axis=1), n) / cnt

    from itertools import combinations
    from math import comb

    if n <= 3:
        hyps = [tuple(range(n))]
    elif comb(n, 3) <= CONSENSUS_HYPOTHESES:
        hyps = list(combinations(range(n), 3))
    else:
        rng = np.random.default_rng(seed)
        hyps = [tuple(rng.choice(n, 3, replace=False)) for _ in range(CONSENSUS_HYPOTHESES)]
    best, best_key = np.full(n, np.inf), (-1, 0.0)
    for h in hyps:
        on = np.zeros(n, bool)
        on[list(h)] = True
        e = per_walk(on)
        ok = e <= RIGHT_M
        key = (int(ok.sum()), -float(e[ok].sum()))
        if key > best_key:
            best, best_key = e, key
    for _ in range(10):  # refit on the inlier walks while that keeps at least as many
        inl = best <= RIGHT_M
        e = per_walk(inl)
        if (e <= RIGHT_M).sum() < inl.sum():
            break
        best = e
        if np.array_equal(e <= RIGHT_M, inl):
            break
    return pd.Series(best, index=ids)


def precision_block(per_walk: pd.DataFrame) -> dict:
    """Walks placed right (consensus error ≤ RIGHT_M) among the linked walks with waypoints, the others'
    median error, the same split by how each walk was placed, and the predicted error's rank correlation
    with the consensus error."""
    lk = per_walk[per_walk["linked"] & per_walk["err_consensus"].notna()]
    right = lk["err_consensus"] <= RIGHT_M
    out: dict = {"scored": len(lk), "right": int(right.sum()),
                 "precision": round(float(right.mean()), 3) if len(lk) else None,
                 "others_median_m": round(float(lk.loc[~right, "err_consensus"].median()), 1) if (~right).any()
                 else None}
    if "placement" in lk:
        kinds = lk["placement"].fillna("").astype(str)
        out["by_placement"] = {k: [int(right[kinds == k].sum()), int((kinds == k).sum())] for k in sorted(set(kinds))}
    col = next((c for c in PREDICTED_ERROR_COLUMNS if c in lk), None)
    out["rho_consensus"] = spearman(lk[col].to_numpy(float), lk["err_consensus"].to_numpy(float)) if col else None
    return out


def spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    from scipy.stats import spearmanr

    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or np.ptp(a[ok]) == 0 or np.ptp(b[ok]) == 0:
        return None
    return round(float(spearmanr(a[ok], b[ok]).statistic), 3)


def confidence_rank(per_walk: pd.DataFrame) -> dict:
    """Spearman rank correlation, over linked walks, of each per-walk confidence-like column with the real
    per-walk error (mean over the walk's waypoints after optimisation)."""
    lk = per_walk[per_walk["linked"]]
    cols = [c for c in (*PREDICTED_ERROR_COLUMNS, "confidence") if c in lk]
    rho = {c: spearman(lk[c].to_numpy(float), lk["err_opt"].to_numpy(float)) for c in cols}
    primary = next(iter(cols), None)
    return {"column": primary, "rho": rho.get(primary) if primary else None, "all": rho, "n": len(lk)}


def per_walk_table(ws: Path, wp: pd.DataFrame, walks: pd.DataFrame | None, shared: dict[str, float],
                   linked: set[str]) -> pd.DataFrame:
    """One row per walk: linked, mean waypoint errors raw / optimised / counted, shared path share and the
    optimiser's own per-walk columns (placement, confidence, ...) when it writes them."""
    dw = need_table(ws, "data.walks")
    g = wp.groupby("walk_id")[["err_raw", "err_opt", "err_all"]].mean()
    out = pd.DataFrame({"walk_id": dw["walk_id"].astype(str)})
    out["linked"] = out["walk_id"].isin(linked)
    out["n_waypoints"] = out["walk_id"].map(wp.groupby("walk_id").size()).fillna(0).astype(int)
    out = out.join(g, on="walk_id")
    out["shared_path_share"] = out["walk_id"].map(shared)
    out["err_consensus"] = out["walk_id"].map(consensus_errors(wp))
    if walks is not None:
        keep = [c for c in ("placement", "confidence", "component", "n_cross_pairs", "n_partner_walks",
                            *PREDICTED_ERROR_COLUMNS) if c in walks]
        out = out.merge(walks.assign(walk_id=walks["walk_id"].astype(str))[["walk_id", *keep]], on="walk_id",
                        how="left")
    return out


def landmark_block(wp: pd.DataFrame, per_walk: pd.DataFrame, gauge: str | None) -> dict:
    lk = wp[wp["linked"]]
    lw = per_walk[per_walk["linked"] & per_walk["err_opt"].notna()]

    def stats(e: pd.Series) -> dict | None:
        e = e.dropna()
        if not len(e):
            return None
        return {"mean": round(float(e.mean()), 2), "median": round(float(e.median()), 2), "n": len(e)}

    return {
        "raw": stats(wp["err_raw"]), "all_walks_unlinked_at_raw": stats(wp["err_all"]),
        "linked_walks": stats(lk["err_opt"]), "linked_walks_raw": stats(lk["err_raw"]),
        "linked_worse_than_raw": int((lw["err_opt"] > lw["err_raw"]).sum()),
        f"linked_over_{WORSE_THAN_M:g}m": int((lw["err_opt"] > WORSE_THAN_M).sum()),
        # a gauge other than "se2" (anchors, a floor plan) places the map in the building frame: no fit
        "linked_walks_building_frame": stats(lk["err_opt_unaligned"]) if gauge not in (None, "se2") else None,
    }


def offset_split(wp: pd.DataFrame) -> dict | None:
    """Where the linked walks' error sits: the mean over linked walks of |their mean error vector| (the walk's
    offset: where it sits) and of the mean error left once that offset is removed (its shape), metres."""
    lk = wp[wp["linked"] & wp["dx_opt"].notna()]
    if not len(lk):
        return None
    mean = lk.groupby("walk_id")[["dx_opt", "dy_opt"]].transform("mean")
    resid = np.hypot(lk["dx_opt"] - mean["dx_opt"], lk["dy_opt"] - mean["dy_opt"]).groupby(lk["walk_id"]).mean()
    off = np.hypot(*lk.groupby("walk_id")[["dx_opt", "dy_opt"]].mean().to_numpy().T)
    return {"offset_m": round(float(np.mean(off)), 2), "shape_m": round(float(resid.mean()), 2)}


def knn_block(ev: dict) -> dict:
    b, s = nested(ev, "maps", "built", "knn", "median"), nested(ev, "maps", "surveyed", "knn", "median")
    return {"built_median_m": b, "surveyed_median_m": s,
            "ratio": round(b / s, 2) if b is not None and s else None,
            "built_mean_m": nested(ev, "maps", "built", "knn", "mean"),
            "surveyed_mean_m": nested(ev, "maps", "surveyed", "knn", "mean"),
            "raw_median_m": nested(ev, "maps", "raw", "knn", "median")}


def true_node_xy(ws: Path) -> np.ndarray:
    """(n_poses, 2): each pose's true position, waypoint-interpolated in time (NaN outside the waypoints)."""
    fixes, poses = need_table(ws, "data.fixes"), need_table(ws, "data.poses")
    out = np.full((len(poses), 2), np.nan)
    pw, pt = poses["walk_id"].astype(str).to_numpy(), poses["t_s"].to_numpy(float)
    for wid, g in fixes.groupby(fixes["walk_id"].astype(str), sort=False):
        g = g.sort_values("t_s")
        ft = g["t_s"].to_numpy(float)
        m = (pw == wid) & (pt >= ft[0]) & (pt <= ft[-1])
        out[m] = np.c_[np.interp(pt[m], ft, g["x_m"]), np.interp(pt[m], ft, g["y_m"])]
    return out


def pairs_block(ws: Path) -> dict | None:
    """The final solve's vicinity pairs: how many, and the share whose nodes are truly < 5 m apart."""
    pairs = read_table(ws, "optimize.pairs")
    if pairs is None or not {"node_k", "node_q"} <= set(pairs):
        return None
    xy = true_node_xy(ws)
    d = np.linalg.norm(xy[pairs["node_k"].to_numpy(int)] - xy[pairs["node_q"].to_numpy(int)], axis=1)
    ok = np.isfinite(d)
    return {"pairs": len(pairs), "scored": int(ok.sum()),
            "true_lt_5m": round(float(np.mean(d[ok] < 5)), 3) if ok.any() else None}


def trimmed_report(rep: dict) -> dict:
    """The optimize report without its long lists (cost history; warnings cut to three)."""
    out = {k: v for k, v in rep.items() if k != "cost_history"}
    if isinstance(out.get("warnings"), list):
        out["n_warnings"], out["warnings"] = len(out["warnings"]), [w[:300] for w in out["warnings"][:3]]
    return out


def score_workspace(ws: Path) -> dict:
    """Every figure of one floor from a workspace that went through all stages."""
    rep, ev = read_report(ws, "optimize"), read_report(ws, "evaluate")
    walks, poses = read_table(ws, "optimize.walks"), need_table(ws, "optimize.poses")
    linked = linked_walks(walks, poses)
    fixes = need_table(ws, "data.fixes")
    shared = shared_path_share(fixes)
    wp = waypoint_errors(ws, linked)
    pw = per_walk_table(ws, wp, walks, shared, linked)
    n = len(pw)
    return {
        "walks": n,
        "shared_path_walks": int(sum(v >= 0.5 for v in shared.values())),
        "linkable": {f"{r:g}m": linkable_walks(fixes, read_table(ws, "data.walks"), need_table(ws, "data.poses"), r)
                     for r in LINK_RADII_M},
        "linked": int(pw["linked"].sum()), "linked_pct": round(100 * pw["linked"].mean(), 1) if n else None,
        "landmark_m": landmark_block(wp, pw, rep.get("gauge")),
        "linked_error_split": offset_split(wp),
        "report_landmark_m": {"raw": nested(rep, "raw", "landmark_error_m", "mean"),
                              "optimized": nested(rep, "optimized", "landmark_error_m", "mean"),
                              "optimized_unlinked_at_raw": nested(rep, "optimized", "landmark_error_unlinked_at_raw_m",
                                                                  "mean"),
                              "gauge": rep.get("gauge"), "fitted_on": nested(rep, "metrics_alignment", "fitted_on")},
        "precision": precision_block(pw),
        "knn": knn_block(ev),
        "confidence_rank": confidence_rank(pw),
        "vicinity_pairs": pairs_block(ws),
        "placement": pw["placement"].fillna("").value_counts().to_dict() if "placement" in pw else None,
        "optimize_report": trimmed_report(rep),
        "per_walk": json.loads(pw.to_json(orient="records", double_precision=3)),
    }


def measure_floor(name: str, root: Path, scratch: Path, config: Path | None = None) -> dict:
    rel, fmt = FLOORS[name]
    src = root / rel
    if not src.exists():
        return {"floor": name, "skipped": f"{src} not found"}
    ws = scratch / name.replace("/", "_")
    print(f"[bench-real] {name}: running {' → '.join(STAGES)} in {ws}", flush=True)
    run = run_pipeline(src, fmt, ws, config)
    out: dict = {"floor": name, "source": rel, "format": fmt, "stages": {s: run[s] for s in STAGES if s in run}}
    if "error" in run:
        out["error"] = run["error"]
        print(f"[bench-real] {name}: {run['error']}", flush=True)
        return out
    try:
        out.update(score_workspace(ws))
    except Exception as e:  # a back end that changed under the bench: one floor's error, not the run's
        out["error"] = f"scoring: {type(e).__name__}: {e}"
    print(f"[bench-real] {name}: {out.get('error', 'done')}", flush=True)
    return out


# ---------------------------------------------------------------------------------------------- output
def _f(v, fmt: str = "{:.1f}") -> str:
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)


def _pct(v: float | None) -> float | None:
    return None if v is None else 100 * v


def md_row(r: dict) -> str:
    if "skipped" in r or "error" in r:
        return f"| {r['floor']} | {r.get('skipped') or r.get('error')} |" + " |" * 10
    n, lm, k, pr = r["walks"], r["landmark_m"], r["knn"], r.get("precision") or {}
    conf = r["confidence_rank"]
    st = r["stages"]
    kinds = ", ".join(f"{kind or '?'} {a}/{b}" for kind, (a, b) in (pr.get("by_placement") or {}).items())
    cells = [
        r["floor"], str(n), f"{r['linked']} ({r['linked_pct']:.0f} %)",
        f"{pr.get('right', '–')} / {pr.get('scored', '–')} ({_f(_pct(pr.get('precision')), '{:.0f}')} %)",
        _f(pr.get("others_median_m")), kinds or "–",
        f"{_f(nested(lm, 'raw', 'mean'))} → {_f(nested(lm, 'all_walks_unlinked_at_raw', 'mean'))}",
        f"{_f(nested(lm, 'linked_walks', 'mean'))} / {_f(nested(lm, 'linked_walks', 'median'))}",
        f"{_f(k['built_median_m'])} / {_f(k['surveyed_median_m'])} ({_f(k['ratio'], '{:.2f}')}×)",
        f"{_f(conf['rho'], '{:+.2f}')} / {_f(pr.get('rho_consensus'), '{:+.2f}')}",
        " / ".join(_f(nested(st, s, "s"), "{:.0f}") for s in STAGES),
        _f(max((nested(st, s, "peak_mb") or 0) for s in STAGES), "{:.0f}"),
    ]
    return "| " + " | ".join(cells) + " |"


HEADER = ("| floor | walks | linked | placed right / linked walks scored (precision) | the others' median error m | "
          "by placement: right / scored | landmark error all walks, raw → optimised (unlinked at raw) m | "
          "linked walks mean / median m (one fit) | kNN median built / surveyed m | "
          "predicted error vs error ρ (one fit / consensus) | time ingest / optimize / export-map / evaluate s | "
          "peak MB |\n|" + "---|" * 12)

NOTES = """
- **Truth**: the surveyed waypoints (ILC `TYPE_WAYPOINT`, IPIN `POSI`), for scoring only. A walk's true path is
  its waypoints joined by straight lines in time order; a pose's true position is interpolated in time between
  them (none outside the first..last waypoint).
- **Shared path**: the true path resampled every 0.5 m; a walk counts when ≥ half its points lie within 5 m of
  another walk's resampled true path.
- **Linkable** (from the truth: what evidence of a given range could link at most): the walks of the largest
  group in which each walk is joined to another by ≥ 10 m of true path within 8 m (12 m) of it, both ways, or
  by being the same device's next recording (gap ≤ 60 s) that truly starts within 8 m (12 m) of where the last
  one ended. Wi-Fi vicinity (a band of ~6 m) links a walk outside the 8 m group only through weak, long-range
  evidence; the 12 m group is a loose upper bound.
- **Placed right**: a linked walk whose mean waypoint error is within 8 m in the *consensus frame*: the one
  rigid frame that puts the most linked walks within 8 m (a RANSAC over triples of linked walks, each triple's
  waypoints fitted rigidly, the best refitted on its inlier walks): wrongly placed walks cannot drag it as
  they drag one fit of the whole map. *Precision*: placed right / linked walks with waypoints. *The others*:
  the median consensus error of the linked walks not placed right. *By placement*: the same per
  `optimize/walks.parquet` `placement` (how the walk was placed).
- **Landmark error** (m, mean over waypoints): the walk's position at each waypoint time, linear between its
  poses, after **one** least-squares rigid SE(2) fit (Umeyama, no scale) for all walks together — as
  `rmbuild evaluate`/`optimize` score it. Raw: raw PDR poses, fit on all walks' waypoints. Optimised: the
  optimised poses, fit on the **linked** walks' waypoints only (an unlinked walk's frame is arbitrary).
  *All walks (unlinked at raw)*: linked walks' optimised errors together with unlinked walks' raw errors — the
  way "never worse than raw" is judged. *rmbuild's report*: the optimize report's own figure for the same
  (`optimized.landmark_error_unlinked_at_raw_m`; when every walk is linked, its all-walks figure).
  *Worse than raw*: linked walks whose mean waypoint error after optimisation exceeds their raw one (in
  brackets: linked walks above 10 m).
- **Offset / shape**: the linked walks' error split into where each walk sits (the mean over walks of the length
  of its mean error vector) and its shape (the mean error left once that offset is removed).
- **kNN**: median localisation error of `evaluate`'s kNN on its held-out walks with the map built from the
  optimised poses vs the map from surveyed positions.
- **ρ**: Spearman rank correlation over linked walks between the predicted error (`predicted_error_m`) and the
  walk's real mean waypoint error, after one fit of all linked walks / in the consensus frame (should be
  ≥ +0.5).
- **Time**: wall-clock of each CLI subprocess; peak MB is the largest of the stages' own peak RSS.
"""


def markdown(result: dict) -> str:
    code = result["code"]
    lines = ["# Real floors: the whole pipeline (`make bench-real`)", "",
             f"Code: {code.get('commit') or '?'}{' (uncommitted changes)' if code.get('dirty') else ''}; "
             f"data: `{result['dataset_root_name']}`; written by `python -m bench.bench_real` on "
             f"{result['date']}. {_config_line(result)}; every figure per floor in the JSON beside this file.", "",
             HEADER]
    lines += [md_row(r) for r in result["floors"]]
    return "\n".join(lines) + "\n" + NOTES


def _config_line(result: dict) -> str:
    cfg = result.get("optimize_config")
    return "Default config" if not cfg else "Optimize config: " + "; ".join(
        line.strip() for line in cfg.splitlines() if line.strip() and not line.lstrip().startswith("#"))


def code_identity() -> dict:
    pkg = rmbuild_root() / "rmbuild"

    def git(*a: str) -> str | None:
        p = subprocess.run(["git", *a], cwd=pkg, capture_output=True, text=True)
        return p.stdout.strip() if p.returncode == 0 else None

    status = git("status", "--porcelain", "--", "rmbuild")
    return {"rmbuild": str(pkg), "commit": git("rev-parse", "--short=12", "HEAD"), "dirty": bool(status)}


def select_floors(spec: str | None) -> list[str]:
    if not spec:
        return list(FLOORS)
    want = [s.strip().lower() for s in spec.split(",") if s.strip()]
    chosen = [f for f in FLOORS if any(w in (f.lower(), f.split("/")[-1].lower(), f.split("/")[0]) for w in want)]
    if not chosen:
        raise SystemExit(f"--floors {spec!r}: none of {', '.join(FLOORS)}")
    return chosen


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--floors", help=f"comma-separated subset of {', '.join(FLOORS)} (or F1, F4, ipin, ...)")
    ap.add_argument("--out", default="real", help="results name: bench/results/NAME.json and NAME.md")
    ap.add_argument("--scratch", type=Path, default=DEFAULT_SCRATCH, help="where the workspaces go")
    ap.add_argument("--jobs", type=int, default=1, help="floors run in parallel")
    ap.add_argument("--config", type=Path, help="an optimize config (TOML) instead of the defaults, e.g. a "
                                                "candidate default for bench.lofo")
    a = ap.parse_args(argv)
    root = Path(os.environ.get("RMBUILD_DATASETS", DEFAULT_DATASETS)).resolve()
    scratch = a.scratch.resolve()  # the stages run in their log directory
    if not root.is_dir():
        print(f"bench-real: no datasets at {root} (set RMBUILD_DATASETS); skipped")
        return 0
    floors = select_floors(a.floors)
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        config = a.config.resolve() if a.config else None
        rows = list(pool.map(lambda f: measure_floor(f, root, scratch, config), floors))
    result = {"code": code_identity(), "dataset_root_name": root.name, "date": time.strftime("%Y-%m-%d"),
              "optimize_config": a.config.read_text() if a.config else None, "floors": rows}
    p = write_result(a.out, result)
    md = p.with_suffix(".md")
    md.write_text(markdown(result))
    print(md.read_text())
    print(f"results: {p}, {md}")
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
