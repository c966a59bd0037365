"""How hard is a simulated venue? Raw dead-reckoning drift and the false-pair rate of Gu et al. 2017's
vicinity rule, measured against the truth (for tests, benchmarks and tuning the simulator)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.synthetic.simulate import SimulatedData


def raw_walk_errors(data: SimulatedData) -> pd.DataFrame:
    """Per walk: own-frame poses placed by the true start pose (world_T_walk) vs the true poses.

    Columns walk_id, n_steps, length_m (true path length), end_err_m, max_err_m.
    """
    starts = data.truth_walks.set_index("walk_id")
    own_xy = data.poses[["x_m", "y_m"]].to_numpy()
    true_xy = data.truth_poses[["x_m", "y_m"]].to_numpy()
    wid = data.poses["walk_id"].to_numpy()
    rows = []
    for w in data.walks["walk_id"]:
        m = wid == w
        x0, y0, th = starts.loc[w, ["x0_m", "y0_m", "heading0_rad"]].to_numpy(dtype=float)
        c, s = np.cos(th), np.sin(th)
        p = own_xy[m]
        placed = np.c_[x0 + c * p[:, 0] - s * p[:, 1], y0 + s * p[:, 0] + c * p[:, 1]]
        err = np.hypot(*(placed - true_xy[m]).T)
        length = float(np.hypot(*np.diff(true_xy[m], axis=0).T).sum())
        rows.append((w, int(m.sum()), length, float(err[-1]), float(err.max())))
    return pd.DataFrame(rows, columns=["walk_id", "n_steps", "length_m", "end_err_m", "max_err_m"])


@dataclass
class PairRuleStats:
    """Outcome of the pair rule of Gu et al. 2017 (eq. 9 distance under the median-window threshold) on the
    scan nodes of a simulated data set."""

    n_scan_nodes: int
    n_pairs: int  # cross-walk pairs (k, q) with d(k, q) < d_med(k) (ordered: k's rule)
    false_rate: float  # fraction of those pairs whose true distance exceeds far_m
    median_true_dist_m: float
    mean_aps_per_scan: float


def scan_fingerprints(data: SimulatedData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each scan attached to the pose nearest in time. Returns (walk index (n,), step index (n,), true
    positions (n, 2), RSSI matrix (n, n_bssid) with NaN for missing), one row per scan."""
    poses = data.poses
    walk_order = {w: i for i, w in enumerate(data.walks["walk_id"])}
    wifi = data.wifi
    keys = wifi[["walk_id", "t_s"]].drop_duplicates().reset_index(drop=True)
    scan_id = pd.MultiIndex.from_frame(keys).get_indexer(pd.MultiIndex.from_frame(wifi[["walk_id", "t_s"]]))
    bssids = np.array(sorted(wifi["bssid"].unique()))
    col = pd.Index(bssids).get_indexer(wifi["bssid"])
    rss = np.full((len(keys), len(bssids)), np.nan)
    rss[scan_id, col] = wifi["rssi_dbm"].to_numpy()
    walk_idx = keys["walk_id"].map(walk_order).to_numpy()
    step = np.empty(len(keys), dtype=np.int64)
    xy = np.empty((len(keys), 2))
    truth = data.truth_poses
    for w, g in keys.groupby("walk_id", sort=False):
        m = (poses["walk_id"] == w).to_numpy()
        t = poses.loc[m, "t_s"].to_numpy()
        k = np.clip(np.searchsorted(t, g["t_s"].to_numpy()), 1, len(t) - 1)
        k = np.where(np.abs(t[k - 1] - g["t_s"].to_numpy()) <= np.abs(t[k] - g["t_s"].to_numpy()), k - 1, k)
        step[g.index] = k
        xy[g.index] = truth.loc[m, ["x_m", "y_m"]].to_numpy()[k]
    return walk_idx, step, xy, rss


def rss_distance(a: np.ndarray, b: np.ndarray, fill_dbm: float = -110.0) -> np.ndarray:
    """(n, m) Gu et al. 2017 RSS distance between rows of a (n, B) and b (m, B) (NaN = missing): fill, then
    sqrt(sum of squared differences over the union of detected APs / size of the union)."""
    da, db = ~np.isnan(a), ~np.isnan(b)
    xa = np.where(da, a - fill_dbm, 0.0)
    xb = np.where(db, b - fill_dbm, 0.0)
    sq = (xa**2).sum(1)[:, None] + (xb**2).sum(1)[None, :] - 2.0 * xa @ xb.T
    union = da.sum(1)[:, None] + db.sum(1)[None, :] - da.astype(float) @ db.T.astype(float)
    return np.sqrt(np.maximum(sq, 0.0) / np.maximum(union, 1.0))


def pair_rule_stats(
    data: SimulatedData, half_window_steps: int = 10, fill_dbm: float = -110.0, far_m: float = 5.0,
    block: int = 2048,
) -> PairRuleStats:
    """Gu et al.'s rule on scan nodes: d_med(k) = median RSS distance from k to the other scan nodes of
    its walk within +-half_window_steps; a pair (k, q), q in another walk, when d(k, q) < d_med(k)."""
    walk, step, xy, rss = scan_fingerprints(data)
    n = len(walk)
    dmed = np.full(n, np.nan)
    for w in np.unique(walk):
        idx = np.flatnonzero(walk == w)
        d = rss_distance(rss[idx], rss[idx], fill_dbm)
        near = np.abs(step[idx][:, None] - step[idx][None, :]) <= half_window_steps
        np.fill_diagonal(near, False)
        for i in range(len(idx)):
            if near[i].any():
                dmed[idx[i]] = np.median(d[i, near[i]])
    n_pairs, n_far, dists = 0, 0, []
    for s in range(0, n, block):
        rows = np.arange(s, min(n, s + block))
        d = rss_distance(rss[rows], rss, fill_dbm)
        sel = (d < dmed[rows, None]) & (walk[rows, None] != walk[None, :])
        r, q = np.nonzero(sel)
        td = np.hypot(*(xy[rows[r]] - xy[q]).T)
        n_pairs += len(td)
        n_far += int((td > far_m).sum())
        dists.append(td)
    alld = np.concatenate(dists) if dists else np.zeros(0)
    return PairRuleStats(
        n_scan_nodes=n, n_pairs=n_pairs, false_rate=n_far / n_pairs if n_pairs else float("nan"),
        median_true_dist_m=float(np.median(alld)) if len(alld) else float("nan"),
        mean_aps_per_scan=float((~np.isnan(rss)).sum(1).mean()) if n else float("nan"),
    )
