"""Where the optimiser's frame sits in the building frame, for drawing (view and report)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.evaluate.trajectory import align_se2
from rmbuild.types import BUILDING_FRAME_GAUGES


def frame_to_truth(poses: pd.DataFrame, truth: pd.DataFrame | None, gauge: str | None = None
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """(R (2, 2), t (2,)) with building ≈ R @ map + t, fitted on all nodes; None without truth, when the
    rows do not match, or with a building-frame gauge (anchors, floor plan: the map frame is the building
    frame already)."""
    if truth is None or gauge in BUILDING_FRAME_GAUGES or len(truth) != len(poses) or len(poses) == 0:
        return None
    if "walk_id" in truth and not (truth["walk_id"].astype(str).to_numpy()
                                   == poses["walk_id"].astype(str).to_numpy()).all():
        return None
    src = poses[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    dst = truth[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    ok = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    if ok.sum() < 2:
        return None
    r, t = align_se2(src[ok], dst[ok])
    return np.asarray(r), np.asarray(t)


def apply(rt: tuple[np.ndarray, np.ndarray] | None, xy: np.ndarray) -> np.ndarray:
    """R @ xy + t row-wise ((n, 2) m); ``xy`` itself when ``rt`` is None."""
    if rt is None:
        return xy
    r, t = rt
    return xy @ r.T + t


def per_walk_to_truth(poses: pd.DataFrame, truth: pd.DataFrame | None) -> pd.DataFrame | None:
    """Each walk aligned to its own truth by one SE(2) fit (how raw PDR looks at best); None without truth."""
    if truth is None or len(truth) != len(poses):
        return None
    out = poses.copy()
    walk = poses["walk_id"].astype(str).to_numpy()
    src_all = poses[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    dst_all = truth[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    xy = src_all.copy()
    for w in dict.fromkeys(walk):
        m = walk == w
        ok = m & np.isfinite(src_all).all(axis=1) & np.isfinite(dst_all).all(axis=1)
        if ok.sum() >= 2:
            xy[m] = apply(align_se2(src_all[ok], dst_all[ok]), src_all[m])
    out["x_m"], out["y_m"] = xy[:, 0], xy[:, 1]
    return out


#: A waypoint / fix this far (s) outside a walk's pose times is still matched to its nearest pose (the
#: first step is often detected a moment after the walker leaves the first waypoint).
FIX_TIME_SLACK_S = 2.0


def poses_at_fixes(poses: pd.DataFrame, fixes: pd.DataFrame) -> np.ndarray:
    """float (n_fixes, 2): each fix's walk position (m, the poses' frame) linearly interpolated at the fix
    time; NaN when the walk has no poses within :data:`FIX_TIME_SLACK_S` of it."""
    out = np.full((len(fixes), 2), np.nan)
    fw = fixes["walk_id"].astype(str).to_numpy()
    ft = fixes["t_s"].to_numpy(dtype=np.float64)
    for w, g in poses.groupby(poses["walk_id"].astype(str), sort=False):
        m = fw == w
        if not m.any():
            continue
        g = g.sort_values("t_s")
        t = g["t_s"].to_numpy(dtype=np.float64)
        ok = m & (ft >= t[0] - FIX_TIME_SLACK_S) & (ft <= t[-1] + FIX_TIME_SLACK_S)
        for k, c in enumerate(("x_m", "y_m")):
            out[ok, k] = np.interp(ft[ok], t, g[c].to_numpy(dtype=np.float64))
    return out


def frame_to_fixes(poses: pd.DataFrame, fixes: pd.DataFrame | None, gauge: str | None = None
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) with building ≈ R @ map + t, fitted on the fixes (waypoints) of all ``poses``' walks (pass
    only walks in one frame); None with fewer than 3 usable fixes or a building-frame gauge."""
    if fixes is None or len(fixes) == 0 or gauge in BUILDING_FRAME_GAUGES:
        return None
    src = poses_at_fixes(poses, fixes)
    dst = fixes[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    ok = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    if ok.sum() < 3:
        return None
    r, t = align_se2(src[ok], dst[ok])
    return np.asarray(r), np.asarray(t)


def per_walk_to_fixes(poses: pd.DataFrame, fixes: pd.DataFrame | None) -> pd.DataFrame | None:
    """The walks with at least two fixes, each aligned to its own fixes by one SE(2) fit (how raw PDR looks
    at best); None when no walk has two."""
    if fixes is None or len(fixes) == 0:
        return None
    src = poses_at_fixes(poses, fixes)
    dst = fixes[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    fw = fixes["walk_id"].astype(str).to_numpy()
    ok = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    walk = poses["walk_id"].astype(str).to_numpy()
    xy = poses[["x_m", "y_m"]].to_numpy(dtype=np.float64).copy()
    keep = np.zeros(len(poses), dtype=bool)
    for w in dict.fromkeys(walk):
        m = ok & (fw == w)
        if m.sum() >= 2:
            pm = walk == w
            xy[pm] = apply(align_se2(src[m], dst[m]), xy[pm])
            keep |= pm
    if not keep.any():
        return None
    out = poses.loc[keep].copy()
    out["x_m"], out["y_m"] = xy[keep, 0], xy[keep, 1]
    return out


def plan_segments(venue: dict | None, plan_geojson: dict | None) -> np.ndarray | None:
    """The floor plan as segments (n, 4) x0, y0, x1, y1 in the building frame (m): the venue's walls, or
    else the boundary of the walkable space of the workspace's plan (``data/floorplan.local.json``); None
    without either."""
    walls = np.asarray((venue or {}).get("walls") or [], dtype=float).reshape(-1, 4)
    if len(walls):
        return walls
    if plan_geojson is None:
        return None
    import shapely

    from rmbuild.floorplan import from_local_geojson

    plan = from_local_geojson(plan_geojson)
    segs = [np.c_[c[:-1], c[1:]] for ring in shapely.get_parts(shapely.boundary(plan.walkable))
            for c in [np.asarray(shapely.get_coordinates(ring))] if len(c) > 1]
    return np.concatenate(segs) if segs else None
