"""Rigid fits of one walk to the placed map, and the rules that accept them.

Two kinds of correspondences give a walk's own-frame points and their positions on the map:
- candidate pairs (:func:`fit_to_pairs`): a walk node and a placed node that look alike; a node may have
  several, so the score counts *distinct* inlier walk nodes, and the fit is compared with the best
  hypothesis that puts the walk elsewhere (margin and lead);
- localised scans (:func:`fit_to_scans`): each scan's map position from its nearest placed scans; the
  score counts inlier scans and a walk needs a share of its covered scans as inliers.
With the walk's compass rotation the fit is a translation (RANSAC over single correspondences), else
SE(2) (RANSAC over pairs of correspondences that span > 2 gates), refined on its inliers.
"""

from __future__ import annotations

import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import PlacementConfig
from rmbuild.slam.placement.model import WalkFit
from rmbuild.slam.problem import covered_m

# RANSAC hypotheses per fit (translation: every correspondence up to this many; SE(2): 2-point samples)
RANSAC_HYPOTHESES = 300
# kNN placement: a walk needs this share of its covered scans as inliers
KNN_MIN_INLIER_FRAC = 0.5


def _score(inl: np.ndarray, wnode_idx: np.ndarray, n_u: int) -> np.ndarray:
    """Distinct walk nodes among each row's inliers: inl (h, m) bool -> (h,) counts."""
    onehot = np.zeros((inl.shape[1], n_u), np.float32)
    onehot[np.arange(inl.shape[1]), wnode_idx] = 1.0
    return ((inl.astype(np.float32) @ onehot) > 0).sum(axis=1)


def fit_to_pairs(pm: np.ndarray, pw: np.ndarray, wnode: np.ndarray, wpath: np.ndarray, mwalk: np.ndarray,
                 rot: float | None, cfg: PlacementConfig, rng: np.random.Generator) -> WalkFit | None:
    """Fit one walk to the placed map from pairs (map position pm (m, 2), walk own-frame position pw (m, 2)).

    ``wnode``: the walk node of each pair; ``wpath``: its walked distance (m); ``mwalk``: the map node's walk.
    ``rot``: the walk frame's rotation when known (translation-only), else None (SE(2) from 2-pair samples).
    """
    m = len(pm)
    if m == 0:
        return None
    gate = cfg.gate_m
    _, widx = np.unique(wnode, return_inverse=True)
    n_u = int(widx.max()) + 1
    if rot is not None:
        t_all = pm - pw @ geometry.rot(rot).T
        hyp = np.arange(m) if m <= RANSAC_HYPOTHESES else rng.choice(m, RANSAC_HYPOTHESES, False)
        inl = np.linalg.norm(t_all[hyp][:, None, :] - t_all[None, :, :], axis=2) < gate
        score = _score(inl, widx, n_u)
        h = int(np.argmax(score))
        T0 = np.array([t_all[hyp[h], 0], t_all[hyp[h], 1], rot])
        ths, ts = np.full(len(hyp), rot), t_all[hyp]
    else:
        if m < 2:
            return None
        H = geometry.two_point_hypotheses(pm, pw, 2 * gate, RANSAC_HYPOTHESES, rng)
        if H is None:
            return None
        score = _score(H.residuals(pm) < gate, widx, n_u)
        h = int(np.argmax(score))
        ths, ts = H.theta, H.t
        T0 = np.array([ts[h, 0], ts[h, 1], float(ths[h])])
    T, inl_final = geometry.refine_on_inliers(pw, pm, T0, gate, se2=rot is None)
    best = int(len(np.unique(widx[inl_final])))
    # the best hypothesis that places the walk elsewhere (its centroid > 2 gates away)
    cen = pw.mean(axis=0)
    c_best = geometry.rot(T[2]) @ cen + T[:2]
    c_h = np.c_[np.cos(ths) * cen[0] - np.sin(ths) * cen[1], np.sin(ths) * cen[0] + np.cos(ths) * cen[1]] + ts
    far = np.linalg.norm(c_h - c_best, axis=1) > 2 * gate
    second = int(score[far].max()) if far.any() else 0
    return WalkFit(np.array([T[0], T[1], float(geometry.wrap(T[2]))]), best, second,
                   covered_m(wpath[inl_final]) if inl_final.any() else 0.0,
                   int(len(np.unique(mwalk[inl_final]))), "translation" if rot is not None else "se2", inl_final)


def fit_to_scans(p_own: np.ndarray, x_hat: np.ndarray, path: np.ndarray, rot: float | None,
                 cfg: PlacementConfig, rng: np.random.Generator) -> WalkFit | None:
    """Rigid fit of a walk's scans (own-frame p_own (m, 2)) to their map-localised positions x_hat (m, 2):
    translation-only with a known rotation, else SE(2) from 2-point samples. Score = inlier scans."""
    m = len(p_own)
    gate = cfg.gate_m
    if m == 0:
        return None
    if rot is not None:
        o = x_hat - p_own @ geometry.rot(rot).T
        cnt = (np.linalg.norm(o[:, None] - o[None], axis=2) < gate).sum(axis=1)
        h = int(np.argmax(cnt))
        T0 = np.array([o[h, 0], o[h, 1], rot])
    else:
        if m < 2:
            return None
        H = geometry.two_point_hypotheses(x_hat, p_own, 2 * gate, RANSAC_HYPOTHESES, rng)
        if H is None:
            return None
        h = int(np.argmax((H.residuals(x_hat) < gate).sum(axis=1)))
        T0 = np.array([H.t[h, 0], H.t[h, 1], float(H.theta[h])])
    T, inl = geometry.refine_on_inliers(p_own, x_hat, T0, gate, se2=rot is None)
    return WalkFit(np.array([T[0], T[1], float(geometry.wrap(T[2]))]), int(inl.sum()), m - int(inl.sum()),
                   covered_m(path[inl]) if inl.any() else 0.0, 0, "translation" if rot is not None else "se2", inl)


def _min_path(cfg: PlacementConfig, se2: bool) -> float:
    return cfg.min_shared_se2_m if se2 else cfg.min_shared_m


def accept_pairs_fit(f: WalkFit | None, se2: bool, cfg: PlacementConfig) -> bool:
    """A pairs fit: enough distinct inliers and shared path, leading the best placement elsewhere."""
    if f is None:
        return False
    min_inl = 2 * cfg.min_inliers if se2 else cfg.min_inliers
    return bool(f.score >= min_inl and f.shared_m >= _min_path(cfg, se2) and f.score >= cfg.margin * f.second
                and f.score >= f.second + cfg.min_lead)


def accept_scans_fit(f: WalkFit | None, se2: bool, cfg: PlacementConfig) -> bool:
    """A localised-scans fit: enough inliers, shared path and share of the covered scans."""
    if f is None:
        return False
    min_inl = 2 * cfg.min_inliers if se2 else cfg.min_inliers
    return bool(f.score >= min_inl and f.shared_m >= _min_path(cfg, se2)
                and f.score >= KNN_MIN_INLIER_FRAC * (f.score + f.second))
