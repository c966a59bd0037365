"""Global initialisation: each walk's frame (world_T_walk) from cross-walk vicinity candidates.

1. Per walk, the frame rotation from the absolute heading when present: the circular mean over steps of
   ``yaw_abs_rad − heading_rad`` (the walk's own-frame heading), in the magnetometer world.
2. Per pair of walks (A, B) with candidates, a RANSAC estimate of A_T_B: translation-only (rotation from
   the two magnetometer rotations) when both headings are known, otherwise SE(2) from 2-pair samples;
   refined on the inliers and accepted only with enough inliers, inlier ratio and shared path.
3. Accepted walk pairs form the walk graph; its connected components are found, a maximum spanning tree
   (by inliers) chains the transforms from the reference walk, then a walk-level pose graph (robust
   between factors + magnetometer heading priors) refines them.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import pandas as pd
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from rmbuild.config.optimize import InitConfig
from rmbuild.evaluate.trajectory import align_se2, rotation_angle_rad
from rmbuild.slam.factors import W


def _rot(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s], [s, c]])


def yaw_sigma(poses: pd.DataFrame, icfg: InitConfig) -> np.ndarray:
    """Per-step 1-sigma (rad) of yaw_abs (the poses column, or the config default where NaN)."""
    s = poses["yaw_abs_sigma_rad"].to_numpy(float) if "yaw_abs_sigma_rad" in poses else np.full(len(poses), np.nan)
    return np.where(np.isfinite(s) & (s > 0), s, icfg.default_yaw_sigma_rad)


def walk_abs_rotation(poses: pd.DataFrame, starts, ends, icfg: InitConfig):
    """(theta, known, sigma), each (n_walks,): each walk frame's rotation (rad) in the heading world,
    whether the walk has yaw_abs, and the rotation's 1-sigma (rad, see InitConfig)."""
    yaw = poses["yaw_abs_rad"].to_numpy(float) if "yaw_abs_rad" in poses else np.full(len(poses), np.nan)
    own = poses["heading_rad"].to_numpy(float)
    ysig = yaw_sigma(poses, icfg)
    th = np.zeros(len(starts))
    sig = np.full(len(starts), np.inf)
    known = np.zeros(len(starts), bool)
    for w, (s, e) in enumerate(zip(starts, ends)):
        z = np.exp(1j * (yaw[s:e] - own[s:e]))
        ok = np.isfinite(z)
        if ok.any():
            th[w] = np.angle(z[ok].mean())
            known[w] = True
            n_ind = max(1.0, ok.sum() / icfg.abs_heading_corr_steps)
            sig[w] = max(icfg.abs_heading_sigma_rad, float(np.median(ysig[s:e][ok])) / np.sqrt(n_ind))
    return th, known, sig


def _covered_m(path: np.ndarray, bin_m: float = 3.0) -> float:
    """Walked length (m) covered by a set of nodes: distinct ``bin_m`` bins of their path position."""
    return float(len(np.unique(np.floor(np.asarray(path) / bin_m)))) * bin_m


@dataclass
class PairFit:
    a: int
    b: int
    T: np.ndarray  # (3,) A_T_B (x, y, theta)
    n_cand: int
    inliers: np.ndarray  # bool over the candidates of this walk pair
    shared_m: float
    accepted: bool


