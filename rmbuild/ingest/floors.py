"""Floors of an input: split what a reader read into one :class:`RawInput` per floor (docs/data-format.md).

A reader says which floor its data is on with an optional ``floor`` column: on ``walks`` (the whole walk
on one floor) or on ``poses`` (a walk that changes floor: stairs, lift). A walk whose poses change floor is
cut at each change into per-floor segments ``<walk>@<floor>`` (``#2``, ``#3`` for a second visit of the
same floor); its Wi-Fi readings and fixes go to the segment whose time span holds them. An input without
floor columns is split where its barometers show floor changes (:mod:`rmbuild.ingest.barometer`), the
floors named by level counted from the lowest one found. Inputs without either, or with a single floor,
stay one floor.
Every cut of a walk is a *transition* (``RawInput.transitions``): the place where its two segments meet,
on both floors.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pandas as pd

from rmbuild.errors import InputError
from rmbuild.ingest.barometer import barometer_floors
from rmbuild.io.formats.base import RawImu, RawInput
from rmbuild.pdr import ImuSignals

FLOOR_COLUMN = "floor"
#: floor names with a level: B2 / -2 (basements), F1 / 1F / L1 (ground floor = level 0 in the "F1" naming
#: of Chinese and US malls, as in the Microsoft ILC data), G / GF (ground), plain integers as given
_LEVEL_PATTERNS = (
    (re.compile(r"^(?:B|LG|UG|P)(\d+)$", re.I), lambda n: -n),
    (re.compile(r"^(?:F|L)(\d+)$|^(\d+)F$", re.I), lambda n: n - 1),
    (re.compile(r"^([+-]?\d+)$"), lambda n: n),
)


def floor_level(name: str) -> int | None:
    """The level of a floor name (0 ground floor, -1 first basement), None when the name does not say."""
    s = name.strip()
    if s.upper() in ("G", "GF", "EG"):
        return 0
    for pat, fn in _LEVEL_PATTERNS:
        m = pat.match(s)
        if m:
            return fn(int(next(g for g in m.groups() if g is not None)))
    return None


def split_floors(raw: RawInput) -> dict[str, RawInput] | None:
    """One RawInput per floor (in order of first appearance), or None for a single floor. The floor
    columns are consumed: the returned inputs (and ``raw`` when None is returned) have none. What the reader
    says of the whole input (``skipped``, ``notes``) stays with ``raw``, not with the floors."""
    cuts = barometer_floors(raw)
    if cuts is not None:
        _apply_cuts(raw, cuts)
    walk_floor = _walk_floors(raw)
    pose_floor = raw.poses[FLOOR_COLUMN].fillna("").astype(str).str.strip() if FLOOR_COLUMN in raw.poses else None
    raw.walks = raw.walks.drop(columns=[FLOOR_COLUMN], errors="ignore")
    raw.poses = raw.poses.drop(columns=[FLOOR_COLUMN], errors="ignore")
    if walk_floor is None and pose_floor is None:
        return None
    pf = pose_floor if pose_floor is not None else pd.Series("", index=raw.poses.index)
    if walk_floor is not None:  # a pose without a floor takes its walk's
        pf = pf.where(pf != "", raw.poses["walk_id"].astype(str).map(walk_floor).fillna(""))
    segments = _segments(raw, pf, walk_floor or {}, cuts or {})
    floors = list(dict.fromkeys(f for _, f, _ in segments))
    if len(floors) <= 1:
        raw.floor_name = floors[0] if floors and floors[0] else None
        return None
    raw.transitions = _transitions(segments)
    return {f: _floor_input(raw, f, [(w, s) for w, ff, s in segments if ff == f]) for f in floors}


def whole_floor(raw: RawInput, floor: str) -> RawInput:
    """``raw`` (every walk on ``floor``, its floor columns consumed) as :func:`split_floors` gives a floor of a
    larger input: a read of one floor folder made what a read of its whole building makes of that floor."""
    return _floor_input(raw, floor, [(w, (w, -np.inf, np.inf)) for w in raw.walks["walk_id"].astype(str)])


def _apply_cuts(raw: RawInput, cuts: dict[str, list[tuple[float, str]]]) -> None:
    """Give ``raw`` the floor columns the barometer cuts say (poses by time; a walk its first part's), and a
    note per walk cut."""
    raw.walks = raw.walks.assign(floor=raw.walks["walk_id"].astype(str).map(lambda w: cuts[w][0][1]))
    wids = raw.poses["walk_id"].astype(str).to_numpy()
    t = raw.poses["t_s"].to_numpy(float)
    floor = np.empty(len(wids), dtype=object)
    for w, parts in cuts.items():
        m = wids == w
        starts = np.array([t0 for t0, _ in parts])
        floor[m] = np.array([f for _, f in parts], dtype=object)[np.searchsorted(starts, t[m], side="right") - 1]
        if len(parts) > 1:
            raw.notes.append(f"walk {w!r}: cut at the barometer's floor changes into floors "
                             + " → ".join(f for _, f in parts)
                             + f" (at {', '.join(f'{t0:.1f}' for t0, _ in parts[1:])} s)")
    raw.poses = raw.poses.assign(floor=floor)


def _transitions(segments: list[Segment]) -> list[dict]:
    """The cuts between consecutive segments of a walk: walk, time (s), segment and floor on either side."""
    out = []
    for (w0, f0, (s0, _, _)), (w1, f1, (s1, t1, _)) in zip(segments, segments[1:], strict=False):
        if w0 == w1:
            out.append({"walk": w0, "t_s": round(float(t1), 3), "from": {"floor": f0, "walk": s0},
                        "to": {"floor": f1, "walk": s1}})
    return out


def _walk_floors(raw: RawInput) -> dict[str, str] | None:
    if FLOOR_COLUMN not in raw.walks:
        return None
    return dict(zip(raw.walks["walk_id"].astype(str), raw.walks[FLOOR_COLUMN].fillna("").astype(str).str.strip(),
                    strict=True))


#: a segment: (walk id as read, floor, (segment id, start time s or -inf, end time s or +inf))
Segment = tuple[str, str, tuple[str, float, float]]


def _segments(raw: RawInput, pose_floor: pd.Series, walk_floor: dict[str, str],
              cuts: dict[str, list[tuple[float, str]]]) -> list[Segment]:
    """Every walk's per-floor segments; a walk or pose without a floor is an error (the others have one). A
    walk without poses (raw IMU) is cut by time where ``cuts`` (barometer) say."""
    out: list[Segment] = []
    wids = raw.poses["walk_id"].astype(str).to_numpy()
    pf = pose_floor.to_numpy(dtype=object)
    t = raw.poses["t_s"].to_numpy(dtype=float)
    where = raw.where.get("poses", lambda i: f"poses row {i + 1}")
    for wid in raw.walks["walk_id"].astype(str):
        rows = np.flatnonzero(wids == wid)
        if len(rows) == 0 and len(cuts.get(wid, [])) > 1:
            out.extend(_named(wid, [(f, t0) for t0, f in cuts[wid]]))
            continue
        if len(rows) == 0:  # a walk without poses (raw IMU): the walk's floor
            f = walk_floor.get(wid, "")
            if not f:
                raise InputError(f"walk {wid!r} has no floor while other walks have one",
                                 raw.where.get("walks", lambda i: "walks")(0))
            out.append((wid, f, (wid, -np.inf, np.inf)))
            continue
        fl = pf[rows]
        if (fl == "").any():
            i = rows[int(np.argmax(fl == ""))]
            raise InputError(f"walk {wid!r}: a pose without a floor while other poses have one", where(int(i)))
        cut = np.flatnonzero(fl[1:] != fl[:-1]) + 1
        starts = np.r_[0, cut]
        if len(starts) == 1:
            out.append((wid, str(fl[0]), (wid, -np.inf, np.inf)))
            continue
        out.extend(_named(wid, [(str(fl[s]), float(t[rows[s]])) for s in starts]))
    return out


def _named(wid: str, parts: list[tuple[str, float]]) -> list[Segment]:
    """A walk's segments from its parts (floor, start time s): ids ``<walk>@<floor>`` (``#2`` for a second
    visit), the first open at the start and the last at the end."""
    out: list[Segment] = []
    seen: dict[str, int] = {}
    for k, (f, _) in enumerate(parts):
        seen[f] = seen.get(f, 0) + 1
        sid = f"{wid}@{f}" + (f"#{seen[f]}" if seen[f] > 1 else "")
        t0 = -np.inf if k == 0 else parts[k][1]
        t1 = np.inf if k == len(parts) - 1 else parts[k + 1][1]
        out.append((wid, f, (sid, t0, t1)))
    return out


def _floor_input(raw: RawInput, floor: str, segs: list[tuple[str, tuple[str, float, float]]]) -> RawInput:
    """The part of ``raw`` on one floor: its walks' segments, with ``where`` still naming the input rows."""
    where: dict[str, Callable[[int], str]] = {}
    tables: dict[str, pd.DataFrame] = {}
    for name in ("walks", "poses", "wifi", "ble", "fixes", "truth_poses"):
        df = getattr(raw, name)
        if df is None:
            continue
        rows, ids = _rows_of(df, segs, by_time=name != "walks")
        part = df.iloc[rows].copy()
        part["walk_id"] = ids
        tables[name] = part.reset_index(drop=True)
        if name in raw.where:
            where[name] = _shifted(raw.where[name], rows)
    own = {w for w, _ in segs}
    imu = {s[0]: _imu_part(raw.imu[w], s[1], s[2]) for w, s in segs if w in raw.imu}
    extra = {k: _truth_part(v, floor, own) for k, v in raw.truth_extra.items()}
    aps = _truth_part(raw.truth_aps, floor, own) if raw.truth_aps is not None else None
    return replace(raw, walks=tables["walks"], poses=tables["poses"], wifi=tables["wifi"], ble=tables.get("ble"),
                   fixes=tables["fixes"],
                   truth_poses=tables.get("truth_poses"), truth_extra=extra, truth_aps=aps, where=where,
                   imu=imu, skipped={}, notes=[], transitions=[],
                   floorplan=raw.floorplans.get(floor) if raw.floorplans else raw.floorplan, floorplans={})


