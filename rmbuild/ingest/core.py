"""Shared validation of read input, and attachment of Wi-Fi (and BLE) readings to pose nodes
(docs/data-format.md).

Pure: takes a :class:`RawInput` from any reader, returns the :class:`Dataset`, the per-node
:class:`Fingerprints` and a summary dict. Every problem is an :class:`InputError` naming file and row.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.errors import InputError
from rmbuild.geometry import wrap
from rmbuild.ingest.checks import scan_ids, walk_time_ordered
from rmbuild.io.formats.base import RawImu, RawInput
from rmbuild.limits import MAX_APS, MAX_COORD_M, MAX_FINGERPRINT_CELLS, MAX_WALK_PATH_M, MAX_WALK_POSES
from rmbuild.pdr import ImuTimeError, PdrReport, run_pdr
from rmbuild.types import (
    BLE_COLUMNS,
    FIX_COLUMNS,
    POSE_COLUMNS,
    WALK_COLUMNS,
    WIFI_COLUMNS,
    Dataset,
    Fingerprints,
)

#: columns ingest adds to the walks table for walks whose poses come from the phone PDR (empty / NaN for
#: the others): steps, walking time (s), cadence (steps per walking second), walked length (m), heading
#: source, removed gyro bias (deg/s), quality flag ("ok", "suspect", "poor") and warnings ("; "-joined)
PDR_WALK_COLUMNS = ("pdr_steps", "pdr_walking_s", "pdr_cadence_hz", "pdr_length_m", "pdr_heading",
                    "pdr_gyro_bias_dps", "pdr_quality", "pdr_warnings")
#: time issues listed one by one in the ingest warnings per walk (the rest are counted)
MAX_TIME_ISSUES_LISTED = 3
#: Wi-Fi motion check (wifi_motion_check): s, the time between two scans compared; dBm, readings at least this
#: strong count; the fewest BSSIDs two scans must share; m, PDR distance below which the walker stood / above
#: which they walked between two scans; the fewest scan pairs for a verdict
WIFI_PAIR_S = (10.0, 30.0)
WIFI_MIN_DBM = -85.0
WIFI_MIN_COMMON = 3
WIFI_STILL_M, WIFI_MOVING_M = 0.5, 8.0
#: a walk standing still by its PDR is suspect when its scans change by this fraction of the walking median
#: or more: measured on the IPIN 2023 walks, standing 2-4 dB (at most 0.6 of the walking median, 6.4 dB)
WIFI_WALKING_FRACTION = 0.75
WIFI_MIN_PAIRS = 6
#: bounds of the check's work per walk: BSSIDs compared (the most heard) and scan pairs (evenly thinned)
WIFI_MAX_APS, WIFI_MAX_PAIRS = 300, 20000


def _where(raw: RawInput, table: str) -> Callable[[int], str]:
    return raw.where.get(table, lambda i: f"{table} row {i + 1}")


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


def _v(x: object) -> str:
    """repr of a value with numpy scalars shown as plain Python values."""
    return repr(x.item() if isinstance(x, np.generic) else x)


def _check_time_order(df: pd.DataFrame, where: Callable[[int], str], strict: bool, what: str
                      ) -> tuple[np.ndarray, pd.Index]:
    """Times must not go backwards within a walk (strictly increase when ``strict``), in file order.
    Returns the walk codes of the rows and the walk ids (``pd.factorize``, a missing id counting as one)."""
    codes, names = pd.factorize(df["walk_id"], use_na_sentinel=False)
    t = df["t_s"].to_numpy(dtype=np.float64)
    # previous row of the same walk, in file order
    order = np.argsort(codes, kind="stable")
    cs, ts = codes[order], t[order]
    same = cs[1:] == cs[:-1]
    dt = ts[1:] - ts[:-1]
    bad = same & ((dt <= 0) if strict else (dt < 0))
    if bad.any():
        k = _first(bad)
        row = int(order[k + 1])
        wid = names[cs[k + 1]]
        if dt[k] == 0:
            raise InputError(f"{what}: duplicate time t_s={_v(ts[k + 1])} in walk {_v(wid)}", where(row))
        raise InputError(
            f"{what}: time goes backwards in walk {_v(wid)} ({_v(ts[k])} -> {_v(ts[k + 1])})", where(row)
        )
    return codes, pd.Index(names)


def _merge_duplicate_readings(raw: RawInput, table: str = "wifi") -> None:
    """Keep the first of repeated (walk, t_s, bssid) readings of ``table`` ("wifi" or "ble"), for formats that
    allow them."""
    df = getattr(raw, table)
    dup = df.duplicated(subset=["walk_id", "t_s", "bssid"]).to_numpy()
    if not dup.any():
        return
    kept = np.flatnonzero(~dup)
    setattr(raw, table, df.iloc[kept].reset_index(drop=True))
    orig = raw.where.get(table)
    if orig is not None:
        raw.where[table] = lambda i: orig(int(kept[i]))
    what = "Wi-Fi readings repeating a BSSID" if table == "wifi" else "BLE readings repeating a beacon"
    raw.notes.append(f"merged {int(dup.sum()):,} {what} within one scan (first kept)")


def _check_readings(df: pd.DataFrame, where: Callable[[int], str], cfg: IngestConfig, table: str,
                    pose_walks: set) -> tuple[np.ndarray, pd.Index]:
    """The checks of one readings table (``table``: "wifi" or "ble"): RSSI range, finite times not going
    backwards within a walk, no repeated (walk, t_s, bssid), no walk without poses. Returns its walk codes and
    ids (``pd.factorize``)."""
    label, pre = ("Wi-Fi", "") if table == "wifi" else ("BLE", "ble: ")
    rssi = df["rssi_dbm"].to_numpy(dtype=np.float64)
    bad = ~np.isfinite(rssi) | (rssi < cfg.rssi_min_dbm) | (rssi > cfg.rssi_max_dbm)
    if bad.any():
        i = _first(bad)
        raise InputError(
            f"{pre}rssi_dbm {_v(rssi[i])} outside [{cfg.rssi_min_dbm:g}, {cfg.rssi_max_dbm:g}] dBm", where(i)
        )
    if not np.isfinite(df["t_s"].to_numpy(dtype=np.float64)).all():
        raise InputError(f"{table}: t_s is NaN or infinite", where(_first(~np.isfinite(df["t_s"].to_numpy()))))
    codes, walk_ids = _check_time_order(df, where, strict=False, what=table)
    i = _first_repeated_reading(df, codes)
    if i >= 0:
        raise InputError(
            f"duplicate {'' if table == 'wifi' else 'BLE '}reading (walk {_v(df['walk_id'].iloc[i])}, "
            f"t_s={_v(df['t_s'].iloc[i])}, "
            f"bssid {_v(df['bssid'].iloc[i])})",
            where(i),
        )
    orphan = ~walk_ids.isin(pose_walks)[codes]
    if orphan.any():
        i = _first(orphan)
        raise InputError(f"{label} reading of walk {_v(df['walk_id'].iloc[i])}, which has no poses", where(i))
    return codes, walk_ids


def validate(raw: RawInput, cfg: IngestConfig) -> dict[str, tuple[np.ndarray, pd.Index]]:
    """Checks shared by every format (types and columns were checked by the reader). Returns the walk codes
    and walk ids of ``raw.poses``, ``raw.wifi`` (and ``raw.ble``) rows (``pd.factorize``), for the ordering that
    follows."""
    if raw.merge_duplicate_readings:
        _merge_duplicate_readings(raw)
        if raw.ble is not None:
            _merge_duplicate_readings(raw, "ble")
    poses, wifi, fixes = raw.poses, raw.wifi, raw.fixes
    wp, ww, wf = _where(raw, "poses"), _where(raw, "wifi"), _where(raw, "fixes")
    if len(poses) == 0:
        raise InputError("no poses in the input")
    if len(wifi) == 0:  # every walk without Wi-Fi: name the first walk's source
        first = next(iter(raw.imu.values())).source if raw.imu else wp(0)
        raise InputError("no Wi-Fi readings in any input file: nothing to build a radio map from", first)
    for c in ("t_s", "x_m", "y_m", "heading_rad"):
        v = poses[c].to_numpy(dtype=np.float64)
        if not np.isfinite(v).all():
            raise InputError(f"poses: {c} is NaN or infinite", wp(_first(~np.isfinite(v))))
    _check_positions(poses, wp, "poses")
    pose_codes, pose_walk_ids = _check_time_order(poses, wp, strict=True, what="poses")
    _check_walk_size(poses, pose_codes, pose_walk_ids, wp)

    pose_walks = set(pose_walk_ids)
    codes = {"poses": (pose_codes, pose_walk_ids), "wifi": _check_readings(wifi, ww, cfg, "wifi", pose_walks)}
    if raw.ble is not None and len(raw.ble):
        codes["ble"] = _check_readings(raw.ble, _where(raw, "ble"), cfg, "ble", pose_walks)
    if raw.truth_poses is not None and len(raw.truth_poses):
        _check_positions(raw.truth_poses, _where(raw, "truth/poses"), "truth poses")
    if len(fixes):
        _check_positions(fixes, wf, "fixes")
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
        wid = sorted(missing)[0]
        raise InputError(f"walk {_v(wid)} has poses but no row in the walks table",
                         wp(_first((poses["walk_id"] == wid).to_numpy())))
    return codes


def _check_positions(df: pd.DataFrame, where: Callable[[int], str], what: str) -> None:
    """x_m and y_m within :data:`MAX_COORD_M` of the origin (a position beyond it is no position)."""
    for c in ("x_m", "y_m"):
        v = np.abs(df[c].to_numpy(dtype=np.float64))
        far = ~(v <= MAX_COORD_M)  # NaN too
        if far.any():
            i = _first(far)
            raise InputError(f"{what}: {c} {float(df[c].iloc[i]):.10g} is more than {MAX_COORD_M:g} m from the origin "
                             "(the limit of a position)", where(i))


def _check_walk_size(poses: pd.DataFrame, codes: np.ndarray, walk_ids: pd.Index, where: Callable[[int], str]) -> None:
    """At most :data:`MAX_WALK_POSES` poses and :data:`MAX_WALK_PATH_M` of path (the sum of the steps) in
    each walk; the error names the first pose beyond the limit."""
    n = np.bincount(codes, minlength=len(walk_ids))
    if (n > MAX_WALK_POSES).any():
        w = int(np.argmax(n > MAX_WALK_POSES))
        row = int(np.flatnonzero(codes == w)[MAX_WALK_POSES])
        raise InputError(f"walk {_v(walk_ids[w])} has {int(n[w]):,} poses: at most {MAX_WALK_POSES:,} in one walk "
                         "(split it into several walks)", where(row))
    order = np.argsort(codes, kind="stable")
    c = codes[order]
    x, y = (poses[k].to_numpy(np.float64)[order] for k in ("x_m", "y_m"))
    step = np.hypot(np.diff(x), np.diff(y))
    step[c[1:] != c[:-1]] = 0.0
    path = np.r_[0.0, np.cumsum(step)]
    path -= path[np.searchsorted(c, c)]  # metres walked within the row's walk up to the row
    if (path > MAX_WALK_PATH_M).any():
        k = _first(path > MAX_WALK_PATH_M)
        raise InputError(f"walk {_v(walk_ids[c[k]])}: its steps add up to more than {MAX_WALK_PATH_M:g} m by this "
                         "pose (the limit of one walk's path; are the positions in metres?)", where(int(order[k])))


def _check_fingerprint_size(readings: pd.DataFrame, where: Callable[[int], str], label: str, keys: str) -> None:
    """The dense per-node table of ``readings`` (attached ones: nodes × distinct keys) has at most
    :data:`MAX_FINGERPRINT_CELLS` cells; checked before it is allocated."""
    if not len(readings):
        return
    n_nodes = int(pd.unique(readings["node"]).size)
    n_keys = int(readings["bssid"].nunique())
    if n_keys > MAX_APS:
        raise InputError(f"{n_keys:,} distinct {keys} in the {label} readings of one floor: at most {MAX_APS:,} (the "
                         f"optimizer compares scans over every one of them; drop {keys} heard only once or twice, "
                         "e.g. phones' hotspots)", where(0).rsplit(":", 1)[0])
    if n_nodes * n_keys > MAX_FINGERPRINT_CELLS:
        raise InputError(f"{n_nodes:,} poses with {label} readings of {n_keys:,} distinct {keys}: a fingerprint table "
                         f"of {n_nodes * n_keys:,} cells, at most {MAX_FINGERPRINT_CELLS:,} (split the input, or "
                         f"drop {keys} heard only once or twice)", where(0).rsplit(":", 1)[0])


def _first_repeated_reading(wifi: pd.DataFrame, walk_codes: np.ndarray) -> int:
    """The first row repeating an earlier row's (walk, t_s, bssid), -1 when none (as ``DataFrame.duplicated``).
    Rows ordered by walk and time (the usual file) are keyed by scan run and BSSID code: no hashing of text
    pairs."""
    t = wifi["t_s"].to_numpy(dtype=np.float64)
    if walk_time_ordered(walk_codes, t):
        scan = scan_ids(walk_codes, t)  # equal (walk, time) rows are one run here
        b, uniq = pd.factorize(wifi["bssid"], use_na_sentinel=False)
        key = scan * max(len(uniq), 1) + b
        if not (np.diff(np.sort(key)) == 0).any():  # a sort finds that there is none (the usual case)
            return -1
        dup = pd.Series(key).duplicated().to_numpy()
    else:
        dup = wifi.duplicated(subset=["walk_id", "t_s", "bssid"]).to_numpy()
    return _first(dup) if dup.any() else -1


def attach(poses: pd.DataFrame, pose_walk: np.ndarray, wifi: pd.DataFrame, wifi_walk: np.ndarray,
           cfg: IngestConfig) -> np.ndarray:
    """Node id (row of ``poses``) of every reading, -1 where it lies too far outside its walk's poses.

    ``poses`` must be sorted by walk then time with a RangeIndex; ``pose_walk``, ``wifi_walk``: the walk
    number of each pose (ascending) and of each reading. "interval": node k takes the readings with
    t_k <= t < t_{k+1}; "nearest": the node nearest in time. Readings more than ``cfg.max_attach_gap_s``
    before the first / after the last pose of the walk are not attached.
    """
    node = np.full(len(wifi), -1, dtype=np.int64)
    pt = poses["t_s"].to_numpy(dtype=np.float64)
    wt = wifi["t_s"].to_numpy(dtype=np.float64)
    n_walks = int(max(pose_walk.max(initial=-1), wifi_walk.max(initial=-1))) + 1
    span = np.searchsorted(pose_walk, np.arange(n_walks + 1))
    by_walk = np.argsort(wifi_walk, kind="stable")
    cuts = np.searchsorted(wifi_walk[by_walk], np.arange(n_walks + 1))
    for w in np.flatnonzero(np.diff(cuts)):
        rows = by_walk[cuts[w]:cuts[w + 1]]
        s, e = int(span[w]), int(span[w + 1])
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


def _pdr_one(wid: str, imu: RawImu, pdr_cfg: PdrConfig) -> tuple[pd.DataFrame, PdrReport, list[str]]:
    """Poses, report and located warnings of one walk's raw IMU; problems -> InputError naming the file."""
    try:
        res = run_pdr(imu.signals, pdr_cfg)
    except ImuTimeError as e:
        raise InputError(f"walk {wid!r}: {e}", imu.where(e.stream, e.index)) from None
    except ValueError as e:
        raise InputError(f"walk {wid!r}: PDR failed: {e}", imu.source) from None
    rep = res.report
    issues = rep.time_issues
    warn = [f"{imu.where(i.stream, i.index)}: {i.message}" for i in issues[:MAX_TIME_ISSUES_LISTED]]
    if len(issues) > MAX_TIME_ISSUES_LISTED:
        warn.append(f"{imu.source}: {len(issues) - MAX_TIME_ISSUES_LISTED} more timestamp problem(s)")
    warn += [f"{imu.source}: walk {wid!r}: PDR {rep.quality}: {w}" for w in rep.warnings]
    return res.poses.to_frame(wid), rep, warn


