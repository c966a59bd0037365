"""Shared by export-map and evaluate: the optimised node positions the built map uses, and its frame."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.config import MapConfig
from rmbuild.errors import InputError, WorkspaceError
from rmbuild.evaluate.trajectory import align_se2, interpolate_xy
from rmbuild.io.anchors import Anchors
from rmbuild.io.workspace import Workspace
from rmbuild.radiomap import devices
from rmbuild.types import BUILDING_FRAME_GAUGES, Dataset


def built_positions(ws: Workspace, ds: Dataset, cfg: MapConfig) -> tuple[np.ndarray, dict]:
    """(n_nodes, 2) optimised positions (NaN for walks left out) and a dict describing the frame.

    The frame is "building" when optimize used anchors, otherwise the reference walk's own frame;
    ``device_offsets_db``: the phones' offsets optimize estimated (non-zero ones; the built map and its
    queries take them off, :mod:`rmbuild.radiomap.devices`).
    """
    ws.require("optimize")
    if ws.stale_inputs("optimize"):
        raise WorkspaceError(f"{ws.path('optimize.poses')}: optimize ran on an earlier ingest of this workspace; "
                             "re-run `rmbuild optimize --force`")
    poses = ws.read_table("optimize.poses")
    if len(poses) != ds.n_nodes or not (poses["walk_id"].to_numpy() == ds.poses["walk_id"].to_numpy()).all():
        raise InputError(f"{ws.path('optimize.poses')}: does not match the ingested poses; re-run `rmbuild optimize`")
    xy = poses[["x_m", "y_m"]].to_numpy(dtype=float).copy()
    state = ws.read_optimize_state()
    info: dict = {"gauge": state.gauge, "left_out_walks": [],
                  "device_offsets_db": devices.nonzero(state.device_offsets_db)}
    if not cfg.include_unlinked_walks:  # walks placed neither by Wi-Fi links nor by anchors are left out
        unlinked = set(ds.poses["walk_id"].astype(str)) - set(state.linked_walks)
        info["left_out_walks"] = sorted(unlinked)
        xy[ds.poses["walk_id"].astype(str).isin(unlinked).to_numpy()] = np.nan
    ref = state.reference_walk
    info["frame"] = "building" if info["gauge"] in BUILDING_FRAME_GAUGES else f"walk:{ref}" if ref else "reference walk"
    return xy, info


def place_with_anchors(xy: np.ndarray, ds: Dataset, optimized_poses: pd.DataFrame,
                       anchors: Anchors) -> tuple[np.ndarray, dict]:
    """One SE(2) from the optimised positions at the anchors' times to the anchors (>= 2 anchors, checked
    by :func:`rmbuild.io.anchors.check_anchors`)."""
    tab = anchors.table
    src_a = np.full((len(tab), 2), np.nan)
    for wid, rows in tab.groupby("walk_id", sort=False).indices.items():
        src_a[rows] = interpolate_xy(optimized_poses, str(wid), tab["t_s"].to_numpy(float)[rows])
    dst_a = tab[["x_m", "y_m"]].to_numpy(float)
    if len(src_a) < 2:
        raise InputError("placing a map in the building frame needs at least 2 anchors", anchors.where(0))
    if not np.isfinite(src_a).all():
        raise InputError("an anchored walk has no optimised position at the anchor's time; re-run "
                         "`rmbuild optimize`", anchors.where(int(np.argmax(~np.isfinite(src_a).all(axis=1)))))
    r, t = align_se2(src_a, dst_a)
    res = np.hypot(*(src_a @ r.T + t - dst_a).T)
    return xy @ r.T + t, {"frame": "building", "anchor_fit": {
        "n": len(src_a), "rotation_deg": float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))),
        "residual_rms_m": float(np.sqrt((res ** 2).mean()))}}
