"""Plausibility checks of ingested evidence that are warnings, not errors (called by `rmbuild ingest`).

- A walk duplicated under another id (same steps, or same scans relative to its start): it would count
  twice as evidence and link perfectly to its copy.
- A walk much shorter than a vicinity link needs.
- A walk whose readings are offset from the other walks' at the same places (a device offset, e.g. a
  phone reading 10 dB stronger): co-located scans are found without positions, by the strongest AP they
  hear and the agreement of their readings after removing a constant, and the walk's median difference to
  the other walks is its offset. The optimizer removes offsets per device (``device_id``: the phones'
  offsets, docs/notes/optimize.md step 1), not per walk, so such a walk of a device shared with others links poorly;
  the ``slac`` localizer calibrates devices (RSS = k·φ + b; He, Chan, Yu and Liu, "Calibration-Free
  Fusion of Step Counter and Wireless Fingerprints for Indoor Localization", UbiComp 2015) only when
  localizing.

Pure: takes a :class:`Dataset`, returns the warnings.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.types import Dataset

#: steps; a walk with fewer poses is too short to link by Wi-Fi (one scan every ~2-4 s, ~2 steps/s)
MIN_WALK_STEPS = 5
#: dB; a walk whose readings are at least this much above or below the others' at the same places is
#: reported (on the MS ILC floors site1/F1 and site2/F4 the walks' estimated offsets are within ±6 dB,
#: 90 % within ±3.5 dB: docs/notes/reliability.md)
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


@dataclass(frozen=True)
class _Codes:
    """``pd.factorize`` of a dataset's id columns, computed once for all the checks."""

    pose_walk: tuple[np.ndarray, pd.Index]
    wifi_walk: tuple[np.ndarray, pd.Index]
    bssid: np.ndarray

    @staticmethod
    def of(ds: Dataset) -> _Codes:
        pw, pn = pd.factorize(ds.poses["walk_id"])
        ww, wn = pd.factorize(ds.wifi["walk_id"])
        return _Codes((pw, pd.Index(pn)), (ww, pd.Index(wn)), pd.factorize(ds.wifi["bssid"])[0])


def evidence_warnings(ds: Dataset) -> list[str]:
    """Warnings about duplicated walks, very short walks and device offsets (empty when all is plausible)."""
    codes = _Codes.of(ds)
    offsets = {w: off for w, off in walk_rss_offsets(ds, codes=codes).items() if abs(off) >= OFFSET_WARN_DB}
    return duplicate_walks(ds, codes) + short_walks(ds, codes) + offset_warning(offsets)


#: walks named with their offset in the device-offset warning; past this, their number
NAMED_OFFSETS = 8


def offset_warning(offsets: dict[str, float]) -> list[str]:
    """One warning for every walk reading :data:`OFFSET_WARN_DB` or more off the others (walk -> dB),
    largest offsets first; [] when there is none."""
    if not offsets:
        return []
    ranked = sorted(offsets.items(), key=lambda kv: -abs(kv[1]))
    shown = ", ".join(f"{w!r} {off:+.1f} dB" for w, off in ranked[:NAMED_OFFSETS])
    more = f" and {len(ranked) - NAMED_OFFSETS} more" if len(ranked) > NAMED_OFFSETS else ""
    tail = ("the optimizer removes offsets per device (device_id), not per walk, so {} may stay unlinked; the slac "
            "localizer calibrates devices when localizing")
    if len(ranked) == 1:
        w, off = ranked[0]
        return [f"walk {w!r} reads {off:+.1f} dB against the other walks at the same places (a device offset?); "
                + tail.format("it")]
    return [f"{len(ranked)} walks read {OFFSET_WARN_DB:g} dB or more against the other walks at the same places "
            f"(a device offset?): {shown}{more}; " + tail.format("they")]


def _walk_digests(df: pd.DataFrame, cols: list[str], t0: pd.Series, walk: tuple[np.ndarray, pd.Index],
                  text: dict[str, np.ndarray]) -> dict[str, tuple[int, int, int]]:
    """Per walk (in order of first appearance; ``walk``: the rows' walk codes and the walk ids, which may
    name walks without rows), an order-independent digest of its rows (times relative to the walk's first
    pose, values rounded): equal digests mean equal rows. ``text``: codes of text columns."""
    codes, names = walk
    start = t0.reindex(names).to_numpy(float)  # NaN for a walk without poses
    rel = {}  # the walk id itself is not hashed: a copy has another one
    for c in cols:
        s = df[c]
        if c == "t_s":
            rel[c] = np.round(s.to_numpy(float) - start[codes], 3)
        elif c in text:
            rel[c] = text[c]  # equal text, equal code: hashing codes is hashing the text here
        elif pd.api.types.is_float_dtype(s):
            rel[c] = np.round(s.to_numpy(float), 3)
        elif not pd.api.types.is_numeric_dtype(s):
            rel[c] = pd.factorize(s)[0]
        else:
            rel[c] = s.to_numpy()
    h = pd.util.hash_pandas_object(pd.DataFrame(rel), index=False).to_numpy()
    order = np.argsort(codes, kind="stable")
    present = np.flatnonzero(np.bincount(codes, minlength=len(names)))
    cuts = np.searchsorted(codes[order], present)
    h = h[order]
    # wrapping sum and xor of 64-bit row hashes, and the row count: a multiset digest
    sums = np.add.reduceat(h, cuts) if len(h) else h
    xors = np.bitwise_xor.reduceat(h, cuts) if len(h) else h
    sizes = np.diff(np.r_[cuts, len(h)])
    return {str(w): (int(a), int(b), int(n)) for w, a, b, n in zip(names[present], sums, xors, sizes, strict=True)}


