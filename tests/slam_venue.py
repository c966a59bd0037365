"""A small, seeded synthetic venue for the slam package's tests and benchmarks (kept out of the package).

Not the product simulator (``rmbuild.synthetic``): a grid of corridors, APs with log-distance path loss
and a smooth shadowing field, walks that wander the corridor graph, foot-IMU-like dead reckoning in each
walk's own frame (start (0, 0, 0)), a disturbed magnetometer heading, and landmark fixes at corridor
crossings. Returns a :class:`Dataset` and :class:`Fingerprints` directly (no ingest needed).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.types import Dataset, Fingerprints


def walk_set(raw: np.ndarray, walk_of: np.ndarray, yaw_abs: np.ndarray | None = None, yaw_sigma: float = 0.1):
    """A :class:`rmbuild.slam.problem.WalkSet` from own-frame poses ``raw`` (n, 3) and the walk of each node
    (contiguous, 0..n_walks-1), one step per second, no fingerprints: for tests of the back end's parts."""
    from rmbuild.slam.problem import WalkSet

    raw = np.asarray(raw, float)
    walk_of = np.asarray(walk_of, np.int64)
    n_walks = int(walk_of.max()) + 1
    starts = np.searchsorted(walk_of, np.arange(n_walks))
    ends = np.searchsorted(walk_of, np.arange(n_walks), side="right")
    step_len = np.r_[0.0, np.hypot(*np.diff(raw[:, :2], axis=0).T)]
    step_len[starts] = 0.0
    path = np.cumsum(step_len)
    path -= np.repeat(path[starts], ends - starts)
    n = len(raw)
    yaw = np.full(n, np.nan) if yaw_abs is None else np.asarray(yaw_abs, float)
    fp = Fingerprints(np.zeros(0, np.int64), np.zeros(0, dtype=object), np.zeros((0, 0), np.float32),
                      np.zeros((0, 0), np.int32))
    return WalkSet([f"w{w}" for w in range(n_walks)], raw, walk_of, starts, ends, path,
                   np.arange(n, dtype=float), np.arange(n) - np.repeat(starts, ends - starts),
                   np.ones(n_walks, bool), yaw, np.full(n, yaw_sigma), fp)


def _route(rng, xs, ys, n_steps, step_m):
    """True positions (n_steps, 2) of a walk along the corridor grid (lines x in xs, y in ys)."""
    ix, iy = rng.integers(len(xs)), rng.integers(len(ys))
    pts = [np.array([xs[ix], ys[iy]], float)]
    total = 0.0
    prev = None
    while total < n_steps * step_m + 5:
        moves = []
        if ix > 0:
            moves.append((-1, 0))
        if ix < len(xs) - 1:
            moves.append((1, 0))
        if iy > 0:
            moves.append((0, -1))
        if iy < len(ys) - 1:
            moves.append((0, 1))
        if prev is not None and len(moves) > 1 and (-prev[0], -prev[1]) in moves and rng.random() < 0.85:
            moves.remove((-prev[0], -prev[1]))
        mv = moves[rng.integers(len(moves))]
        ix, iy = ix + mv[0], iy + mv[1]
        p = np.array([xs[ix], ys[iy]], float)
        total += np.linalg.norm(p - pts[-1])
        pts.append(p)
        prev = mv
    pts = np.array(pts)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.r_[0, np.cumsum(seg)]
    q = np.arange(n_steps) * step_m
    return np.c_[np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1])]