def derive_poses(raw: RawInput, pdr_cfg: PdrConfig, on_walk: Callable[[str], None] | None = None
                 ) -> tuple[dict[str, PdrReport], list[str]]:
    """Run the phone PDR on every walk of ``raw.imu`` and append the poses to ``raw.poses`` (with row names
    "file (PDR step k)"). Returns the per-walk reports and the warnings (file:line where one applies).
    ``on_walk(walk_id)`` is called after each walk (progress)."""
    if not raw.imu:
        return {}, []
    have = set(raw.poses["walk_id"].unique()) if len(raw.poses) else set()
    both = [w for w in raw.imu if w in have]
    if both:
        raise InputError(f"walk {both[0]!r} has both poses and raw IMU; give one of them",
                         raw.imu[both[0]].where("acc", 0))
    frames, reports, warnings = [], {}, []
    for wid, imu in raw.imu.items():
        df, reports[wid], warn = _pdr_one(wid, imu, pdr_cfg)
        frames.append(df)
        warnings += warn
        if on_walk is not None:
            on_walk(wid)
    n0 = len(raw.poses)
    new = pd.concat(frames, ignore_index=True)
    raw.poses = pd.concat([raw.poses, new], ignore_index=True) if n0 else new
    before = raw.where.get("poses")
    src = {w: imu.source for w, imu in raw.imu.items()}
    nw, ns = new["walk_id"].to_numpy(), new["step"].to_numpy()
    raw.where["poses"] = lambda i: (before(i) if before is not None and i < n0 else
                                    f"{src[nw[i - n0]]} (PDR step {int(ns[i - n0])})")
    steps = sum(r.steps for r in reports.values())
    srcs = sorted({r.heading_source for r in reports.values()})
    raw.notes.append(f"phone PDR: {steps:,} steps in {len(reports)} walk(s) (heading: {', '.join(srcs)})")
    return reports, warnings