def ransac_walk_pair(pa, pb, path_a, path_b, rot_ab: float | None, icfg: InitConfig,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Robust A_T_B from candidate point pairs pa (m, 2) in A's frame ~ pb (m, 2) in B's frame.

    ``rot_ab``: known relative rotation (rad) or None (estimate SE(2)). Returns (T (3,), inlier mask).
    """
    m = len(pa)
    gate = icfg.ransac_gate_m
    if rot_ab is not None:
        R = _rot(rot_ab)
        t_all = pa - pb @ R.T
        hyp = np.arange(m) if m <= icfg.ransac_iterations else rng.choice(m, icfg.ransac_iterations, False)
        score = (np.linalg.norm(t_all[hyp][:, None, :] - t_all[None, :, :], axis=2) < gate).sum(axis=1)
        t = t_all[hyp[np.argmax(score)]]
        th = rot_ab
    else:
        if m < 2:
            return np.zeros(3), np.zeros(m, bool)
        i1 = rng.integers(0, m, icfg.ransac_iterations)
        i2 = rng.integers(0, m, icfg.ransac_iterations)
        va, vb = pa[i2] - pa[i1], pb[i2] - pb[i1]
        ok = (np.linalg.norm(va, axis=1) > 2 * gate) & (np.linalg.norm(vb, axis=1) > 2 * gate)
        if not ok.any():
            return np.zeros(3), np.zeros(m, bool)
        i1, i2, va, vb = i1[ok], i2[ok], va[ok], vb[ok]
        ths = np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0])
        c, s = np.cos(ths), np.sin(ths)
        mb = (pb[i1] + pb[i2]) / 2
        ma = (pa[i1] + pa[i2]) / 2
        ts = ma - np.c_[c * mb[:, 0] - s * mb[:, 1], s * mb[:, 0] + c * mb[:, 1]]
        # (h, m) residuals
        px = c[:, None] * pb[None, :, 0] - s[:, None] * pb[None, :, 1] + ts[:, 0:1]
        py = s[:, None] * pb[None, :, 0] + c[:, None] * pb[None, :, 1] + ts[:, 1:2]
        score = (np.hypot(px - pa[None, :, 0], py - pa[None, :, 1]) < gate).sum(axis=1)
        h = int(np.argmax(score))
        th, t = float(ths[h]), ts[h]
    for _ in range(3):  # refine on inliers
        res = np.linalg.norm(pa - (pb @ _rot(th).T + t), axis=1)
        inl = res < gate
        if inl.sum() < 2:
            break
        if rot_ab is None or (min(_covered_m(path_a[inl]), _covered_m(path_b[inl]))
                              >= icfg.refit_rotation_min_path_m):
            R, t = align_se2(pb[inl], pa[inl])
            th = rotation_angle_rad(R)
        else:
            t = np.mean(pa[inl] - pb[inl] @ _rot(th).T, axis=0)
    inl = np.linalg.norm(pa - (pb @ _rot(th).T + t), axis=1) < gate
    return np.array([t[0], t[1], th]), inl


@dataclass
class InitResult:
    world_T_walk: np.ndarray  # (n_walks, 3)
    component: np.ndarray  # (n_walks,) component id (reference walk's component = 0)
    linked: np.ndarray  # (n_walks,) bool: in the reference walk's component
    reference: int
    fits: list[PairFit]
    heading_known: np.ndarray
    abs_rot: np.ndarray
    grow: object | None = None  # the GrowResult of method "grow"
    links: tuple | None = None  # (node_k, node_q) scan links that placed walks (grow, knn evidence)


def initialise(raw: np.ndarray, path: np.ndarray, walk_of_node: np.ndarray, n_walks: int,
               cand: pd.DataFrame, abs_rot: np.ndarray, abs_known: np.ndarray, abs_sig: np.ndarray,
               icfg: InitConfig,
               reference_walk: int | None) -> InitResult:
    """Walk frames from cross-walk candidates (columns node_k, node_q). See the module docstring."""
    rng = np.random.default_rng(icfg.seed)
    use_abs = icfg.use_abs_heading
    nk, nq = cand["node_k"].to_numpy(), cand["node_q"].to_numpy()
    wk, wq = walk_of_node[nk], walk_of_node[nq]
    a_w, b_w = np.minimum(wk, wq), np.maximum(wk, wq)
    swap = wk > wq
    na, nb = np.where(swap, nq, nk), np.where(swap, nk, nq)
    order = np.lexsort((b_w, a_w))
    fits: list[PairFit] = []
    key = a_w[order].astype(np.int64) * n_walks + b_w[order]
    bounds = np.r_[0, np.flatnonzero(np.diff(key)) + 1, len(key)] if len(key) else np.array([0])
    for g0, g1 in zip(bounds[:-1], bounds[1:]):
        idx = order[g0:g1]
        a, b = int(a_w[idx[0]]), int(b_w[idx[0]])
        if a == b:
            continue
        pa, pb = raw[na[idx], :2], raw[nb[idx], :2]
        rot_ab = None
        if use_abs and abs_known[a] and abs_known[b]:
            rot_ab = float(np.angle(np.exp(1j * (abs_rot[b] - abs_rot[a]))))
        T, inl = ransac_walk_pair(pa, pb, path[na[idx]], path[nb[idx]], rot_ab, icfg, rng)
        shared = min(_covered_m(path[na[idx][inl]]), _covered_m(path[nb[idx][inl]])) if inl.any() else 0.0
        ok = (inl.sum() >= icfg.min_inliers and inl.mean() >= icfg.min_inlier_ratio
              and shared >= icfg.min_shared_path_m)
        fit = PairFit(a, b, T, len(idx), np.zeros(len(cand), bool), shared, bool(ok))
        fit.inliers[idx[inl]] = True
        fits.append(fit)
    acc = [f for f in fits if f.accepted]
    wgt = np.array([f.inliers.sum() for f in acc], float)
    if acc:
        A = coo_matrix((wgt, ([f.a for f in acc], [f.b for f in acc])), shape=(n_walks, n_walks)).tocsr()
    else:
        A = coo_matrix((n_walks, n_walks)).tocsr()
    n_comp, comp = connected_components(A, directed=False)
    if reference_walk is None:
        deg = np.zeros(n_walks)
        for f in acc:
            deg[f.a] += f.inliers.sum()
            deg[f.b] += f.inliers.sum()
        sizes = np.bincount(comp, minlength=n_comp)
        big = comp == np.argmax(sizes)
        reference_walk = int(np.argmax(np.where(big, deg, -1)))
    # relabel components so the reference walk's is 0
    ref_c = comp[reference_walk]
    comp = np.where(comp == ref_c, -1, comp)
    _, comp = np.unique(comp, return_inverse=True)
    # maximum spanning tree (minimum on 1/weight) and BFS chaining from each component's root
    T = np.zeros((n_walks, 3))
    if acc:
        inv = coo_matrix((1.0 / wgt, ([f.a for f in acc], [f.b for f in acc])), shape=(n_walks, n_walks))
        mst = minimum_spanning_tree(inv).tocoo()
        edges = {}
        fit_of = {(f.a, f.b): f for f in acc}
        for i, j in zip(mst.row, mst.col):
            a, b = (i, j) if i < j else (j, i)
            edges.setdefault(int(a), []).append(int(b))
            edges.setdefault(int(b), []).append(int(a))
        done = np.zeros(n_walks, bool)
        roots = [reference_walk] + [int(np.flatnonzero(comp == c)[0]) for c in range(1, comp.max() + 1)]
        for r in roots:
            if use_abs and abs_known[r] and abs_known[reference_walk] and r != reference_walk:
                T[r, 2] = np.angle(np.exp(1j * (abs_rot[r] - abs_rot[reference_walk])))
            done[r] = True
            stack = [r]
            while stack:
                u = stack.pop()
                for v in edges.get(u, []):
                    if done[v]:
                        continue
                    f = fit_of[(min(u, v), max(u, v))]
                    rel = f.T if f.a == u else _inverse(f.T)
                    T[v] = _compose(T[u], rel)
                    done[v] = True
                    stack.append(v)
        T = _refine_walk_graph(T, acc, comp, reference_walk, abs_rot, abs_known & use_abs, abs_sig, icfg)
    else:
        for w in range(n_walks):
            if use_abs and abs_known[w] and abs_known[reference_walk]:
                T[w, 2] = np.angle(np.exp(1j * (abs_rot[w] - abs_rot[reference_walk])))
    return InitResult(T, comp, comp == 0, reference_walk, fits, abs_known & use_abs, abs_rot)


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    R = _rot(a[2])
    t = a[:2] + R @ b[:2]
    return np.array([t[0], t[1], np.angle(np.exp(1j * (a[2] + b[2])))])


def _inverse(a: np.ndarray) -> np.ndarray:
    R = _rot(a[2])
    t = -R.T @ a[:2]
    return np.array([t[0], t[1], -a[2]])


def _refine_walk_graph(T0, acc, comp, ref, abs_rot, abs_known, abs_sig, icfg: InitConfig) -> np.ndarray:
    """Walk-level pose graph: Huber between factors (sigma from the inlier geometry), magnetometer
    heading priors, a gauge prior on the reference walk and on each other component's root."""
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    n = len(T0)
    for w in range(n):
        v.insert(W(w), gtsam.Pose2(*T0[w]))
    for f in acc:
        k = max(int(f.inliers.sum()), 1)
        s_t = icfg.ransac_gate_m / np.sqrt(k)
        s_r = max(icfg.ransac_gate_m / max(f.shared_m, 1.0) / np.sqrt(k), 1e-3)
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber(1.345),
                                               gtsam.noiseModel.Diagonal.Sigmas(np.array([s_t, s_t, s_r])))
        g.add(gtsam.BetweenFactorPose2(W(f.a), W(f.b), gtsam.Pose2(*f.T), noise))
    tight = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    g.add(gtsam.PriorFactorPose2(W(ref), gtsam.Pose2(*T0[ref]), tight))
    for c in range(1, comp.max() + 1):
        r = int(np.flatnonzero(comp == c)[0])
        g.add(gtsam.PriorFactorPose2(W(r), gtsam.Pose2(*T0[r]), tight))
    if abs_known[ref]:
        for w in range(n):
            if abs_known[w] and w != ref:
                hn = gtsam.noiseModel.Isotropic.Sigma(1, float(np.hypot(abs_sig[w], abs_sig[ref])))
                g.add(gtsam.PoseRotationPrior2D(W(w), gtsam.Pose2(0, 0, abs_rot[w] - abs_rot[ref]), hn))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    res = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
    out = np.empty_like(T0)
    for w in range(n):
        p = res.atPose2(W(w))
        out[w] = (p.x(), p.y(), p.theta())
    return out
