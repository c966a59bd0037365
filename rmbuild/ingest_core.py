"""Shared validation of read input, and attachment of Wi-Fi readings to pose nodes (docs/data-format.md).

Pure: takes a :class:`RawInput` from any reader, returns the :class:`Dataset`, the per-node
:class:`Fingerprints` and a summary dict. Every problem is an :class:`InputError` naming file and row.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig
from rmbuild.errors import InputError
from rmbuild.io.formats.base import RawInput
from rmbuild.types import FIX_COLUMNS, POSE_COLUMNS, WALK_COLUMNS, WIFI_COLUMNS, Dataset, Fingerprints


def _where(raw: RawInput, table: str) -> Callable[[int], str]:
    return raw.where.get(table, lambda i: f"{table} row {i + 1}")


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


def _v(x: object) -> str:
    """repr of a value with numpy scalars shown as plain Python values."""
    return repr(x.item() if isinstance(x, np.generic) else x)


def _check_time_order(df: pd.DataFrame, where: Callable[[int], str], strict: bool, what: str) -> None:
    """Times must not go backwards within a walk (strictly increase when ``strict``), in file order."""
    codes, names = pd.factorize(df["walk_id"])
    t = df["t_s"].to_numpy(dtype=np.float64)
    # previous row of the same walk, in file order
    order = np.argsort(codes, kind="stable")
    cs, ts = codes[order], t[order]
    ws = np.asarray(names, dtype=object)[cs]
    same = cs[1:] == cs[:-1]
    dt = ts[1:] - ts[:-1]
    bad = same & ((dt <= 0) if strict else (dt < 0))
    if bad.any():
        k = _first(bad)
        row = int(order[k + 1])
        if dt[k] == 0:
            raise InputError(f"{what}: duplicate time t_s={_v(ts[k + 1])} in walk {_v(ws[k + 1])}", where(row))
        raise InputError(
            f"{what}: time goes backwards in walk {_v(ws[k + 1])} ({_v(ts[k])} -> {_v(ts[k + 1])})", where(row)
        )


def _merge_duplicate_readings(raw: RawInput) -> None:
    """Keep the first of repeated (walk, t_s, bssid) readings, for formats that allow them."""
    dup = raw.wifi.duplicated(subset=["walk_id", "t_s", "bssid"]).to_numpy()
    if not dup.any():
        return
    kept = np.flatnonzero(~dup)
    raw.wifi = raw.wifi.iloc[kept].reset_index(drop=True)
    orig = raw.where.get("wifi")
    if orig is not None:
        raw.where["wifi"] = lambda i: orig(int(kept[i]))
    raw.notes.append(f"merged {int(dup.sum()):,} Wi-Fi readings repeating a BSSID within one scan (first kept)")


def validate(raw: RawInput, cfg: IngestConfig) -> None:
    """Checks shared by every format (types and columns were checked by the reader)."""
    if raw.merge_duplicate_readings:
        _merge_duplicate_readings(raw)
    poses, wifi, fixes = raw.poses, raw.wifi, raw.fixes
    wp, ww, wf = _where(raw, "poses"), _where(raw, "wifi"), _where(raw, "fixes")
    if len(poses) == 0:
        raise InputError("no poses in the input")
    if len(wifi) == 0:
        raise InputError("no Wi-Fi readings in the input")
    for c in ("t_s", "x_m", "y_m", "heading_rad"):
        v = poses[c].to_numpy(dtype=np.float64)
        if not np.isfinite(v).all():
            raise InputError(f"poses: {c} is NaN or infinite", wp(_first(~np.isfinite(v))))
    _check_time_order(poses, wp, strict=True, what="poses")

    rssi = wifi["rssi_dbm"].to_numpy(dtype=np.float64)
    bad = ~np.isfinite(rssi) | (rssi < cfg.rssi_min_dbm) | (rssi > cfg.rssi_max_dbm)
    if bad.any():
        i = _first(bad)
        raise InputError(
            f"rssi_dbm {_v(rssi[i])} outside [{cfg.rssi_min_dbm:g}, {cfg.rssi_max_dbm:g}] dBm", ww(i)
        )
    if not np.isfinite(wifi["t_s"].to_numpy(dtype=np.float64)).all():
        raise InputError("wifi: t_s is NaN or infinite", ww(_first(~np.isfinite(wifi["t_s"].to_numpy()))))
    _check_time_order(wifi, ww, strict=False, what="wifi")
    dup = wifi.duplicated(subset=["walk_id", "t_s", "bssid"]).to_numpy()
    if dup.any():
        i = _first(dup)
        raise InputError(
            f"duplicate reading (walk {_v(wifi['walk_id'].iloc[i])}, t_s={_v(wifi['t_s'].iloc[i])}, "
            f"bssid {_v(wifi['bssid'].iloc[i])})",
            ww(i),
        )
    pose_walks = set(poses["walk_id"].unique())
    orphan = ~wifi["walk_id"].isin(pose_walks).to_numpy()
    if orphan.any():
        i = _first(orphan)
        raise InputError(f"Wi-Fi reading of walk {_v(wifi['walk_id'].iloc[i])}, which has no poses", ww(i))
    if len(fixes):
        orphan = ~fixes["walk_id"].isin(pose_walks).to_numpy()
        if orphan.any():
            i = _first(orphan)
            raise InputError(f"fix of walk {_v(fixes['walk_id'].iloc[i])}, which has no poses", wf(i))
        dup = fixes.duplicated(subset=["walk_id", "t_s"]).to_numpy()
        if dup.any():
            raise InputError("duplicate fix (same walk and time)", wf(_first(dup)))
    walks = raw.walks
    dup = walks["walk_id"].duplicated().to_numpy()
    if dup.any():
        raise InputError(f"duplicate walk_id {_v(walks['walk_id'].iloc[_first(dup)])}", _where(raw, "walks")(
            _first(dup)))
    missing = pose_walks - set(walks["walk_id"])
    if missing:
        raise InputError(f"walk {_v(sorted(missing)[0])} has poses but no row in the walks table")


def attach(poses: pd.DataFrame, wifi: pd.DataFrame, cfg: IngestConfig) -> np.ndarray:
    """Node id (row of ``poses``) of every reading, -1 where it lies too far outside its walk's poses.

    ``poses`` must be sorted by walk then time with a RangeIndex. "interval": node k takes the readings
    with t_k <= t < t_{k+1}; "nearest": the node nearest in time. Readings more than
    ``cfg.max_attach_gap_s`` before the first / after the last pose of the walk are not attached.
    """
    node = np.full(len(wifi), -1, dtype=np.int64)
    pw = poses["walk_id"].to_numpy()
    pt = poses["t_s"].to_numpy(dtype=np.float64)
    starts = np.r_[0, np.flatnonzero(pw[1:] != pw[:-1]) + 1]
    ends = np.r_[starts[1:], len(pw)]
    span = {pw[s]: (int(s), int(e)) for s, e in zip(starts, ends)}
    wt = wifi["t_s"].to_numpy(dtype=np.float64)
    groups = wifi.groupby("walk_id", sort=False).indices
    for wid, rows in groups.items():
        s, e = span[wid]
        t = pt[s:e]
        r = wt[rows]
        if cfg.attach == "interval":
            k = np.searchsorted(t, r, side="right") - 1
        else:
            k = np.clip(np.searchsorted(t, r), 1, max(len(t) - 1, 1))
            if len(t) > 1:
                k = np.where(np.abs(r - t[k - 1]) <= np.abs(t[k] - r), k - 1, k)
            else:
                k = np.zeros_like(k)
        k = np.clip(k, 0, len(t) - 1)
        ok = (r >= t[0] - cfg.max_attach_gap_s) & (r <= t[-1] + cfg.max_attach_gap_s)
        node[rows] = np.where(ok, s + k, -1)
    return node


def build_dataset(raw: RawInput, cfg: IngestConfig, source: str = "") -> tuple[Dataset, Fingerprints, dict]:
    """Validate, order, attach readings to nodes and average them into per-node fingerprints.

    ``source`` (the reader's format name) fills the walks' ``source`` column where the reader left it empty.
    """
    validate(raw, cfg)
    walks = raw.walks.copy()
    for c in WALK_COLUMNS:
        if c not in walks.columns:
            walks[c] = ""
    walks = walks[list(WALK_COLUMNS)]
    walks["source"] = walks["source"].where(walks["source"] != "", source)
    # keep only walks that have poses, in the walks table's order
    has_poses = walks["walk_id"].isin(raw.poses["walk_id"].unique())
    dropped_walks = walks.loc[~has_poses, "walk_id"].tolist()
    walks = walks[has_poses].reset_index(drop=True)
    walk_index = pd.Index(walks["walk_id"])

    poses = raw.poses.copy()
    poses["_w"] = walk_index.get_indexer(poses["walk_id"])
    poses = poses.sort_values(["_w", "t_s"], kind="stable").drop(columns="_w").reset_index(drop=True)
    poses["step"] = poses.groupby("walk_id", sort=False).cumcount().astype(np.int64)
    for c in ("yaw_abs_rad", "yaw_abs_sigma_rad", "step_freq_hz"):
        if c not in poses.columns:
            poses[c] = np.nan
    poses = poses[list(POSE_COLUMNS) + [c for c in poses.columns if c not in POSE_COLUMNS]]
    one_step = poses.groupby("walk_id", sort=False).size()
    one_step = one_step[one_step < 2]

    wifi = raw.wifi.copy()
    if "freq_mhz" not in wifi.columns:
        wifi["freq_mhz"] = np.nan
    if "ssid" not in wifi.columns:
        wifi["ssid"] = ""
    wifi["_w"] = walk_index.get_indexer(wifi["walk_id"])
    wifi = wifi.sort_values(["_w", "t_s"], kind="stable").drop(columns="_w").reset_index(drop=True)
    wifi["node"] = attach(poses, wifi, cfg)
    n_dropped = int((wifi["node"] < 0).sum())
    wifi = wifi[wifi["node"] >= 0].reset_index(drop=True)
    wifi = wifi[list(WIFI_COLUMNS)]
    wifi["rssi_dbm"] = wifi["rssi_dbm"].astype(np.float32)

    fixes = raw.fixes.copy()
    if "label" not in fixes.columns:
        fixes["label"] = ""
    fixes = fixes[list(FIX_COLUMNS) + [c for c in fixes.columns if c not in FIX_COLUMNS]].reset_index(drop=True)

    truth = raw.truth_poses
    if truth is not None:
        truth = _match_truth(poses, truth, raw, cfg.max_attach_gap_s)

    ds = Dataset(
        walks=walks, poses=poses, wifi=wifi, fixes=fixes, truth_poses=truth, truth_aps=raw.truth_aps,
        venue=raw.venue, extra={"truth": dict(raw.truth_extra)},
    )
    fp = Fingerprints.from_readings(wifi)
    scans = wifi.groupby(["walk_id", "t_s"], sort=False).ngroups
    summary = {
        "walks": len(walks),
        "poses": len(poses),
        "readings": len(wifi),
        "readings_dropped_outside_walk": n_dropped,
        "scans": int(scans),
        "nodes_with_fingerprint": len(fp),
        "aps": len(fp.bssids),
        "fixes": len(fixes),
        "has_truth_poses": truth is not None,
        "attach": cfg.attach,
        "skipped": dict(raw.skipped),
        "notes": list(raw.notes),
        "warnings": [],
    }
    if dropped_walks:
        summary["warnings"].append(f"{len(dropped_walks)} walk(s) without poses dropped: {dropped_walks[:5]}")
    if len(one_step):
        summary["warnings"].append(f"{len(one_step)} walk(s) with a single step: {list(one_step.index[:5])}")
    if n_dropped:
        summary["warnings"].append(
            f"{n_dropped} Wi-Fi reading(s) more than {cfg.max_attach_gap_s:g} s outside their walk's poses "
            "were not attached"
        )
    return ds, fp, summary


def _match_truth(poses: pd.DataFrame, truth: pd.DataFrame, raw: RawInput, max_gap_s: float) -> pd.DataFrame:
    """True poses at the rows of ``poses``: matched on (walk_id, t_s) where the times agree, otherwise
    interpolated in time along the walk's true track (e.g. steps found by the PDR), clamped to the ends up
    to ``max_gap_s``; a pose further outside its walk's truth is an error."""
    key = pd.MultiIndex.from_arrays([truth["walk_id"], truth["t_s"]])
    if key.has_duplicates:
        i = _first(key.duplicated())
        raise InputError("truth poses: duplicate (walk_id, t_s)", _where(raw, "truth/poses")(i))
    out = pd.DataFrame({"walk_id": poses["walk_id"].to_numpy(), "step": poses["step"].to_numpy(),
                        "t_s": poses["t_s"].to_numpy(float)})
    xyh = np.full((len(poses), 3), np.nan)
    tw = truth["walk_id"].to_numpy()
    for wid, rows in out.groupby("walk_id", sort=False).indices.items():
        g = truth[tw == wid].sort_values("t_s")
        t = out["t_s"].to_numpy()[rows]
        if len(g) == 0 or (t < g["t_s"].iloc[0] - max_gap_s).any() or (t > g["t_s"].iloc[-1] + max_gap_s).any():
            i = int(rows[0])
            raise InputError(
                f"truth poses do not cover pose (walk {_v(poses['walk_id'].iloc[i])}, "
                f"t_s={_v(poses['t_s'].iloc[i])})", "truth/poses")
        tt = g["t_s"].to_numpy(float)
        xyh[rows, 0] = np.interp(t, tt, g["x_m"].to_numpy(float))
        xyh[rows, 1] = np.interp(t, tt, g["y_m"].to_numpy(float))
        h = np.interp(t, tt, np.unwrap(g["heading_rad"].to_numpy(float)))
        xyh[rows, 2] = np.arctan2(np.sin(h), np.cos(h))
    out["x_m"], out["y_m"], out["heading_rad"] = xyh[:, 0], xyh[:, 1], xyh[:, 2]
    return out[["walk_id", "step", "t_s", "x_m", "y_m", "heading_rad"]]
