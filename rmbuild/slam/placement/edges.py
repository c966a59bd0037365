"""Walk-pair edges: a rigid fit of one walk to another from their links alone.

Two long walks that share a long stretch can be fitted to each other even when the map placed so far
offers too little to place either: per pair of walks with links, a RANSAC estimate of A_T_B (translation
only with both compass rotations, else SE(2) from 2-link samples), refined on its inliers and accepted
with PAIR_MIN_INLIERS inliers, PAIR_MIN_INLIER_RATIO of the pair's links and PAIR_MIN_SHARED_M of
shared path. The placement loop falls back on these edges when no walk fits the map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild import geometry
from rmbuild.slam.evidence.base import Links, RotationPriors
from rmbuild.slam.placement.fits import RANSAC_HYPOTHESES
from rmbuild.slam.problem import WalkSet, covered_m

# m; a link is an inlier of a walk-pair fit when it puts its two nodes this close
PAIR_GATE_M = 3.0
PAIR_MIN_INLIERS = 5
PAIR_MIN_INLIER_RATIO = 0.2
PAIR_MIN_SHARED_M = 8.0
# RNG seed of the RANSAC samplers (results are deterministic)
RANSAC_SEED = 0


@dataclass
class PairEdge:
    a: int
    b: int
    T: np.ndarray  # (3,) A_T_B
    accepted: bool


def pair_edges(walks: WalkSet, links: Links, rot: RotationPriors, min_shared_se2_m: float) -> list[PairEdge]:
    """Every walk pair with links, fitted (module docstring); ``min_shared_se2_m``: shared path (m) above
    which a translation fit refits its rotation too."""
    rng = np.random.default_rng(RANSAC_SEED)
    wo, path, raw = walks.walk_of, walks.path, walks.raw
    nk, nq = links.node_k, links.node_q
    wk, wq = wo[nk], wo[nq]
    a_w, b_w = np.minimum(wk, wq), np.maximum(wk, wq)
    swap = wk > wq
    na, nb = np.where(swap, nq, nk), np.where(swap, nk, nq)
    order = np.lexsort((b_w, a_w))
    key = a_w[order].astype(np.int64) * walks.n_walks + b_w[order]
    bounds = np.r_[0, np.flatnonzero(np.diff(key)) + 1, len(key)] if len(key) else np.array([0])
    out = []
    for g0, g1 in zip(bounds[:-1], bounds[1:]):
        idx = order[g0:g1]
        a, b = int(a_w[idx[0]]), int(b_w[idx[0]])
        if a == b:
            continue
        rot_ab = float(geometry.wrap(rot.theta[b] - rot.theta[a])) if rot.known[a] and rot.known[b] else None
        T, inl = fit_walk_pair(raw[na[idx], :2], raw[nb[idx], :2], path[na[idx]], path[nb[idx]], rot_ab,
                               min_shared_se2_m, rng)
        shared = min(covered_m(path[na[idx][inl]]), covered_m(path[nb[idx][inl]])) if inl.any() else 0.0
        ok = inl.sum() >= PAIR_MIN_INLIERS and inl.mean() >= PAIR_MIN_INLIER_RATIO and shared >= PAIR_MIN_SHARED_M
        out.append(PairEdge(a, b, T, bool(ok)))
    return out


def fit_walk_pair(pa, pb, path_a, path_b, rot_ab: float | None, min_shared_se2_m: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Robust A_T_B from link points pa (m, 2) in A's frame ~ pb (m, 2) in B's frame; ``rot_ab``: known
    relative rotation (rad) or None (estimate SE(2)). Returns (T (3,), inlier mask)."""
    m = len(pa)
    gate = PAIR_GATE_M
    if rot_ab is not None:
        t_all = pa - pb @ geometry.rot(rot_ab).T
        hyp = np.arange(m) if m <= RANSAC_HYPOTHESES else rng.choice(m, RANSAC_HYPOTHESES, False)
        score = (np.linalg.norm(t_all[hyp][:, None, :] - t_all[None, :, :], axis=2) < gate).sum(axis=1)
        t = t_all[hyp[np.argmax(score)]]
        th = rot_ab
    else:
        if m < 2:
            return np.zeros(3), np.zeros(m, bool)
        H = geometry.two_point_hypotheses(pa, pb, 2 * gate, RANSAC_HYPOTHESES, rng)
        if H is None:
            return np.zeros(3), np.zeros(m, bool)
        h = int(np.argmax((H.residuals(pa) < gate).sum(axis=1)))
        th, t = float(H.theta[h]), H.t[h]
    for _ in range(3):  # refine on inliers
        inl = np.linalg.norm(pa - (pb @ geometry.rot(th).T + t), axis=1) < gate
        if inl.sum() < 2:
            break
        if rot_ab is None or min(covered_m(path_a[inl]), covered_m(path_b[inl])) >= min_shared_se2_m:
            T = geometry.fit_rigid(pb[inl], pa[inl])
            th, t = float(T[2]), T[:2]
        else:
            t = np.mean(pa[inl] - pb[inl] @ geometry.rot(th).T, axis=0)
    inl = np.linalg.norm(pa - (pb @ geometry.rot(th).T + t), axis=1) < gate
    return np.array([t[0], t[1], th]), inl