def make_venue(
    n_walks: int = 6,
    steps_per_walk: int = 300,
    seed: int = 0,
    size_m: tuple[float, float] = (100.0, 60.0),
    corridor_spacing_m: float = 20.0,
    n_aps: int = 40,
    step_m: float = 0.7,
    step_dt_s: float = 0.55,
    heading_known: bool = True,
    pdr_heading_noise_rad: float = 0.004,
    pdr_scale_sigma: float = 0.02,
    mag_disturbance_rad: float = 0.06,
    reading_noise_db: float = 8.0,
    shadow_db: float = 5.0,
    detect_dbm: float = -85.0,
) -> tuple[Dataset, Fingerprints]:
    """A seeded venue; one Wi-Fi scan per step (node). Walk frames are random (start pose unknown)."""
    rng = np.random.default_rng(seed)
    xs = np.arange(0, size_m[0] + 1e-9, corridor_spacing_m)
    ys = np.arange(0, size_m[1] + 1e-9, corridor_spacing_m)
    aps = np.c_[rng.uniform(-5, size_m[0] + 5, n_aps), rng.uniform(-5, size_m[1] + 5, n_aps)]
    p0 = rng.uniform(-40, -30, n_aps)
    # smooth shadowing: per AP a sum of 6 random plane waves (wavelengths 8-30 m)
    kvec = rng.normal(size=(n_aps, 6, 2))
    kvec *= (2 * np.pi / rng.uniform(8, 30, (n_aps, 6, 1))) / np.linalg.norm(kvec, axis=2, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, (n_aps, 6))
    mag_k = rng.normal(size=(4, 2)) * 2 * np.pi / 25
    mag_ph = rng.uniform(0, 2 * np.pi, 4)

    walks, poses, truth, wifi, fixes = [], [], [], [], []
    t0 = 0.0
    node = 0
    for w in range(n_walks):
        wid = f"w{w:03d}"
        xy = _route(rng, xs, ys, steps_per_walk, step_m)
        d = np.diff(xy, axis=0)
        hd = np.arctan2(d[:, 1], d[:, 0])
        hd = np.r_[hd, hd[-1]]
        # dead reckoning in the walk's own frame: first pose (0, 0, 0)
        dth = np.diff(np.unwrap(hd)) + rng.normal(0, pdr_heading_noise_rad, steps_per_walk - 1)
        lens = np.linalg.norm(d, axis=1) * (1 + rng.normal(0, pdr_scale_sigma)) + rng.normal(
            0, 0.01, steps_per_walk - 1
        )
        th = np.r_[0.0, np.cumsum(dth)]
        own = np.zeros((steps_per_walk, 2))
        own[1:] = np.cumsum(np.c_[lens * np.cos(th[:-1]), lens * np.sin(th[:-1])], axis=0)
        t = t0 + np.arange(steps_per_walk) * step_dt_s
        t0 = t[-1] + 100.0
        dist = (np.sin(xy @ mag_k.T + mag_ph) * mag_disturbance_rad).sum(axis=1) / 2
        yaw = hd + dist + rng.normal(0, 0.02, steps_per_walk)
        walks.append({"walk_id": wid, "device_id": "d0", "user_id": "u0", "role": "", "source": "slam_venue"})
        poses.append(pd.DataFrame({
            "walk_id": wid, "step": np.arange(steps_per_walk), "t_s": t, "x_m": own[:, 0], "y_m": own[:, 1],
            "heading_rad": th,
            "yaw_abs_rad": np.angle(np.exp(1j * yaw)) if heading_known else np.nan,
            "yaw_abs_sigma_rad": 0.1 if heading_known else np.nan, "step_freq_hz": 1 / step_dt_s,
        }))
        truth.append(pd.DataFrame({"walk_id": wid, "step": np.arange(steps_per_walk), "t_s": t,
                                   "x_m": xy[:, 0], "y_m": xy[:, 1], "heading_rad": hd}))
        # Wi-Fi: one reading per AP and step when above the detection level
        dd = np.linalg.norm(xy[:, None, :] - aps[None], axis=2)
        shadow = shadow_db * np.sin(np.einsum("nd,akd->nak", xy, kvec) + phase[None]).sum(axis=2) / np.sqrt(3)
        rss = p0[None] - 30 * np.log10(np.maximum(dd, 1.0)) + shadow
        rss = rss + rng.normal(0, reading_noise_db, rss.shape)
        r, c = np.nonzero(rss > detect_dbm)
        wifi.append(pd.DataFrame({
            "walk_id": wid, "t_s": t[r], "bssid": [f"ap{k:03d}" for k in c], "rssi_dbm": np.round(rss[r, c]),
            "freq_mhz": 2437.0, "ssid": "", "node": node + r,
        }))
        # landmark fixes: steps within 0.4 m of a corridor crossing, first step of each visit
        near = np.min(np.abs(xy[:, 0, None] - xs[None]), axis=1) ** 2 + np.min(
            np.abs(xy[:, 1, None] - ys[None]), axis=1) ** 2 < 0.4**2
        starts = np.flatnonzero(near & ~np.r_[False, near[:-1]])
        for k in starts:
            fixes.append({"walk_id": wid, "t_s": t[k], "x_m": xy[k, 0], "y_m": xy[k, 1], "label": f"x{k}"})
        node += steps_per_walk
    wifi_df = pd.concat(wifi, ignore_index=True)
    ds = Dataset(
        walks=pd.DataFrame(walks),
        poses=pd.concat(poses, ignore_index=True),
        wifi=wifi_df,
        fixes=pd.DataFrame(fixes, columns=["walk_id", "t_s", "x_m", "y_m", "label"]),
        truth_poses=pd.concat(truth, ignore_index=True),
    )
    return ds, Fingerprints.from_readings(wifi_df)


