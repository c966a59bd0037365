"""A radio map that ages: per-AP change detection between collections, and an update rule from new data.

Venues change under a map: APs are removed, replaced, moved, added, and the signal at a spot drifts.
This module works on point maps — one reference point (RP) per surveyed or visited spot, the per-AP mean
RSSI of the readings taken there — and offers:

* :func:`point_map` — samples -> RPs; samples of one floor within ``merge_m`` of a point are one RP (the
  self-building database of UILoc merges a new fingerprint into the reference point within 1 m);
* :func:`ap_evidence` / :func:`classify_aps` — per AP and collection: detected or not, its strongest RPs'
  location and RSSI; then per AP a verdict against the first collection — ``gone`` (not heard in the last
  ``gone_after`` collections), ``appeared`` (unheard in the first, heard in at least ``min_months``),
  ``moved`` (its strongest readings now centre more than ``move_m`` away, or on another floor with its
  RSSI changed), ``transient`` (unheard in the first, heard in fewer than ``min_months``), or ``stable`` —
  with the evidence (months heard, RSS shift at the RPs heard in both, location shift);
* :func:`refresh` and :func:`drop_aps` — the update rule: an RP seen again takes the new fingerprint, a
  new spot becomes a new RP, and an AP no new reading has heard for ``gone_after`` collections leaves
  the map.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.radiomap.reference import ReferenceSet

#: 1; an AP counts as heard in a collection with at least this many readings (one stray reading is not
#: evidence that an AP still exists)
MIN_READINGS = 2
#: 1; the location of an AP's strongest readings is the mean position of its this many strongest RPs
#: (on the floor of the strongest)
PEAK_RPS = 3
#: dB; an AP whose strongest readings changed floor counts as moved only when its RSSI at the RPs that
#: heard it in both collections changed by more than this in median (an AP between two floors flips its
#: strongest floor with no change at all: UJI long-term, floors 3 and 5 of one library)
MOVE_FLOOR_DB = 6.0


@dataclass
class PointMap:
    """One RP per spot. ``xy`` float64 (n, 2) m; ``floor`` int64 (n,); ``rss_dbm`` float32 (n, n_ap) mean of
    the readings (NaN = never detected there); ``detect`` float32 (n, n_ap) share of the spot's samples that
    detected the AP; ``n_samples`` int64 (n,); ``month`` int64 (n,) the collection the RP's fingerprint
    comes from; ``bssids`` (n_ap,)."""

    xy: np.ndarray
    floor: np.ndarray
    rss_dbm: np.ndarray
    detect: np.ndarray
    n_samples: np.ndarray
    month: np.ndarray
    bssids: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)

    def rows(self, sel: np.ndarray) -> PointMap:
        return PointMap(self.xy[sel], self.floor[sel], self.rss_dbm[sel], self.detect[sel], self.n_samples[sel],
                        self.month[sel], self.bssids)

    def reference_set(self, floor: int | None = None) -> ReferenceSet:
        """The RPs (of one floor, or all) as a localizer's :class:`ReferenceSet` ("nodes" kind)."""
        sel = np.ones(len(self), bool) if floor is None else self.floor == floor
        return ReferenceSet(self.xy[sel], self.rss_dbm[sel], self.bssids, None, None,
                            np.zeros(int(sel.sum()), bool), "nodes")


def _spots(xy: np.ndarray, floor: np.ndarray, merge_m: float) -> np.ndarray:
    """int64 (n,) spot index of each sample: a sample joins the first spot of its floor within ``merge_m``
    (in order of first appearance), else starts one."""
    key = np.c_[np.round(xy, 3), floor]
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    centre: list[np.ndarray] = []
    cfloor: list[float] = []
    spot_of = np.empty(len(uniq), np.int64)
    for i, (x, y, f) in enumerate(uniq):
        hit = -1
        for j, (c, cf) in enumerate(zip(centre, cfloor, strict=True)):
            if cf == f and np.hypot(x - c[0], y - c[1]) <= merge_m:
                hit = j
                break
        if hit < 0:
            centre.append(np.array([x, y]))
            cfloor.append(f)
            hit = len(centre) - 1
        spot_of[i] = hit
    return spot_of[inv.reshape(-1)]


def point_map(rss_dbm: np.ndarray, xy: np.ndarray, floor: np.ndarray, bssids: np.ndarray, month: int,
              merge_m: float = 1.0) -> PointMap:
    """Samples -> RPs. ``rss_dbm`` (n, n_ap) NaN = not detected; ``xy`` (n, 2) m; ``floor`` (n,)."""
    spot = _spots(np.asarray(xy, float), np.asarray(floor), merge_m)
    n = int(spot.max()) + 1 if len(spot) else 0
    det = ~np.isnan(rss_dbm)
    cnt = np.zeros((n, rss_dbm.shape[1]))
    np.add.at(cnt, spot, det)
    tot = np.zeros((n, rss_dbm.shape[1]))
    np.add.at(tot, spot, np.where(det, rss_dbm, 0.0))
    n_s = np.bincount(spot, minlength=n)
    pos = np.zeros((n, 2))
    np.add.at(pos, spot, xy)
    fl = np.zeros(n, np.int64)
    fl[spot] = floor
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return PointMap(pos / n_s[:, None], fl, mean.astype(np.float32), (cnt / n_s[:, None]).astype(np.float32),
                    n_s.astype(np.int64), np.full(n, month, np.int64), np.asarray(bssids, dtype=object))