def _pdr_columns(walks: pd.DataFrame, reports: dict[str, PdrReport]) -> pd.DataFrame:
    """The walks table with the PDR_WALK_COLUMNS filled from ``reports`` (missing walks: NaN / "")."""
    out = walks.copy()
    r = [reports.get(str(w)) for w in out["walk_id"]]
    num = lambda f: [float(f(x)) if x is not None else np.nan for x in r]  # noqa: E731
    txt = lambda f: [str(f(x)) if x is not None else "" for x in r]  # noqa: E731
    out["pdr_steps"] = pd.array([x.steps if x is not None else None for x in r], dtype="Int64")
    out["pdr_walking_s"] = num(lambda x: x.walking_s)
    out["pdr_cadence_hz"] = num(lambda x: x.cadence_hz)
    out["pdr_length_m"] = num(lambda x: x.walked_m)
    out["pdr_heading"] = txt(lambda x: x.heading_source)
    out["pdr_gyro_bias_dps"] = num(lambda x: x.gyro_bias_dps)
    out["pdr_quality"] = txt(lambda x: x.quality)
    out["pdr_warnings"] = txt(lambda x: "; ".join(x.warnings))
    return out


def _scan_pairs(poses: pd.DataFrame, wifi: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of one walk's scans WIFI_PAIR_S apart: the mean absolute RSSI difference over the BSSIDs both
    hear above WIFI_MIN_DBM (at least WIFI_MIN_COMMON of them), and the PDR distance walked between them."""
    w = wifi[wifi["rssi_dbm"] >= WIFI_MIN_DBM]
    t, scan = np.unique(w["t_s"].to_numpy(float), return_inverse=True)
    bssids, ap, n_ap = np.unique(w["bssid"].to_numpy(), return_inverse=True, return_counts=True)
    if len(t) < 2:
        return np.zeros(0), np.zeros(0)
    # bounded work whatever the input: the most heard BSSIDs, and evenly thinned pairs
    keep_ap = np.argsort(-n_ap, kind="stable")[:WIFI_MAX_APS]
    col = np.full(len(bssids), -1)
    col[keep_ap] = np.arange(len(keep_ap))
    r = np.full((len(t), len(keep_ap)), np.nan)
    sel = col[ap] >= 0
    r[scan[sel], col[ap[sel]]] = w["rssi_dbm"].to_numpy(float)[sel]
    lo = np.searchsorted(t, t + WIFI_PAIR_S[0], side="left")
    hi = np.searchsorted(t, t + WIFI_PAIR_S[1], side="right")
    n = hi - lo
    i = np.repeat(np.arange(len(t)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
    if len(i) > WIFI_MAX_PAIRS:
        k = np.linspace(0, len(i) - 1, WIFI_MAX_PAIRS).astype(np.int64)
        i, j = i[k], j[k]
    diff = np.abs(r[i] - r[j])
    common = np.isfinite(diff).sum(axis=1)
    ok = common >= WIFI_MIN_COMMON
    d_rssi = np.nansum(np.where(np.isfinite(diff), diff, 0.0), axis=1)[ok] / common[ok]
    dist = np.r_[0.0, np.cumsum(np.hypot(np.diff(poses["x_m"].to_numpy(float)), np.diff(poses["y_m"].to_numpy(float))))]
    at = dist[np.clip(np.searchsorted(poses["t_s"].to_numpy(float), t, side="right") - 1, 0, len(dist) - 1)]
    return d_rssi, (at[j] - at[i])[ok]


def wifi_motion_check(poses: pd.DataFrame, wifi: pd.DataFrame, reports: dict[str, PdrReport],
                      source: dict[str, str]) -> list[str]:
    """Warnings (and quality "suspect") for PDR walks that stand still while their Wi-Fi changes as if they
    walked: over pairs of scans 10-30 s apart with no PDR step between them (< WIFI_STILL_M), the median RSSI
    change reaches WIFI_WALKING_FRACTION of the median over all walks' pairs with more than WIFI_MOVING_M
    walked between them. Missed steps, or a phone carried in a way the PDR does not follow."""
    pw = poses.groupby("walk_id", sort=False)
    ww = wifi.groupby("walk_id", sort=False)
    pairs = {w: _scan_pairs(pw.get_group(w), ww.get_group(w)) for w in reports if w in ww.groups}
    moving = np.concatenate([d[m > WIFI_MOVING_M] for d, m in pairs.values()]) if pairs else np.zeros(0)
    if len(moving) < WIFI_MIN_PAIRS:
        return []
    ref = float(np.median(moving))
    out = []
    for w, (d, m) in pairs.items():
        still = d[m < WIFI_STILL_M]
        if len(still) >= WIFI_MIN_PAIRS and float(np.median(still)) >= WIFI_WALKING_FRACTION * ref:
            msg = (f"no steps between {len(still)} pairs of scans 10-30 s apart whose RSSI changes nearly as much "
                   f"as while walking (median {float(np.median(still)):.1f} dB, walking {ref:.1f} dB): steps missed?")
            reports[w].warnings.append(msg)
            reports[w].quality = "poor" if reports[w].quality == "poor" else "suspect"
            out.append(f"{source.get(w, w)}: walk {w!r}: PDR suspect: {msg}")
    return out


def _pdr_summary(reports: dict[str, PdrReport]) -> dict:
    """The per-walk PDR table of the ingest report."""
    return {w: {"steps": r.steps, "walking_s": r.walking_s, "handling_s": r.handling_s, "duration_s": r.duration_s,
                "cadence_hz": round(r.cadence_hz, 3) if np.isfinite(r.cadence_hz) else None,
                "walked_m": round(r.walked_m, 2), "heading": r.heading_source,
                "gyro_bias_dps": round(r.gyro_bias_dps, 3), "gyro_bias_from": r.bias_source,
                "yaw_abs_not_in_front": r.yaw_abs_not_in_front, "quality": r.quality, "warnings": r.warnings}
            for w, r in reports.items()}


def _walks_table(raw: RawInput, source: str) -> tuple[pd.DataFrame, list]:
    """The walks table with :data:`WALK_COLUMNS` (``source`` where the reader left it empty), only the walks
    that have poses, in the table's order; and the ids of the walks dropped for having none."""
    walks = raw.walks.copy()
    for c in WALK_COLUMNS:
        if c not in walks.columns:
            walks[c] = ""
    walks = walks[list(WALK_COLUMNS)]
    walks["source"] = walks["source"].where(walks["source"] != "", source)
    has_poses = walks["walk_id"].isin(raw.poses["walk_id"].unique())
    return walks[has_poses].reset_index(drop=True), walks.loc[~has_poses, "walk_id"].tolist()


def build_dataset(raw: RawInput, cfg: IngestConfig, source: str = "", pdr_cfg: PdrConfig | None = None,
                  on_walk: Callable[[str], None] | None = None) -> tuple[Dataset, Fingerprints, dict]:
    """Run the PDR on raw IMU, validate, order, attach readings to nodes and average them into per-node
    fingerprints.

    ``source`` (the reader's format name) fills the walks' ``source`` column where the reader left it empty;
    ``pdr_cfg``: the phone PDR's settings (defaults when None); ``on_walk(walk_id)``: called after the PDR
    of each walk with raw IMU (progress).
    """
    reports, pdr_warnings = derive_poses(raw, pdr_cfg or PdrConfig(), on_walk)
    codes = validate(raw, cfg)
    walks, dropped_walks = _walks_table(raw, source)
    walk_index = pd.Index(walks["walk_id"])

    poses, pose_walk = _order_by_walk(raw.poses, walk_index, codes["poses"])
    new_walk = np.r_[True, pose_walk[1:] != pose_walk[:-1]]
    row = np.arange(len(poses))
    poses["step"] = row - np.maximum.accumulate(np.where(new_walk, row, 0))  # the row's number in its walk
    for c in ("yaw_abs_rad", "yaw_abs_sigma_rad", "step_freq_hz"):
        if c not in poses.columns:
            poses[c] = np.nan
    poses = poses[list(POSE_COLUMNS) + [c for c in poses.columns if c not in POSE_COLUMNS]]
    one_step = walk_index[np.bincount(pose_walk, minlength=len(walk_index)) == 1]

    wifi = raw.wifi
    if "freq_mhz" not in wifi.columns:
        wifi = wifi.assign(freq_mhz=np.nan)
    if "ssid" not in wifi.columns:
        wifi = wifi.assign(ssid="")
    wifi, wifi_walk = _order_by_walk(wifi, walk_index, codes["wifi"])
    wifi["node"] = attach(poses, pose_walk, wifi, wifi_walk, cfg)
    all_readings = wifi   # for the PDR's Wi-Fi check: a walk without steps keeps no readings attached
    attached = wifi["node"].to_numpy() >= 0
    n_dropped = int((~attached).sum())
    wifi_walk = wifi_walk[attached]
    wifi = wifi[list(WIFI_COLUMNS)][attached].reset_index(drop=True)
    wifi["rssi_dbm"] = wifi["rssi_dbm"].astype(np.float32)

    fixes = raw.fixes if "label" in raw.fixes.columns else raw.fixes.assign(label="")
    fixes = fixes[list(FIX_COLUMNS) + [c for c in fixes.columns if c not in FIX_COLUMNS]].reset_index(drop=True)

    truth = raw.truth_poses
    if truth is not None:
        truth = _match_truth(poses, truth, raw, cfg.max_attach_gap_s)
    if reports:
        pdr_warnings += wifi_motion_check(poses, all_readings, reports, {w: imu.source for w, imu in raw.imu.items()})
        walks = _pdr_columns(walks, reports)

    ble, ble_summary = _attach_ble(raw, poses, pose_walk, walk_index, codes, cfg)
    ds = Dataset(
        walks=walks, poses=poses, wifi=wifi, fixes=fixes, truth_poses=truth, truth_aps=raw.truth_aps,
        venue=raw.venue, extra={"truth": dict(raw.truth_extra)}, ble=ble,
    )
    _check_fingerprint_size(wifi, _where(raw, "wifi"), "Wi-Fi", "BSSIDs")
    if ble is not None:
        _check_fingerprint_size(ble, _where(raw, "ble"), "BLE", "beacons")
    fp = Fingerprints.from_readings(wifi)
    scan = scan_ids(wifi_walk, wifi["t_s"].to_numpy(np.float64))
    scans = int(scan.max()) + 1 if len(scan) else 0
    summary: dict[str, Any] = {
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
        "warnings": list(pdr_warnings),
    }
    if reports:
        summary["pdr"] = _pdr_summary(reports)
    if ble_summary:
        summary["ble"] = ble_summary
        if ble_summary["readings_dropped_outside_walk"]:
            summary["warnings"].append(
                f"{ble_summary['readings_dropped_outside_walk']} BLE reading(s) more than {cfg.max_attach_gap_s:g} s "
                "outside their walk's poses were not attached")
    no_wifi = sorted(str(w) for w in walk_index[np.bincount(wifi_walk, minlength=len(walk_index)) == 0])
    if no_wifi:
        summary["warnings"].append(
            f"{len(no_wifi)} walk(s) without Wi-Fi readings kept without radio evidence (placed only by session "
            f"continuity or anchors, else unlinked): {', '.join(no_wifi[:5])}{' ...' if len(no_wifi) > 5 else ''}")
    if dropped_walks:
        summary["warnings"].append(f"{len(dropped_walks)} walk(s) without poses dropped: {dropped_walks[:5]}")
    if len(one_step):
        summary["warnings"].append(f"{len(one_step)} walk(s) with a single step: {[str(w) for w in one_step[:5]]}")
    if n_dropped:
        summary["warnings"].append(
            f"{n_dropped} Wi-Fi reading(s) more than {cfg.max_attach_gap_s:g} s outside their walk's poses "
            "were not attached"
        )
    return ds, fp, summary


def _attach_ble(raw: RawInput, poses: pd.DataFrame, pose_walk: np.ndarray, walk_index: pd.Index,
                codes: dict[str, tuple[np.ndarray, pd.Index]], cfg: IngestConfig) -> tuple[pd.DataFrame | None, dict]:
    """The BLE readings (:data:`BLE_COLUMNS`) attached to nodes exactly as the Wi-Fi ones, and their summary
    (readings, beacons, readings not attached); (None, {}) when the input has none."""
    if raw.ble is None or not len(raw.ble):
        return None, {}
    ble = raw.ble
    for c, v in (("freq_mhz", np.nan), ("ssid", "")):
        if c not in ble.columns:
            ble = ble.assign(**{c: v})
    ble, ble_walk = _order_by_walk(ble, walk_index, codes["ble"])
    ble["node"] = attach(poses, pose_walk, ble, ble_walk, cfg)
    attached = ble["node"].to_numpy() >= 0
    out = ble[list(BLE_COLUMNS)][attached].reset_index(drop=True)
    out["rssi_dbm"] = out["rssi_dbm"].astype(np.float32)
    return out, {"readings": len(out), "beacons": int(out["bssid"].nunique()),
                 "readings_dropped_outside_walk": int((~attached).sum())}


def _order_by_walk(df: pd.DataFrame, walk_index: pd.Index, codes: tuple[np.ndarray, pd.Index]
                   ) -> tuple[pd.DataFrame, np.ndarray]:
    """``df`` (rows of the walks of ``walk_index``; ``codes``: its rows' ``pd.factorize`` of walk_id) ordered by
    walk, in the index's order, then by time (file order among equal keys), with a RangeIndex; and each row's
    walk (its position in ``walk_index``)."""
    w = walk_index.get_indexer(codes[1])[codes[0]]
    t = df["t_s"].to_numpy(dtype=np.float64)
    if walk_time_ordered(w, t):  # ordered already (the usual input)
        return df.reset_index(drop=True), w
    order = np.lexsort((t, w))
    return df.take(order).reset_index(drop=True), w[order]


def _match_truth(poses: pd.DataFrame, truth: pd.DataFrame, raw: RawInput, max_gap_s: float) -> pd.DataFrame:
    """True poses at the rows of ``poses``: matched on (walk_id, t_s) where the times agree, otherwise
    interpolated in time along the walk's true track (e.g. steps found by the PDR), clamped to the ends up
    to ``max_gap_s``; a pose further outside its walk's truth is an error."""
    tcodes, tnames = pd.factorize(truth["walk_id"])
    tt_all = truth["t_s"].to_numpy(float)
    order = np.lexsort((tt_all, tcodes))  # by walk, then time; file order among equal keys
    sc, st = tcodes[order], tt_all[order]
    dup = (sc[1:] == sc[:-1]) & (st[1:] == st[:-1])
    if dup.any():
        raise InputError("truth poses: duplicate (walk_id, t_s)", _where(raw, "truth/poses")(int(order[1:][dup].min())))
    out = pd.DataFrame({"walk_id": poses["walk_id"].to_numpy(), "step": poses["step"].to_numpy(),
                        "t_s": poses["t_s"].to_numpy(float)})
    xyh = np.full((len(poses), 3), np.nan)
    start = np.searchsorted(sc, np.arange(len(tnames) + 1))
    tx, ty, th = (truth[c].to_numpy(float)[order] for c in ("x_m", "y_m", "heading_rad"))
    t_all = out["t_s"].to_numpy()
    pcodes, pnames = pd.factorize(out["walk_id"])
    pk = pd.Index(tnames).get_indexer(pnames)  # each pose walk's block of the truth (-1: none)
    by_walk = np.argsort(pcodes, kind="stable")
    pstart = np.searchsorted(pcodes[by_walk], np.arange(len(pnames) + 1))
    for w, k in enumerate(pk):
        rows = by_walk[pstart[w]:pstart[w + 1]]
        blk = slice(start[k], start[k + 1]) if k >= 0 else slice(0, 0)
        tt = st[blk]
        t = t_all[rows]
        if len(tt) == 0 or (t < tt[0] - max_gap_s).any() or (t > tt[-1] + max_gap_s).any():
            i = int(rows[0])
            at = _where(raw, "truth/poses")(int(order[blk].min())) if len(tt) else _where(raw, "poses")(i)
            raise InputError(
                f"truth poses do not cover pose (walk {_v(poses['walk_id'].iloc[i])}, "
                f"t_s={_v(poses['t_s'].iloc[i])})", at)
        xyh[rows, 0] = np.interp(t, tt, tx[blk])
        xyh[rows, 1] = np.interp(t, tt, ty[blk])
        h = np.interp(t, tt, np.unwrap(th[blk]))
        xyh[rows, 2] = wrap(h)
    out["x_m"], out["y_m"], out["heading_rad"] = xyh[:, 0], xyh[:, 1], xyh[:, 2]
    return out[["walk_id", "step", "t_s", "x_m", "y_m", "heading_rad"]]