def false_pairs(frac: float, seed: int = 0):
    """A ``candidates_hook`` for :func:`rmbuild.slam.optimize` that replaces a fraction ``frac`` of the Wi-Fi
    candidate pairs by random cross-walk pairs of scanned nodes (marked ``injected``): the robustness test."""

    def hook(cand: pd.DataFrame, walks) -> pd.DataFrame:
        rng = np.random.default_rng(seed + 7919)
        n_bad = int(round(frac * len(cand)))
        if n_bad == 0:
            return cand
        drop = rng.choice(len(cand), n_bad, replace=False)
        keep = cand.drop(index=cand.index[drop]).copy()
        nodes = walks.fingerprints.node
        a, b = rng.choice(nodes, 4 * n_bad), rng.choice(nodes, 4 * n_bad)
        ok = walks.walk_of[a] != walks.walk_of[b]
        a, b = a[ok][:n_bad], b[ok][:n_bad]
        fake = pd.DataFrame({"node_k": np.minimum(a, b), "node_q": np.maximum(a, b), "rss_dist": np.nan,
                             "common": 0, "kind": "cross", "injected": True})
        return pd.concat([keep, fake], ignore_index=True)

    return hook


def split_walk(ds: Dataset, walk_id: str, n_pieces: int, gap_s: float, device: str = "dS") -> Dataset:
    """``ds`` with walk ``walk_id`` cut into ``n_pieces`` consecutive walks of one device (``device``):
    each piece in its own dead-reckoned frame (first pose at the origin), each starting ``gap_s`` after the
    previous one ended (later times of the walk's poses, readings and fixes are shifted). Node ids (rows
    of the poses table), and so the fingerprints, are unchanged."""
    from rmbuild import geometry

    poses = ds.poses.copy()
    rows = np.flatnonzero(poses["walk_id"].to_numpy() == walk_id)
    cuts = np.array_split(rows, n_pieces)
    walks, fixes, wifi = ds.walks.copy(), ds.fixes.copy(), ds.wifi.copy()
    truth = ds.truth_poses.copy() if ds.truth_poses is not None else None
    base = walks[walks["walk_id"] == walk_id].iloc[0].to_dict()
    new_walks = []
    for i, r in enumerate(cuts):
        wid = f"{walk_id}_{i}"
        t_lo, t_hi = poses.loc[r[0], "t_s"], poses.loc[r[-1], "t_s"]
        xyt = poses.loc[r, ["x_m", "y_m", "heading_rad"]].to_numpy(float)
        own = geometry.between(np.repeat(xyt[:1], len(r), axis=0), xyt)
        poses.loc[r, ["x_m", "y_m", "heading_rad"]] = own
        poses.loc[r, "walk_id"] = wid
        poses.loc[r, "step"] = np.arange(len(r))
        shift = i * gap_s
        poses.loc[r, "t_s"] += shift
        if truth is not None:
            truth.loc[r, "walk_id"], truth.loc[r, "t_s"] = wid, truth.loc[r, "t_s"] + shift
        for df in (fixes, wifi):
            m = (df["walk_id"] == walk_id) & (df["t_s"] >= t_lo - 1e-9) & (df["t_s"] <= t_hi + 0.5)
            df.loc[m, "walk_id"], df.loc[m, "t_s"] = wid, df.loc[m, "t_s"] + shift
        new_walks.append({**base, "walk_id": wid, "device_id": device})
    i = int(np.flatnonzero(walks["walk_id"].to_numpy() == walk_id)[0])
    walks = pd.concat([walks.iloc[:i], pd.DataFrame(new_walks), walks.iloc[i + 1:]], ignore_index=True)
    walks.loc[~walks["walk_id"].isin([w["walk_id"] for w in new_walks]), "device_id"] = [
        f"other{j}" for j in range(len(walks) - n_pieces)]
    return Dataset(walks=walks, poses=poses, wifi=wifi, fixes=fixes, truth_poses=truth, truth_aps=ds.truth_aps,
                   venue=ds.venue)