def _match(old: PointMap, new: PointMap, merge_m: float) -> np.ndarray:
    """int64 (len(new),) the old RP each new RP falls on (same floor, within ``merge_m``; nearest), -1 none."""
    out = np.full(len(new), -1, np.int64)
    for i in range(len(new)):
        same = np.flatnonzero(old.floor == new.floor[i])
        if same.size == 0:
            continue
        d = np.hypot(*(old.xy[same] - new.xy[i]).T)
        j = int(np.argmin(d))
        if d[j] <= merge_m:
            out[i] = same[j]
    return out


def refresh(old: PointMap, new: PointMap, merge_m: float = 1.0) -> PointMap:
    """The update rule's first half: RPs of ``new`` falling on an RP of ``old`` replace its fingerprint;
    the others are added. Both maps must share the AP columns."""
    if not np.array_equal(old.bssids, new.bssids):
        raise ValueError("the two maps have different AP columns")
    hit = _match(old, new, merge_m)
    out = old.rows(np.arange(len(old)))
    seen = hit >= 0
    for name in ("rss_dbm", "detect", "n_samples", "month"):
        getattr(out, name)[hit[seen]] = getattr(new, name)[seen]
    fresh = new.rows(~seen)
    return PointMap(np.vstack([out.xy, fresh.xy]), np.r_[out.floor, fresh.floor],
                    np.vstack([out.rss_dbm, fresh.rss_dbm]), np.vstack([out.detect, fresh.detect]),
                    np.r_[out.n_samples, fresh.n_samples], np.r_[out.month, fresh.month], out.bssids)


def drop_aps(m: PointMap, drop: np.ndarray) -> PointMap:
    """The map with the APs ``drop`` (bool (n_ap,)) removed from every RP (columns kept, all not detected)."""
    out = m.rows(np.arange(len(m)))
    out.rss_dbm[:, drop] = np.nan
    out.detect[:, drop] = 0.0
    return out


def heard(m: PointMap) -> np.ndarray:
    """bool (n_ap,): APs with at least :data:`MIN_READINGS` readings over the map's samples."""
    return (m.detect * m.n_samples[:, None]).sum(axis=0) >= MIN_READINGS - 1e-6


def _peak(m: PointMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per AP: (x, y) of its strongest readings, their floor, the strongest RP mean (NaN when unheard)."""
    n_ap = len(m.bssids)
    xy = np.full((n_ap, 2), np.nan)
    fl = np.full(n_ap, -1, np.int64)
    top = np.full(n_ap, np.nan)
    h = heard(m)
    for j in np.flatnonzero(h):
        col = m.rss_dbm[:, j]
        ok = np.flatnonzero(np.isfinite(col))
        if ok.size == 0:
            continue
        best = ok[np.argmax(col[ok])]
        same = ok[m.floor[ok] == m.floor[best]]
        strongest = same[np.argsort(-col[same], kind="stable")[:PEAK_RPS]]
        xy[j] = m.xy[strongest].mean(axis=0)
        fl[j] = m.floor[best]
        top[j] = col[best]
    return xy, fl, top


def ap_evidence(maps: dict[int, PointMap]) -> pd.DataFrame:
    """One row per (collection, AP) heard: month, bssid, n_rps (RPs where detected), peak_x_m, peak_y_m,
    peak_floor, peak_dbm. ``maps``: collection (e.g. month) -> its point map (same AP columns)."""
    rows = []
    for month, m in sorted(maps.items()):
        xy, fl, top = _peak(m)
        h = heard(m)
        rows.append(pd.DataFrame({
            "month": month, "bssid": m.bssids[h].astype(str), "n_rps": (~np.isnan(m.rss_dbm[:, h])).sum(axis=0),
            "peak_x_m": xy[h, 0], "peak_y_m": xy[h, 1], "peak_floor": fl[h], "peak_dbm": top[h],
        }))
    return pd.concat(rows, ignore_index=True)


def _runs(months: list[int]) -> str:
    """"1-5,7,9-10" for a sorted list of months."""
    out: list[str] = []
    for mo in months:
        if out and int(out[-1].split("-")[-1]) == mo - 1:
            out[-1] = f"{out[-1].split('-')[0]}-{mo}"
        else:
            out.append(str(mo))
    return ",".join(out)


def _centre(g: pd.DataFrame) -> tuple[np.ndarray, int]:
    """Median centre of an AP's strongest readings over the collections ``g`` (rows of
    :func:`ap_evidence`) on their most frequent floor, and that floor; NaN / -1 when ``g`` is empty."""
    if not len(g):
        return np.full(2, np.nan), -1
    f = int(g["peak_floor"].mode().iloc[0])
    return g.loc[g["peak_floor"] == f, ["peak_x_m", "peak_y_m"]].median().to_numpy(dtype=float), f


def _rss_shift(maps: dict[int, PointMap], first: int, late: list[int], j: int) -> float:
    """Median over the first collection's RPs that detected AP j then and later of (late − first) RSSI."""
    a = maps[first].rss_dbm[:, j]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the mean of an RP no later collection heard it at
        z = np.nanmean(np.stack([_on(maps[first], maps[mo], j) for mo in late]), axis=0)
    both = np.isfinite(a) & np.isfinite(z)
    return float(np.median(z[both] - a[both])) if both.any() else float("nan")