def duplicate_walks(ds: Dataset, codes: _Codes | None = None) -> list[str]:
    """Walks whose steps (relative times and own-frame poses) or scans (relative times, BSSIDs, RSSI)
    repeat another walk's."""
    codes = codes or _Codes.of(ds)
    pw, names = codes.pose_walk
    n = np.bincount(pw, minlength=len(names))
    t = ds.poses["t_s"].to_numpy(float)
    first_row = np.full(len(names), len(pw))
    np.minimum.at(first_row, pw, np.arange(len(pw)))
    t0 = pd.Series(t[first_row] if len(pw) else np.zeros(0), index=names)  # each walk's first time, file order
    steps = n[pw] >= 2
    digests = {"steps": _walk_digests(ds.poses[steps], ["t_s", "x_m", "y_m", "heading_rad"], t0,
                                      (pw[steps], names), {}),
               "scans": _walk_digests(ds.wifi, ["t_s", "bssid", "rssi_dbm"], t0, codes.wifi_walk,
                                      {"bssid": codes.bssid})}
    out: list[str] = []
    reported: set[str] = set()
    for what, d in digests.items():
        first: dict[tuple[int, int, int], str] = {}
        for wid, key in d.items():
            other = first.setdefault(key, wid)
            if other != wid and wid not in reported:
                reported.add(wid)
                out.append(f"walk {wid!r} repeats the {what} of walk {other!r} (a copy under another id?); "
                           "it counts twice as evidence: remove one of them")
    return out


def short_walks(ds: Dataset, codes: _Codes | None = None) -> list[str]:
    pw, names = (codes or _Codes.of(ds)).pose_walk
    n = np.bincount(pw, minlength=len(names))  # walks in order of first appearance
    short = names[(n >= 2) & (n < MIN_WALK_STEPS)]
    if not len(short):
        return []
    return [f"{len(short)} walk(s) with fewer than {MIN_WALK_STEPS} steps, too short to link by Wi-Fi: "
            f"{[str(w) for w in short[:5]]}"]


def walk_rss_offsets(ds: Dataset, seed: int = 0, codes: _Codes | None = None) -> dict[str, float]:
    """Each walk's median RSS difference (dB) to the other walks' co-located scans (walks with too few
    co-located pairs are left out)."""
    wifi = ds.wifi
    codes = codes or _Codes.of(ds)
    wc_all, names_all = codes.wifi_walk
    if wc_all.max(initial=-1) < 2:
        return {}
    scan = scan_ids(wc_all, wifi["t_s"].to_numpy(np.float64))
    keep = np.bincount(scan)[scan] >= MIN_SHARED_APS
    if not keep.any():
        return {}
    scan = scan[keep]
    rssi = wifi["rssi_dbm"].to_numpy(np.float64)[keep]
    ap, _ = _first_appearance(codes.bssid[keep])
    walk_codes, walk_uniq = _first_appearance(wc_all[keep])
    walk_names = names_all[walk_uniq]
    by_scan, start, scan_walk, top = _scan_groups(scan, rssi, ap, walk_codes)
    n_ap = int(ap.max()) + 1
    rng = np.random.default_rng(seed)
    found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for members in sorted(top, key=len, reverse=True)[:MAX_GROUPS]:
        m = np.asarray(members)
        w = scan_walk[m]
        if (w == w[0]).all():
            continue
        if len(m) > MAX_GROUP_SCANS:
            m = rng.choice(m, MAX_GROUP_SCANS, replace=False)
        n = start[m + 1] - start[m]
        member = np.repeat(np.arange(len(m)), n)
        rows = by_scan[np.repeat(start[m] - np.cumsum(n) + n, n) + np.arange(n.sum())]
        found.append(_group_pairs(m, member, ap[rows], rssi[rows], scan_walk, n_ap))
    if not found:
        return {}
    wi, wj, med = (np.concatenate(x) for x in zip(*found, strict=True))
    walk = np.r_[wi, wj]
    diff = np.r_[med, -med]  # each pair counts for both walks, with opposite signs
    order = np.argsort(walk, kind="stable")
    walk, diff = walk[order], diff[order]
    cuts = np.searchsorted(walk, np.arange(len(walk_names) + 1))
    return {str(walk_names[w]): float(np.median(diff[cuts[w]:cuts[w + 1]]))
            for w in range(len(walk_names)) if cuts[w + 1] - cuts[w] >= MIN_PAIRS}


