"""Floors on top of each other: the transitions of a building's walks tie its floors' frames.

Each floor is mapped in a frame of its own. Where ingest cut a walk between two floors (a *transition*,
``building/ingest.json`` → ``transitions``), the last optimised pose of the walk's segment on one floor and
the first of its segment on the other are, give or take a flight of stairs, one place seen in both frames.
Per pair of floors, those places give the rigid transform from one frame to the other: a rotation and a
translation when they lie at least :data:`MIN_SPREAD_M` apart (stairs and a lift), else a translation alone
(one place says nothing of the rotation). The floors are chained from the first floor of the manifest; each
floor's entry says how its frame maps onto that one's and how well the places agree. A segment that its
floor's optimisation left unlinked is not in a frame that means anything, so its transition is not used.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.geometry import align_se2
from rmbuild.io.workspace import Workspace, building_floors, building_report_path

#: m; transition places this far apart (largest distance from their mean) fix the rotation between frames
MIN_SPREAD_M = 5.0


def floor_frames(workspace: str | Path) -> dict | None:
    """{"reference": floor, "floors": {name: {"rotation_deg", "rotation_known", "dx_m", "dy_m", "transitions",
    "rms_m"}}}: x_ref = R(rotation) x + (dx, dy) for the floors tied to the reference by transitions
    (``rotation_known`` false: some link of the chain had one place only, its rotation taken as 0); None
    without any transition."""
    pairs = _transition_places(workspace)
    if not pairs:
        return None
    floors = list(building_floors(workspace) or {})
    ref = floors[0]
    frames: dict[str, tuple[np.ndarray, np.ndarray, bool, int, float]] = {ref: (np.eye(2), np.zeros(2), True, 0, 0.0)}
    grown = True
    while grown:  # chain floor to floor (a floor tied to a placed one is placed)
        grown = False
        for (fa, fb), (pa, pb) in pairs.items():
            for known, new, src, dst in ((fa, fb, pb, pa), (fb, fa, pa, pb)):
                if known in frames and new not in frames:
                    r0, t0, rot0, _, _ = frames[known]
                    r, t, rot, rms = _fit(src, dst)
                    frames[new] = (r0 @ r, r0 @ t + t0, rot0 and rot, len(src), rms)
                    grown = True
    return {"reference": ref, "floors": {
        n: {"rotation_deg": round(float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))), 2), "rotation_known": rot,
            "dx_m": round(float(t[0]), 3), "dy_m": round(float(t[1]), 3), "transitions": k, "rms_m": round(rms, 3)}
        for n, (r, t, rot, k, rms) in frames.items() if n != ref}}


def _fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, float]:
    """dst ≈ R src + t: (R, t, whether the rotation is known, rms residual m)."""
    spread = float(np.hypot(*(src - src.mean(axis=0)).T).max())
    if len(src) >= 2 and spread >= MIN_SPREAD_M:
        r, t = align_se2(src, dst)
        known = True
    else:
        r, t, known = np.eye(2), (dst - src).mean(axis=0), False
    res = dst - (src @ r.T + t)
    return r, t, known, float(np.sqrt((res ** 2).sum(axis=1).mean()))


def _transition_places(workspace: str | Path) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """(floor a, floor b) -> (places in a's frame, the same in b's frame), from the linked segments."""
    path = building_report_path(workspace, "ingest")
    if not path.is_file():
        return {}
    transitions = json.loads(path.read_text()).get("transitions", [])
    floors = building_floors(workspace) or {}
    poses: dict[str, pd.DataFrame] = {}
    for name, p in floors.items():
        ws = Workspace.open(p)
        if ws.path("optimize.poses").is_file():
            poses[name] = ws.read_table("optimize.poses")
    out: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for tr in transitions:
        a, b = tr["from"], tr["to"]
        pa = _end(poses.get(a["floor"]), a["walk"], last=True)
        pb = _end(poses.get(b["floor"]), b["walk"], last=False)
        if pa is not None and pb is not None:
            key = (a["floor"], b["floor"]) if a["floor"] < b["floor"] else (b["floor"], a["floor"])
            pair = (pa, pb) if key[0] == a["floor"] else (pb, pa)
            out.setdefault(key, []).append(pair)
    return {k: (np.array([p for p, _ in v]), np.array([q for _, q in v])) for k, v in out.items()}


def _end(poses: pd.DataFrame | None, walk: str, last: bool) -> np.ndarray | None:
    """The first or last optimised x, y of a linked walk, None when absent or unlinked."""
    if poses is None:
        return None
    w = poses[poses["walk_id"].astype(str) == walk]
    if len(w) == 0 or ("linked" in w and not bool(w["linked"].iloc[0])):
        return None
    row = w.sort_values("t_s").iloc[-1 if last else 0]
    return np.array([float(row["x_m"]), float(row["y_m"])])
