"""Plausibility checks of ingested evidence that are warnings, not errors (called by `rmbuild ingest`).

- A walk duplicated under another id (same steps, or same scans relative to its start): it would count
  twice as evidence and link perfectly to its copy.
- A walk much shorter than a vicinity link needs.
- A walk whose readings are offset from the other walks' at the same places (a device offset, e.g. a
  phone reading 10 dB stronger): co-located scans are found without positions, by the strongest AP they
  hear and the agreement of their readings after removing a constant, and the walk's median difference to
  the other walks is its offset. rmbuild's vicinity factors compare raw RSS, so such a walk links poorly;
  the ``slac`` localizer calibrates devices (RSS = k·φ + b, Li et al., "SLAC", seed 000) only when
  localizing.

Pure: takes a :class:`Dataset`, returns the warnings.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd

from rmbuild.types import Dataset

#: steps; a walk with fewer poses is too short to link by Wi-Fi (one scan every ~2-4 s, ~2 steps/s)
MIN_WALK_STEPS = 5
#: dB; a walk whose readings are at least this much above or below the others' at the same places is
#: reported (device offsets between phones are typically within ±5 dB)
OFFSET_WARN_DB = 6.0
#: scans compared for the device-offset check need this many APs in common
MIN_SHARED_APS = 5
#: dB; two scans are taken as co-located when their readings agree within this (median absolute deviation
#: of the differences after removing their median): a few metres apart in a typical building
COLOCATED_MAD_DB = 4.0
#: co-located scan pairs a walk needs before its offset is estimated
MIN_PAIRS = 10
#: scans kept per strongest-AP group (spread over the walks): bounds the work to ~O(groups x 40^2)
MAX_GROUP_SCANS = 40
#: groups (strongest APs) examined, largest first
MAX_GROUPS = 300


def evidence_warnings(ds: Dataset) -> list[str]:
    """Warnings about duplicated walks, very short walks and device offsets (empty when all is plausible)."""
    return duplicate_walks(ds) + short_walks(ds) + [
        f"walk {w!r} reads {off:+.1f} dB against the other walks at the same places (a device offset?); "
        "vicinity factors compare raw RSS, so it may stay unlinked; the slac localizer calibrates devices "
        "when localizing"
        for w, off in walk_rss_offsets(ds).items() if abs(off) >= OFFSET_WARN_DB
    ]


def _walk_digest(poses: pd.DataFrame, cols: list[str], t0: float) -> str:
    rel = poses[cols].to_numpy(dtype=np.float64).copy()
    rel[:, 0] -= t0
    return hashlib.sha1(np.round(rel, 4).tobytes()).hexdigest()


def duplicate_walks(ds: Dataset) -> list[str]:
    """Walks whose steps (relative times and own-frame poses) or scans (relative times, BSSIDs, RSSI)
    repeat another walk's."""
    seen: dict[str, str] = {}
    out: list[str] = []
    t0 = ds.poses.groupby("walk_id", sort=False)["t_s"].first()
    wifi = ds.wifi.sort_values(["walk_id", "t_s", "bssid"], kind="stable")
    scans = dict(iter(wifi.groupby("walk_id", sort=False)))
    for wid, g in ds.poses.groupby("walk_id", sort=False):
        keys = [("steps", _walk_digest(g, ["t_s", "x_m", "y_m", "heading_rad"], float(t0[wid])))]
        w = scans.get(wid)
        if w is not None and len(w):
            rel = np.round(w["t_s"].to_numpy(float) - float(t0[wid]), 3)
            text = "|".join(f"{t}/{b}/{r:.1f}" for t, b, r in zip(rel, w["bssid"], w["rssi_dbm"]))
            keys.append(("scans", hashlib.sha1(text.encode()).hexdigest()))
        if len(g) < 2:
            keys = keys[1:]  # one pose is no evidence of a copy
        for what, k in keys:
            other = seen.setdefault(k, str(wid))
            if other != str(wid):
                out.append(f"walk {str(wid)!r} repeats the {what} of walk {other!r} (a copy under another id?); "
                           "it counts twice as evidence: remove one of them")
                break
    return out