def _truth_part(df: pd.DataFrame, floor: str, walks: set[str]) -> pd.DataFrame:
    """A truth table's rows of one floor: by its ``floor`` column (dropped), else by walk, else all."""
    if FLOOR_COLUMN in df:
        keep = df[FLOOR_COLUMN].astype(str) == floor
        return df[keep].drop(columns=[FLOOR_COLUMN]).reset_index(drop=True)
    if "walk_id" in df:
        return df[df["walk_id"].astype(str).isin(walks)].reset_index(drop=True)
    return df


def _rows_of(df: pd.DataFrame, segs: list[tuple[str, tuple[str, float, float]]],
             by_time: bool) -> tuple[np.ndarray, np.ndarray]:
    """Row positions of ``df`` in the segments (by walk, and by time for timed tables) and their new ids."""
    wids = df["walk_id"].astype(str).to_numpy()
    t = df["t_s"].to_numpy(dtype=float) if by_time else None
    rows: list[np.ndarray] = []
    ids: list[np.ndarray] = []
    for wid, (sid, t0, t1) in segs:
        m = wids == wid
        if t is not None and (np.isfinite(t0) or np.isfinite(t1)):
            m &= (t >= t0) & (t < t1)
        r = np.flatnonzero(m)
        rows.append(r)
        ids.append(np.full(len(r), sid, dtype=object))
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=object)
    r = np.concatenate(rows)
    order = np.argsort(r, kind="stable")
    return r[order], np.concatenate(ids)[order]


