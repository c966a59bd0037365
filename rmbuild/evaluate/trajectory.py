"""Trajectory metrics: SE(2) alignment, ATE, landmark error, heading alignment error (no gtsam).

Conventions: positions are (n, 2) arrays in metres; a rigid 2-D transform is ``(R (2, 2), t (2,))`` with
``dst ≈ R @ src + t``. Every metric returns ``None`` when it cannot be computed (no truth, no fixes, too
few points), so a report can write ``null`` instead of leaving the key out.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from rmbuild.geometry import align_se2, rotation_angle_rad

__all__ = ["align_se2", "ate", "heading_alignment_error_deg", "interpolate_xy", "landmark_error",
           "rotation_angle_rad", "trajectory_metrics"]


def _stats(err: np.ndarray) -> dict[str, float]:
    return {
        "rmse": float(np.sqrt(np.mean(err**2))),
        "mean": float(np.mean(err)),
        "median": float(np.median(err)),
        "max": float(np.max(err)),
    }


def ate(est_xy: np.ndarray, true_xy: np.ndarray, align: bool = True) -> dict[str, float] | None:
    """Absolute trajectory error (m): rmse, mean, median, max of ‖est − true‖.

    ``align``: first fit one rigid SE(2) transform est -> true over all points (evo's APE with SE(2)
    alignment); off when anchors already put the estimate into the building frame.
    """
    est = np.asarray(est_xy, dtype=float).reshape(-1, 2)
    tru = np.asarray(true_xy, dtype=float).reshape(-1, 2)
    ok = np.isfinite(est).all(axis=1) & np.isfinite(tru).all(axis=1)
    if ok.sum() == 0:
        return None
    est, tru = est[ok], tru[ok]
    if align:
        r, t = align_se2(est, tru)
        est = est @ r.T + t
    return _stats(np.linalg.norm(est - tru, axis=1))


def interpolate_xy(poses: pd.DataFrame, walk_id: str, t_s: np.ndarray) -> np.ndarray:
    """Positions (len(t_s), 2) of one walk at times ``t_s`` (linear between poses; NaN outside the span)."""
    w = poses[poses["walk_id"] == walk_id]
    out = np.full((len(t_s), 2), np.nan)
    if len(w) == 0:
        return out
    tt = w["t_s"].to_numpy(dtype=float)
    inside = (t_s >= tt[0]) & (t_s <= tt[-1])
    for j, col in enumerate(("x_m", "y_m")):
        out[inside, j] = np.interp(t_s[inside], tt, w[col].to_numpy(dtype=float))
    return out


def estimates_at_fixes(poses: pd.DataFrame, fix_walk: np.ndarray, fix_t: np.ndarray) -> np.ndarray:
    """Positions (n_fixes, 2) of ``poses`` at each fix's walk and time, as :func:`interpolate_xy` gives them
    walk by walk (NaN outside a walk's span or for an unknown walk); the poses are grouped once."""
    est = np.full((len(fix_walk), 2), np.nan)
    rows = pd.Series(np.arange(len(poses))).groupby(poses["walk_id"].astype(str).to_numpy(), sort=False).indices
    t = poses["t_s"].to_numpy(dtype=float)
    xy = poses[["x_m", "y_m"]].to_numpy(dtype=float)
    for wid in np.unique(fix_walk):
        r = rows.get(str(wid))
        if r is None or len(r) == 0:
            continue
        m = fix_walk == wid
        tt, ft = t[r], fix_t[m]
        inside = (ft >= tt[0]) & (ft <= tt[-1])
        out = np.full((len(ft), 2), np.nan)
        for j in range(2):
            out[inside, j] = np.interp(ft[inside], tt, xy[r, j])
        est[m] = out
    return est


def landmark_error(
    poses: pd.DataFrame, fixes: pd.DataFrame, world_R: np.ndarray | None = None, world_t: np.ndarray | None = None
) -> dict[str, float] | None:
    """Error (m) at landmark fixes: mean, std, max, n.

    ``poses``: walk_id, t_s, x_m, y_m (estimate); ``fixes``: walk_id, t_s, x_m, y_m (truth, building frame).
    The estimate at each fix's time is interpolated between poses of the fix's walk, then mapped by the
    optional global alignment ``world_R @ p + world_t`` (from :func:`align_se2` on all poses).
    """
    if fixes is None or len(fixes) == 0:
        return None
    est = estimates_at_fixes(poses, fixes["walk_id"].astype(str).to_numpy(), fixes["t_s"].to_numpy(dtype=float))
    if world_R is not None:
        est = est @ np.asarray(world_R).T + (0 if world_t is None else np.asarray(world_t))
    ok = np.isfinite(est).all(axis=1)
    if ok.sum() == 0:
        return None
    err = np.linalg.norm(est[ok] - fixes[["x_m", "y_m"]].to_numpy(dtype=float)[ok], axis=1)
    return {"mean": float(err.mean()), "std": float(err.std()), "max": float(err.max()), "n": int(ok.sum())}


def heading_alignment_error_deg(
    poses: pd.DataFrame, truth: pd.DataFrame, world_R: np.ndarray | None = None
) -> dict[str, float] | None:
    """Per-walk heading alignment error (deg): mean and std over walks of |rotation of walk vs truth|.

    ``poses`` and ``truth`` have the same rows (walk_id, x_m, y_m). After the single global rotation
    ``world_R`` (if given), each walk's estimated trajectory is fitted rigidly onto its true one; the
    fitted rotation angle is how far that walk's frame is turned against truth (Gu et al. 2017's 12-walk figure).
    Walks with fewer than 2 distinct positions are skipped.
    """
    if truth is None or len(truth) != len(poses):
        return None
    est = poses[["x_m", "y_m"]].to_numpy(dtype=float)
    if world_R is not None:
        est = est @ np.asarray(world_R).T
    tru = truth[["x_m", "y_m"]].to_numpy(dtype=float)
    errs = []
    wids = poses["walk_id"].astype(str).to_numpy()
    for wid in pd.unique(wids):
        m = wids == wid
        if m.sum() < 2 or np.ptp(tru[m], axis=0).max() < 1e-6:
            continue
        r, _ = align_se2(est[m], tru[m])
        errs.append(abs(math.degrees(rotation_angle_rad(r))))
    if not errs:
        return None
    e = np.asarray(errs)
    return {"mean": float(e.mean()), "std": float(e.std())}


def trajectory_metrics(poses_df: pd.DataFrame, dataset, align: bool = True, fit_walks=None) -> dict:
    """The METRICS block of ``optimize/report.json`` for one set of poses.

    ``poses_df``: walk_id, step, t_s, x_m, y_m, heading_rad in ``dataset.poses`` row order (e.g. the raw
    poses, or the optimised ones). ``align``: one SE(2) transform, applied to all walks together, is fitted
    onto truth first (no anchors). It is fitted on the walks named in ``fit_walks`` (default: all) — the
    optimiser passes the walks it linked, so that a walk it reports as unplaced (its frame arbitrary) does
    not turn and shift every other walk's figures; that walk's own error still counts in full. The fit
    uses the truth poses when they exist, otherwise the fixes. Returns ``{"ate_m", "landmark_error_m",
    "heading_alignment_error_deg"}`` with ``None`` for what cannot be computed, and with ``fit_walks``
    ``"landmark_error_fitted_walks_m"``: the landmark error of those walks alone.
    """
    truth: pd.DataFrame | None = getattr(dataset, "truth_poses", None)
    fixes = getattr(dataset, "fixes", None)
    if truth is not None and not 0 < len(truth) == len(poses_df):
        truth = None  # no truth row per pose: landmark errors only
    wids = poses_df["walk_id"].astype(str).to_numpy()
    sel = np.ones(len(poses_df), bool) if fit_walks is None else np.isin(wids, [str(w) for w in fit_walks])
    world_R, world_t = np.eye(2), np.zeros(2)
    if align:
        if truth is not None:
            est = poses_df[["x_m", "y_m"]].to_numpy(float)
            tru = truth[["x_m", "y_m"]].to_numpy(float)
            use = sel if sel.sum() >= 2 else np.ones(len(est), bool)
            world_R, world_t = align_se2(est[use], tru[use])
        elif fixes is not None and len(fixes) >= 2:
            fw = fixes["walk_id"].astype(str).to_numpy()
            est = estimates_at_fixes(poses_df, fw, fixes["t_s"].to_numpy(float))
            ok = np.isfinite(est).all(axis=1)
            if fit_walks is not None:
                named = ok & np.isin(fw, [str(w) for w in fit_walks])
                ok = named if named.sum() >= 2 else ok
            if ok.sum() >= 2:
                world_R, world_t = align_se2(est[ok], fixes[["x_m", "y_m"]].to_numpy(float)[ok])
    out: dict = {"ate_m": None, "landmark_error_m": None, "heading_alignment_error_deg": None}
    if truth is not None:
        est = poses_df[["x_m", "y_m"]].to_numpy(float) @ world_R.T + world_t
        out["ate_m"] = ate(est, truth[["x_m", "y_m"]].to_numpy(float), align=False)
        out["heading_alignment_error_deg"] = heading_alignment_error_deg(poses_df, truth, world_R)
    if fixes is not None and len(fixes) > 0:
        out["landmark_error_m"] = landmark_error(poses_df, fixes, world_R, world_t)
        if fit_walks is not None:
            mine = fixes[fixes["walk_id"].astype(str).isin([str(w) for w in fit_walks])]
            out["landmark_error_fitted_walks_m"] = (landmark_error(poses_df, mine, world_R, world_t) if len(mine)
                                                    else None)
    return out