def short_walks(ds: Dataset) -> list[str]:
    n = ds.poses.groupby("walk_id", sort=False).size()
    short = n[(n >= 2) & (n < MIN_WALK_STEPS)]
    if not len(short):
        return []
    return [f"{len(short)} walk(s) with fewer than {MIN_WALK_STEPS} steps, too short to link by Wi-Fi: "
            f"{[str(w) for w in short.index[:5]]}"]


def walk_rss_offsets(ds: Dataset, seed: int = 0) -> dict[str, float]:
    """Each walk's median RSS difference (dB) to the other walks' co-located scans (walks with too few
    co-located pairs are left out)."""
    wifi = ds.wifi[["walk_id", "t_s", "bssid", "rssi_dbm"]]
    if wifi["walk_id"].nunique() < 3:
        return {}
    scan = wifi.groupby(["walk_id", "t_s"], sort=False).ngroup().to_numpy()
    n_aps = np.bincount(scan)
    keep = n_aps[scan] >= MIN_SHARED_APS
    wifi, scan = wifi[keep], scan[keep]
    if not len(wifi):
        return {}
    rssi = wifi["rssi_dbm"].to_numpy(np.float64)
    ap = pd.factorize(wifi["bssid"])[0]
    walk_codes, walk_names = pd.factorize(wifi["walk_id"])
    # the strongest AP of every scan names its group
    order = np.lexsort((-rssi, scan))
    first = order[np.r_[True, scan[order][1:] != scan[order][:-1]]]
    top = pd.Series(ap[first], index=scan[first])
    scan_walk = pd.Series(walk_codes[first], index=scan[first])
    rng = np.random.default_rng(seed)
    diffs: list[list[float]] = [[] for _ in walk_names]
    groups = top.groupby(top.to_numpy()).groups
    for _, members in sorted(groups.items(), key=lambda kv: -len(kv[1]))[:MAX_GROUPS]:
        m = np.asarray(members)
        if scan_walk[m].nunique() < 2:
            continue
        if len(m) > MAX_GROUP_SCANS:
            m = rng.choice(m, MAX_GROUP_SCANS, replace=False)
        _group_pairs(m, scan, ap, rssi, scan_walk, diffs)
    return {str(walk_names[w]): float(np.median(d)) for w, d in enumerate(diffs) if len(d) >= MIN_PAIRS}


def _group_pairs(members: np.ndarray, scan: np.ndarray, ap: np.ndarray, rssi: np.ndarray, scan_walk: pd.Series,
                 diffs: list[list[float]]) -> None:
    """Median differences of the co-located scan pairs of one group, added to both walks' lists."""
    sel = np.isin(scan, members)
    row = pd.Index(members).get_indexer(scan[sel])
    cols, col_ap = pd.factorize(ap[sel])
    mat = np.full((len(members), len(col_ap)), np.nan)
    mat[row, cols] = rssi[sel]
    d = mat[:, None, :] - mat[None, :, :]  # scans x scans x APs
    shared = np.isfinite(d).sum(axis=2)
    walks = scan_walk[members].to_numpy()
    iu, ju = np.triu_indices(len(members), 1)
    ok = (walks[iu] != walks[ju]) & (shared[iu, ju] >= MIN_SHARED_APS)
    if not ok.any():
        return
    iu, ju = iu[ok], ju[ok]
    dd = d[iu, ju]
    med = np.nanmedian(dd, axis=1)
    mad = np.nanmedian(np.abs(dd - med[:, None]), axis=1)
    for i, j, v in zip(iu[mad <= COLOCATED_MAD_DB], ju[mad <= COLOCATED_MAD_DB], med[mad <= COLOCATED_MAD_DB]):
        diffs[walks[i]].append(float(v))
        diffs[walks[j]].append(-float(v))
