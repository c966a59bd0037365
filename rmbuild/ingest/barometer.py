"""Floors of an input that does not name them, from its barometers and its Wi-Fi (docs/floors.md).

A walk whose barometer shows a floor change (:func:`rmbuild.pdr.baro.floor_changes`) is cut at each
change's midpoint; its parts get levels relative to its start, counting storeys of :data:`STOREY_M`
(at least one per change). Which floors the walks' relative levels are on follows from the Wi-Fi. The walks
are placed one at a time, those that change floor first: each at the level offset where its scans lie
nearest (:func:`rmbuild.localize.floor.floor_distances`, mean over its scans that land on a level holding
placed scans) to the placed scans of the same levels; an offset must put at least
:data:`MIN_OVERLAP_SCANS` of its scans on such levels. Then each walk in turn is placed again against all
the others, until none moves (at most :data:`MAX_ROUNDS` rounds): a walk placed early, against the few
scans one walk has of a level, may sit a floor off, and the others' scans correct it.

Tried and dropped (simulated three-floor buildings, docs/notes/floors.md): counting a scan on a level without
placed scans as its largest distance to a placed level (it pushed walks onto the known levels), and the
first pass alone (it put the top floor's walks one floor down).

A walk wholly on a floor that no walk reaches from another is put on the known floor its scans are
nearest: nothing tells it from that floor. The floors are named by their level counted from the lowest
floor found, ``+0``, ``+1``, ``+2``: nothing in a barometer or a scan says which storey of the building
that is. An input without barometer floor changes is left as it is (one floor, or the floors its
``floor`` columns give).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.ingest.checks import scan_ids
from rmbuild.io.formats.base import RawInput
from rmbuild.localize.floor import floor_distances
from rmbuild.pdr.baro import floor_changes

#: m; the height of a storey counted per floor change (storeys are 3-4.5 m; a change of 6 m or more counts
#: two: a lift passing a floor)
STOREY_M = 4.0
#: scans of a walk that an offset must put on levels with placed scans (fewer say little)
MIN_OVERLAP_SCANS = 10
#: reference scans per level at most when placing a walk (a seeded subsample bounds the distance matrix)
MAX_REFS = 1000
#: rounds placing every walk again against all the others
MAX_ROUNDS = 5
#: in those rounds, the share of the most scans any offset puts on placed levels that an offset must put
#: there (every level has scans by then: a walk does not drift onto levels of its own)
ROUND_SHARE = 0.9

#: a walk's parts: [(start time s, -inf for the first; relative level)]
Parts = list[tuple[float, int]]


def barometer_floors(raw: RawInput) -> dict[str, list[tuple[float, str]]] | None:
    """walk id -> [(start time of the part in s, -inf for the first; floor name)] for every walk, when some
    walk's barometer changes floor and the input has no floor columns; else None."""
    if "floor" in raw.walks or "floor" in raw.poses:
        return None
    rel: dict[str, Parts] = {}
    for wid in raw.walks["walk_id"].astype(str):
        level, parts = 0, [(-np.inf, 0)]
        t_p = raw.pressure.get(wid)
        for ch in floor_changes(*t_p) if t_p is not None else []:
            level += int(np.sign(ch.dh_m)) * max(1, int(round(abs(ch.dh_m) / STOREY_M)))
            parts.append((ch.t_mid_s, level))
        rel[wid] = parts
    if all(len(p) == 1 for p in rel.values()):
        return None
    offsets = _place_walks(raw.wifi, rel)
    return {w: [(t0, f"{lv + offsets[w]:+d}") for t0, lv in parts] for w, parts in rel.items()}


def _scans(wifi: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(walk id per scan, time per scan, float32 RSS matrix scans x APs with NaN for not heard)."""
    walk_codes, _ = pd.factorize(wifi["walk_id"].astype(str))
    scan = scan_ids(walk_codes, wifi["t_s"].to_numpy(float)) if len(wifi) else np.zeros(0, np.int64)
    ap, _ = pd.factorize(wifi["bssid"].astype(str))
    n_scans = int(scan.max()) + 1 if len(scan) else 0
    rss = np.full((n_scans, int(ap.max()) + 1 if len(ap) else 0), np.nan, dtype=np.float32)
    rss[scan, ap] = wifi["rssi_dbm"].to_numpy(float)
    first = np.unique(scan, return_index=True)[1]
    return (wifi["walk_id"].astype(str).to_numpy()[first], wifi["t_s"].to_numpy(float)[first], rss)


def _place_walks(wifi: pd.DataFrame, rel: dict[str, Parts]) -> dict[str, int]:
    """walk -> level offset of its relative levels (module docstring)."""
    wid, t, rss = _scans(wifi)
    level = np.zeros(len(wid), dtype=np.int64)
    for w, parts in rel.items():
        m = wid == w
        for t0, lv in parts:
            level[m & (t >= t0)] = lv
    order = sorted(rel, key=lambda w: (-len({lv for _, lv in rel[w]}), -int((wid == w).sum()), w))
    offsets = {order[0]: 0}
    placed = wid == order[0]
    at = np.where(placed, level, 0)  # absolute level of the placed scans
    rng = np.random.default_rng(0)
    for w in order[1:]:
        mine = np.flatnonzero(wid == w)
        offsets[w] = _best_offset(rss, mine, level[mine], placed, at, rng) if len(mine) else 0
        placed[mine] = True
        at[mine] = level[mine] + offsets[w]
    for _ in range(MAX_ROUNDS):  # each walk again against all the others
        moved = False
        for w in order:
            mine = np.flatnonzero(wid == w)
            others = placed.copy()
            others[mine] = False
            if len(mine) == 0 or not others.any():
                continue
            o = _best_offset(rss, mine, level[mine], others, at, rng, ROUND_SHARE)
            if o != offsets[w]:
                offsets[w], moved = o, True
                at[mine] = level[mine] + o
        if not moved:
            break
    low = min(lv + offsets[w] for w, parts in rel.items() for _, lv in parts)
    return {w: o - low for w, o in offsets.items()}


def _best_offset(rss: np.ndarray, mine: np.ndarray, mine_level: np.ndarray, placed: np.ndarray,
                 at: np.ndarray, rng: np.random.Generator, share: float = 0.0) -> int:
    """The level offset putting a walk's scans (rows ``mine``, relative levels ``mine_level``) nearest the
    placed scans of the same absolute levels; an offset must put :data:`MIN_OVERLAP_SCANS` and ``share`` of
    the most any offset puts on placed levels there (module docstring)."""
    known = np.unique(at[placed])
    refs = []
    for k in known:
        r = np.flatnonzero(placed & (at == k))
        refs.append(rss[np.sort(rng.choice(r, MAX_REFS, replace=False)) if len(r) > MAX_REFS else r])
    d = floor_distances(refs, rss[mine])
    cands = []
    for o in range(int(known[0] - mine_level.max()), int(known[-1] - mine_level.min()) + 1):
        idx = np.minimum(np.searchsorted(known, mine_level + o), len(known) - 1)
        ok = known[idx] == mine_level + o
        cands.append((o, int(ok.sum()), float(d[np.flatnonzero(ok), idx[ok]].mean()) if ok.any() else np.inf))
    most = max(n for _, n, _ in cands)
    need = max(min(MIN_OVERLAP_SCANS, len(mine)), share * most)
    return min((c for c in cands if c[1] >= need), key=lambda c: (c[2], abs(c[0])))[0]