def _shifted(where: Callable[[int], str], rows: np.ndarray) -> Callable[[int], str]:
    return lambda i: where(int(rows[i]))


def _imu_part(imu: RawImu, t0: float, t1: float) -> RawImu:
    """The raw IMU samples of a walk in [t0, t1) s (a segment of a walk cut by its barometer)."""
    if not (np.isfinite(t0) or np.isfinite(t1)):
        return imu
    sg = imu.signals

    def keep(t: np.ndarray) -> np.ndarray:
        return (t >= t0) & (t < t1)

    a, y, g = keep(sg.t_acc_s), keep(sg.t_yaw_s), keep(sg.t_gyro_s)
    quat = sg.quat_xyzw[y] if len(sg.quat_xyzw) == len(y) else sg.quat_xyzw
    signals = ImuSignals(t_acc_s=sg.t_acc_s[a], acc_mps2=sg.acc_mps2[a], t_yaw_s=sg.t_yaw_s[y],
                         yaw_abs_rad=sg.yaw_abs_rad[y], yaw_accuracy=sg.yaw_accuracy[y], t_gyro_s=sg.t_gyro_s[g],
                         gyro_radps=sg.gyro_radps[g], quat_xyzw=quat)
    masks = {"acc": a, "yaw": y, "gyro": g}
    lines = {k: v[masks[k]] if k in masks and len(v) == len(masks[k]) else v for k, v in imu.lines.items()}
    return RawImu(signals, imu.source, lines, imu.unit)
