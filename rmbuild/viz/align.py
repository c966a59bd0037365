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