def _first_appearance(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``pd.factorize`` of non-negative integer codes (numbered again in order of first appearance); codes
    already so numbered (all but a few readings kept: the usual case) are returned as they are."""
    top = np.maximum.accumulate(codes)
    if len(codes) and codes[0] == 0 and (codes[1:] <= top[:-1] + 1).all():
        return codes, np.arange(int(top[-1]) + 1)
    return pd.factorize(codes)


def _scan_groups(scan: np.ndarray, rssi: np.ndarray, ap: np.ndarray, walk_codes: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[list[int]]]:
    """The readings by scan (``by_scan``; scan s's readings are ``by_scan[start[s]:start[s + 1]]``), each scan's
    walk and the scans grouped by their strongest AP (the first reading of the scan at its maximum), groups in
    the order of their AP's code."""
    by_scan = np.argsort(scan, kind="stable")
    s_sorted, r_sorted = scan[by_scan], rssi[by_scan]
    run = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    at_max = np.flatnonzero(r_sorted == np.repeat(np.maximum.reduceat(r_sorted, run), np.diff(np.r_[run, len(scan)])))
    first = by_scan[at_max[np.r_[True, s_sorted[at_max][1:] != s_sorted[at_max][:-1]]]]
    scan_walk = np.full(int(scan.max()) + 1, -1)
    scan_walk[scan[first]] = walk_codes[first]
    start = np.searchsorted(s_sorted, np.arange(len(scan_walk) + 1))
    g = np.argsort(ap[first], kind="stable")  # scans in ascending order within a group, as `first` lists them
    top_ap, top_scan = ap[first][g], scan[first][g]
    cuts = np.flatnonzero(np.r_[True, top_ap[1:] != top_ap[:-1], True])
    top = [top_scan[a:b].tolist() for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    return by_scan, start, scan_walk, top


def walk_time_ordered(walk_codes: np.ndarray, t: np.ndarray) -> bool:
    """Whether the rows are ordered by walk code, then by time (as ingest leaves them; the usual file)."""
    dw = np.diff(walk_codes)
    return bool((dw >= 0).all() and ((dw > 0) | (np.diff(t) >= 0)).all())


def scan_ids(walk_codes: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per reading, its scan's number: (walk, time) groups numbered in order of first appearance. Readings
    ordered by walk and time (as ingest leaves them) are numbered by their runs, others by a groupby."""
    if walk_time_ordered(walk_codes, t):
        return np.cumsum(np.r_[0, (np.diff(walk_codes) != 0) | (np.diff(t) != 0)])
    return pd.DataFrame({"w": walk_codes, "t": t}).groupby(["w", "t"], sort=False).ngroup().to_numpy()


def _sorted_row_median(srt: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Median of each row of ``srt`` (rows sorted, their ``n`` finite values first)."""
    r = np.arange(len(srt))
    return 0.5 * (srt[r, (n - 1) // 2] + srt[r, n // 2])


@functools.cache
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, 1)``, kept (groups have at most MAX_GROUP_SCANS members)."""
    return np.triu_indices(n, 1)


def _group_pairs(members: np.ndarray, row: np.ndarray, ap: np.ndarray, rssi: np.ndarray, scan_walk: np.ndarray,
                 n_ap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The co-located scan pairs of one group (``row``: the member index of each of the members' readings
    ``ap``, codes below ``n_ap``, ``rssi``): the two walks and the median difference of each pair."""
    shared_col = np.bincount(ap, minlength=n_ap) >= 2  # an AP only one scan heard is never shared: no column
    twice = shared_col[ap]
    mat = np.full((len(members), int(shared_col.sum())), np.nan)
    mat[row[twice], (np.cumsum(shared_col) - 1)[ap[twice]]] = rssi[twice]
    walks = scan_walk[members]
    iu, ju = _pairs(len(members))
    seen = np.isfinite(mat).astype(np.float32)  # counts < 2^24: exact in float32
    shared = (seen @ seen.T)[iu, ju]
    ok = (walks[iu] != walks[ju]) & (shared >= MIN_SHARED_APS)
    if not ok.any():
        return np.zeros(0, walks.dtype), np.zeros(0, walks.dtype), np.zeros(0)
    iu, ju, n = iu[ok], ju[ok], shared[ok].astype(np.int64)  # n: the APs both scans heard
    srt = np.sort(mat[iu] - mat[ju], axis=1)[:, :int(n.max())]  # NaN last: the n differences first
    med = _sorted_row_median(srt, n)
    mad = _sorted_row_median(np.sort(np.abs(srt - med[:, None]), axis=1), n)
    co = mad <= COLOCATED_MAD_DB
    return walks[iu[co]], walks[ju[co]], med[co]
