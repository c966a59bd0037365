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
           "landmark_error_unlinked_at_raw", "rotation_angle_rad", "trajectory_metrics"]


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
    for wid, m in walk_rows(fix_walk).items():
        r = rows.get(wid)
        if r is None or len(r) == 0:
            continue
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
    return _fix_stats(fix_errors(poses, fixes, world_R, world_t))


def fix_errors(poses: pd.DataFrame, fixes: pd.DataFrame, world_R: np.ndarray | None = None,
               world_t: np.ndarray | None = None) -> np.ndarray:
    """(len(fixes),) error (m) at each fix as :func:`landmark_error` measures it; NaN where the fix's walk
    has no estimate at its time."""
    est = estimates_at_fixes(poses, fixes["walk_id"].astype(str).to_numpy(), fixes["t_s"].to_numpy(dtype=float))
    if world_R is not None:
        est = est @ np.asarray(world_R).T + (0 if world_t is None else np.asarray(world_t))
    return np.linalg.norm(est - fixes[["x_m", "y_m"]].to_numpy(dtype=float), axis=1)


def _fix_stats(err: np.ndarray) -> dict[str, float] | None:
    err = err[np.isfinite(err)]
    if len(err) == 0:
        return None
    return {"mean": float(err.mean()), "std": float(err.std()), "max": float(err.max()), "n": int(len(err))}


def landmark_error_unlinked_at_raw(raw_poses: pd.DataFrame, opt_poses: pd.DataFrame, dataset, linked,
                                   align: bool = True) -> dict[str, float] | None:
    """Landmark error of all walks with the walks not in ``linked`` counted at their raw placement: the
    linked walks' fixes on ``opt_poses`` (one SE(2) fit on the linked walks when ``align``, else as placed),
    the others' on ``raw_poses`` (one SE(2) fit on all walks, as the raw figure has it). An unlinked walk's
    optimised frame is arbitrary and it is left out of the map, so it counts where dead reckoning alone puts
    it: the figure that says whether optimising made the walks worse than raw. None without fixes or when
    every walk is linked."""
    fixes = getattr(dataset, "fixes", None)
    if fixes is None or len(fixes) == 0:
        return None
    mine = fixes["walk_id"].astype(str).isin([str(w) for w in linked]).to_numpy()
    if mine.all():
        return None
    R_o, t_o = metric_alignment(opt_poses, dataset, linked) if align else (np.eye(2), np.zeros(2))
    R_r, t_r = metric_alignment(raw_poses, dataset, None)
    err = np.r_[fix_errors(opt_poses, fixes[mine], R_o, t_o), fix_errors(raw_poses, fixes[~mine], R_r, t_r)]
    return _fix_stats(err)


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
    for m in walk_rows(poses["walk_id"]).values():
        if len(m) < 2 or np.ptp(tru[m], axis=0).max() < 1e-6:
            continue
        r, _ = align_se2(est[m], tru[m])
        errs.append(abs(math.degrees(rotation_angle_rad(r))))
    if not errs:
        return None
    e = np.asarray(errs)
    return {"mean": float(e.mean()), "std": float(e.std())}


def walk_rows(walk_ids) -> dict[str, np.ndarray]:
    """Walk id (as text) -> its row indices (walks in order of first appearance, rows ascending): one
    grouping of the column instead of comparing every row's id once per walk."""
    codes, uniq = pd.factorize(pd.Series(walk_ids).astype(str))
    order = np.argsort(codes, kind="stable")
    bounds = np.r_[0, np.cumsum(np.bincount(codes, minlength=len(uniq)))]
    return {str(w): order[bounds[k]:bounds[k + 1]] for k, w in enumerate(uniq)}


def named(walk_ids, names) -> np.ndarray:
    """bool (len(walk_ids),): the entries whose id (as text) is one of ``names`` (a hash lookup per entry:
    numpy's ``isin`` on text columns sorts both sides)."""
    return pd.Series(walk_ids).astype(str).isin({str(w) for w in names}).to_numpy()


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
    truth = _truth_per_pose(dataset, poses_df)
    fixes = getattr(dataset, "fixes", None)
    world_R, world_t = metric_alignment(poses_df, dataset, fit_walks) if align else (np.eye(2), np.zeros(2))
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


def _truth_per_pose(dataset, poses_df: pd.DataFrame) -> pd.DataFrame | None:
    """The dataset's truth poses when there is one row per pose, else None (landmark errors only)."""
    truth: pd.DataFrame | None = getattr(dataset, "truth_poses", None)
    return truth if truth is not None and 0 < len(truth) == len(poses_df) else None


def metric_alignment(poses_df: pd.DataFrame, dataset, fit_walks) -> tuple[np.ndarray, np.ndarray]:
    """One SE(2) (R, t) onto the truth for all walks, fitted on the walks named in ``fit_walks`` (None:
    all; all too when fewer than 2 points are named): on the truth poses when there is one per pose,
    else on the fixes; identity when neither gives 2 points."""
    truth, fixes = _truth_per_pose(dataset, poses_df), getattr(dataset, "fixes", None)
    sel = np.ones(len(poses_df), bool) if fit_walks is None else named(poses_df["walk_id"], fit_walks)
    if truth is not None:
        est = poses_df[["x_m", "y_m"]].to_numpy(float)
        use = sel if sel.sum() >= 2 else np.ones(len(est), bool)
        return align_se2(est[use], truth[["x_m", "y_m"]].to_numpy(float)[use])
    if fixes is None or len(fixes) < 2:
        return np.eye(2), np.zeros(2)
    fw = fixes["walk_id"].astype(str).to_numpy()
    est = estimates_at_fixes(poses_df, fw, fixes["t_s"].to_numpy(float))
    ok = np.isfinite(est).all(axis=1)
    if fit_walks is not None:
        on_named = ok & named(fw, fit_walks)
        ok = on_named if on_named.sum() >= 2 else ok
    if ok.sum() < 2:
        return np.eye(2), np.zeros(2)
    return align_se2(est[ok], fixes[["x_m", "y_m"]].to_numpy(float)[ok])