def classify_aps(maps: dict[int, PointMap], gone_after: int = 3, move_m: float = 5.0,
                 min_months: int = 3) -> pd.DataFrame:
    """Per AP heard in any collection, its verdict against the first collection, with the evidence.

    Columns: bssid, status, months_heard ("1-5,7"), n_months, first_month, last_month; first_x_m,
    first_y_m, floor_first (centre of its strongest readings in the first collection) and late_x_m,
    late_y_m, floor_late (in its last ``min_months`` collections heard); location_shift_m (between the
    two, NaN across floors); rss_shift_db (median over the RPs that detected it in the first collection and
    in the last ``min_months`` of (late − first) mean RSSI); replaced_by (for a gone AP: APs that appeared
    within a collection of its disappearance with their strongest readings within ``move_m``, on its
    floor — a replaced access point gets a new BSSID).
    """
    months = sorted(maps)
    first = months[0]
    ev = ap_evidence(maps)
    cols = {b: j for j, b in enumerate(maps[first].bssids.astype(str))}
    rows = []
    for b, g in ev.groupby("bssid", sort=True):
        heard_in = sorted(g["month"].tolist())
        base = g[g["month"] == first]
        c_first, f_first = _centre(base)
        c_late, f_late = _centre(g[g["month"].isin(heard_in[-min_months:])])
        shift = float(np.hypot(*(c_late - c_first))) if f_late == f_first else float("nan")
        late = [mo for mo in months[-min_months:] if mo in heard_in]
        rss_shift = _rss_shift(maps, first, late, cols[str(b)]) if len(base) and late else float("nan")
        if len(base) and heard_in[-1] <= months[-1] - gone_after:
            status = "gone"
        elif not len(base):
            status = "appeared" if len(heard_in) >= min_months else "transient"
        elif shift > move_m or (f_late != f_first and not abs(rss_shift) <= MOVE_FLOOR_DB):
            status = "moved"
        else:
            status = "stable"
        rows.append({"bssid": b, "status": status, "months_heard": _runs(heard_in), "n_months": len(heard_in),
                     "first_month": heard_in[0], "last_month": heard_in[-1], "first_x_m": c_first[0],
                     "first_y_m": c_first[1], "floor_first": f_first, "late_x_m": c_late[0], "late_y_m": c_late[1],
                     "floor_late": f_late, "location_shift_m": shift, "rss_shift_db": rss_shift})
    out = pd.DataFrame(rows)
    out["replaced_by"] = _replacements(out, move_m)
    return out


def _replacements(aps: pd.DataFrame, move_m: float) -> list[str]:
    """For each gone AP, the appeared APs (";"-joined) first heard within one collection of its last
    collection + 1, whose strongest readings centre within ``move_m`` of its own, on its floor."""
    new = aps[aps["status"] == "appeared"]
    out = []
    for r in aps.itertuples():
        if r.status != "gone" or not len(new):
            out.append("")
            continue
        near_t = (new["first_month"] - (r.last_month + 1)).abs() <= 1
        same_f = new["floor_first"].where(new["floor_first"] >= 0, new["floor_late"]) == r.floor_first
        d = np.hypot(new["late_x_m"] - r.first_x_m, new["late_y_m"] - r.first_y_m)
        out.append(";".join(new.loc[near_t & same_f & (d <= move_m), "bssid"]))
    return out


def _on(ref: PointMap, other: PointMap, j: int) -> np.ndarray:
    """float (len(ref),) AP j's mean RSSI in ``other`` at each RP of ``ref`` (NaN where no RP of ``other``
    falls on it or it did not detect j)."""
    hit = _match(other, ref, 1.0)
    out = np.full(len(ref), np.nan)
    ok = hit >= 0
    out[ok] = other.rss_dbm[hit[ok], j]
    return out
