"""Incremental walk-to-map placement ("grow") and a robust walk-level refinement.

Short crowdsourced walks mostly just cross each other: a pair of walks rarely shares enough path to be
verified on its own (FINDINGS: 30-second phone walks). Verifying a walk against the *map built so far*
pools the evidence of every placed walk it meets, so:

1. Seed: the reference walk is placed (its own frame is the common frame).
2. Each round, every unplaced walk W is fitted against the placed map from its candidate pairs with a
   placed node: translation-only RANSAC when both W's and the map's absolute heading are known (W's
   rotation from the magnetometer), otherwise (or when that fails and the walk is long enough to observe
   its rotation) SE(2) RANSAC. A fit is accepted with enough distinct inlier nodes of W, enough shared path
   (walked metres covered by the inliers) and a margin over the best *different* hypothesis.
3. All walks accepted in a round are placed, then every placed walk is refined jointly
   (:func:`refine_walks`: rigid walks, robust point-to-point pair residuals, robust magnetometer heading
   priors) and the next round searches again with the improved map. Rounds stop when no walk is added.
4. Walks left over are grown into further components from new seeds (reported as not linked).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from rmbuild.config.optimize import InitConfig


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a, dtype=float)))


def _rot(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s], [s, c]])


def world_xy(raw: np.ndarray, T: np.ndarray, walk_of: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Positions (len(nodes), 2) of ``nodes`` under walk frames T (n_walks, 3)."""
    Tw = T[walk_of[nodes]]
    c, s = np.cos(Tw[:, 2]), np.sin(Tw[:, 2])
    x, y = raw[nodes, 0], raw[nodes, 1]
    return np.c_[Tw[:, 0] + c * x - s * y, Tw[:, 1] + s * x + c * y]


def covered_m(path: np.ndarray, bin_m: float = 3.0) -> float:
    """Walked length (m) covered by a set of nodes: distinct ``bin_m`` bins of their path position."""
    return float(len(np.unique(np.floor(np.asarray(path) / bin_m)))) * bin_m


def refine_walks(T: np.ndarray, active: np.ndarray, nk: np.ndarray, nq: np.ndarray, raw: np.ndarray,
                 walk_of: np.ndarray, ref: int, rot_prior: np.ndarray, rot_sig: np.ndarray, icfg: InitConfig,
                 iterations: int | None = None) -> np.ndarray:
    """Robust Gauss-Newton over rigid walk frames (x, y, theta) of the ``active`` walks.

    Residuals: for each pair (nk[p], nq[p]) the 2-D difference of the two nodes' world positions
    (sigma ``icfg.pair_sigma_m``, Cauchy weight with scale ``icfg.robust_c``); for each active walk with a
    finite ``rot_prior`` the wrapped difference theta - prior (sigma ``rot_sig``, same robust weight). The
    reference walk's position is fixed; its rotation too unless it has a rotation prior. Returns new T.
    """
    T = T.copy()
    act = np.flatnonzero(active)
    if len(act) < 2 and not np.isfinite(rot_prior[ref]):
        return T
    col = np.full(len(T), -1)
    col[act] = np.arange(len(act))
    nv = 3 * len(act)
    wa, wb = walk_of[nk], walk_of[nq]
    keep = active[wa] & active[wb] & (wa != wb)
    nk, nq, wa, wb = nk[keep], nq[keep], wa[keep], wb[keep]
    has_prior = active & np.isfinite(rot_prior)
    pw = np.flatnonzero(has_prior)
    s_pair = icfg.pair_sigma_m
    c = icfg.robust_c
    for _ in range(iterations or icfg.refine_iterations):
        pa = world_xy(raw, T, walk_of, nk)
        pb = world_xy(raw, T, walk_of, nq)
        r = (pa - pb) / s_pair
        wr = 1.0 / (1.0 + (np.hypot(r[:, 0], r[:, 1]) / c) ** 2)
        # d(R x + t)/d theta = perp(R x) with perp(v) = (-v_y, v_x); relative to the rotated part only
        ra = pa - T[wa, :2]
        rb = pb - T[wb, :2]
        m = len(nk)
        rows = np.r_[np.arange(m), np.arange(m), np.arange(m), np.arange(m) + m, np.arange(m) + m,
                     np.arange(m) + m, np.arange(m), np.arange(m), np.arange(m) + m, np.arange(m) + m]
        cols = np.r_[3 * col[wa], 3 * col[wb], 3 * col[wa] + 2, 3 * col[wa] + 1, 3 * col[wb] + 1,
                     3 * col[wa] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2]
        # x-residual rows: +t_ax, -t_bx, +(-ra_y) th_a, -(-rb_y) th_b ; y rows: +t_ay, -t_by, +ra_x th_a, -rb_x th_b
        vals = np.r_[np.ones(m), -np.ones(m), -ra[:, 1], np.ones(m), -np.ones(m), ra[:, 0], rb[:, 1],
                     np.zeros(m), -rb[:, 0], np.zeros(m)] / s_pair
        J = sp.coo_matrix((vals, (rows, cols)), shape=(2 * m, nv)).tocsr()
        res = np.r_[r[:, 0], r[:, 1]]
        w = np.r_[wr, wr]
        # rotation priors
        e = _wrap(T[pw, 2] - rot_prior[pw]) / rot_sig[pw]
        we = 1.0 / (1.0 + (np.abs(e) / c) ** 2)
        Jp = sp.coo_matrix((1.0 / rot_sig[pw], (np.arange(len(pw)), 3 * col[pw] + 2)), shape=(len(pw), nv))
        J = sp.vstack([J, Jp]).tocsr()
        res = np.r_[res, e]
        w = np.r_[w, we]
        A = (J.T @ sp.diags(w) @ J).tolil()
        g = J.T @ (w * res)
        # gauge: reference position (and rotation without a prior); tiny damping for unconnected walks
        big = 1e9
        k = 3 * col[ref]
        A[k, k] += big
        A[k + 1, k + 1] += big
        if not np.isfinite(rot_prior[ref]):
            A[k + 2, k + 2] += big
        A = A.tocsr() + sp.identity(nv) * 1e-6
        dx = spsolve(A.tocsc(), -g)
        if not np.all(np.isfinite(dx)):
            break
        T[act, 0] += dx[0::3]
        T[act, 1] += dx[1::3]
        T[act, 2] = _wrap(T[act, 2] + dx[2::3])
        if np.max(np.abs(dx)) < 1e-4:
            break
    return T


@dataclass
class WalkFit:
    t: np.ndarray  # (3,) world_T_walk
    score: int  # distinct inlier nodes of the walk
    second: int  # the same for the best hypothesis far from the chosen one
    shared_m: float
    partners: int  # placed walks among the inliers
    method: str  # "translation" or "se2"
    inliers: np.ndarray  # bool over the given pairs
    span_m: float = 0.0  # walked path between the first and the last inlier scan of the walk


def _se2_two_point_hypotheses(p_map: np.ndarray, p_walk: np.ndarray, gate: float, n: int,
                              rng: np.random.Generator):
    """SE(2) hypotheses walk -> map from ``n`` random point pairs (both spans > 2 gates).

    Returns (theta, t, px, py): per hypothesis the rotation, translation and every walk point mapped by it
    (px, py: hypotheses x points), or None when no sampled pair spans enough.
    """
    m = len(p_map)
    i1, i2 = rng.integers(0, m, n), rng.integers(0, m, n)
    va, vb = p_map[i2] - p_map[i1], p_walk[i2] - p_walk[i1]
    ok = (np.linalg.norm(va, axis=1) > 2 * gate) & (np.linalg.norm(vb, axis=1) > 2 * gate)
    if not ok.any():
        return None
    i1, i2, va, vb = i1[ok], i2[ok], va[ok], vb[ok]
    ths = np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0])
    c, s = np.cos(ths), np.sin(ths)
    mb, ma = (p_walk[i1] + p_walk[i2]) / 2, (p_map[i1] + p_map[i2]) / 2
    ts = ma - np.c_[c * mb[:, 0] - s * mb[:, 1], s * mb[:, 0] + c * mb[:, 1]]
    px = c[:, None] * p_walk[None, :, 0] - s[:, None] * p_walk[None, :, 1] + ts[:, 0:1]
    py = s[:, None] * p_walk[None, :, 0] + c[:, None] * p_walk[None, :, 1] + ts[:, 1:2]
    return ths, ts, px, py


def _refine_on_inliers(p_src: np.ndarray, p_dst: np.ndarray, th: float, t: np.ndarray, se2: bool, gate: float):
    """Refine a rigid fit p_dst ~ R(th) p_src + t on its inliers (< gate), three times: SE(2) (with >= 3
    inliers, when ``se2``) or translation only. Returns (th, t, final inlier mask)."""
    for _ in range(3):
        cur = np.linalg.norm(p_dst - (p_src @ _rot(th).T + t), axis=1) < gate
        if cur.sum() < 1:
            break
        if se2 and cur.sum() >= 3:
            from rmbuild.evaluate.trajectory import align_se2, rotation_angle_rad

            R, t = align_se2(p_src[cur], p_dst[cur])
            th = rotation_angle_rad(R)
        else:
            t = np.mean(p_dst[cur] - p_src[cur] @ _rot(th).T, axis=0)
    return th, t, np.linalg.norm(p_dst - (p_src @ _rot(th).T + t), axis=1) < gate


def _score(inl: np.ndarray, wnode_idx: np.ndarray, n_u: int) -> np.ndarray:
    """Distinct walk nodes among each row's inliers: inl (h, m) bool -> (h,) counts."""
    onehot = np.zeros((inl.shape[1], n_u), np.float32)
    onehot[np.arange(inl.shape[1]), wnode_idx] = 1.0
    return ((inl.astype(np.float32) @ onehot) > 0).sum(axis=1)


def fit_walk_to_map(pm: np.ndarray, pw: np.ndarray, wnode: np.ndarray, wpath: np.ndarray, mwalk: np.ndarray,
                    rot: float | None, icfg: InitConfig, rng: np.random.Generator) -> WalkFit | None:
    """Fit one walk to the placed map from pairs (map position pm (m, 2), walk own-frame position pw (m, 2)).

    ``wnode``: the walk node of each pair; ``wpath``: its walked distance (m); ``mwalk``: the map node's walk.
    ``rot``: the walk frame's rotation when known (translation-only), else None (SE(2) from 2-pair samples).
    """
    m = len(pm)
    if m == 0:
        return None
    gate = icfg.grow_gate_m
    _, widx = np.unique(wnode, return_inverse=True)
    n_u = int(widx.max()) + 1
    if rot is not None:
        R = _rot(rot)
        t_all = pm - pw @ R.T
        hyp = np.arange(m) if m <= icfg.ransac_iterations else rng.choice(m, icfg.ransac_iterations, False)
        inl = np.linalg.norm(t_all[hyp][:, None, :] - t_all[None, :, :], axis=2) < gate
        score = _score(inl, widx, n_u)
        h = int(np.argmax(score))
        t = t_all[hyp[h]]
        th = rot
        ths = np.full(len(hyp), rot)
        ts = t_all[hyp]
    else:
        if m < 2:
            return None
        hyp = _se2_two_point_hypotheses(pm, pw, gate, icfg.ransac_iterations, rng)
        if hyp is None:
            return None
        ths, ts, px, py = hyp
        inl = np.hypot(px - pm[None, :, 0], py - pm[None, :, 1]) < gate
        score = _score(inl, widx, n_u)
        h = int(np.argmax(score))
        t, th = ts[h], float(ths[h])
    th, t, inl_final = _refine_on_inliers(pw, pm, th, t, rot is None, gate)
    best = int(len(np.unique(widx[inl_final])))
    # the best hypothesis that places the walk elsewhere (its centroid > 2 gates away)
    cen = pw.mean(axis=0)
    c_best = _rot(th) @ cen + t
    c_h = np.c_[np.cos(ths) * cen[0] - np.sin(ths) * cen[1], np.sin(ths) * cen[0] + np.cos(ths) * cen[1]] + ts
    far = np.linalg.norm(c_h - c_best, axis=1) > 2 * gate
    second = int(score[far].max()) if far.any() else 0
    return WalkFit(np.array([t[0], t[1], float(_wrap(th))]), best, second,
                   covered_m(wpath[inl_final]) if inl_final.any() else 0.0,
                   int(len(np.unique(mwalk[inl_final]))), "translation" if rot is not None else "se2", inl_final,
                   float(np.ptp(wpath[inl_final])) if inl_final.any() else 0.0)


@dataclass
class GrowResult:
    world_T_walk: np.ndarray  # (n_walks, 3)
    component: np.ndarray  # (n_walks,) 0 = the reference walk's component
    reference: int
    round_placed: np.ndarray  # (n_walks,) round a walk was placed in (-1 never, 0 for seeds)
    n_inliers: np.ndarray  # (n_walks,) distinct inlier nodes at placement
    shared_m: np.ndarray  # (n_walks,) shared path at placement (m)
    method: np.ndarray  # (n_walks,) "seed" / "translation" / "se2" / ""
    heading_used: np.ndarray  # (n_walks,) bool: magnetometer rotation used (not overruled by an SE(2) fit)


def _min_path(icfg: InitConfig, se2: bool, untrusted: bool) -> float:
    if not se2:
        return icfg.grow_min_shared_m
    if untrusted and icfg.grow_se2_min_shared_m > 0:
        return icfg.grow_se2_min_shared_m
    return icfg.refit_rotation_min_path_m


def _spread_ok(f: WalkFit, icfg: InitConfig, se2: bool, walk_len: float | None) -> bool:
    """Translation-only fits: inliers spread over grow_min_span_frac of the walk (or window) length."""
    if se2 or icfg.grow_min_span_frac <= 0 or walk_len is None or walk_len > icfg.grow_span_max_walk_m:
        return True
    return f.span_m >= icfg.grow_min_span_frac * walk_len


def _accept(f: WalkFit | None, icfg: InitConfig, se2: bool, walk_len: float | None = None,
            untrusted: bool = False) -> bool:
    """``walk_len``: walked length (m) the spread rule refers to; ``untrusted``: the walk has no trusted
    magnetometer heading (an SE(2) fit then needs grow_se2_min_shared_m of shared path when set)."""
    if f is None:
        return False
    min_path = _min_path(icfg, se2, untrusted)
    min_inl = icfg.grow_min_inliers_se2 if se2 else icfg.grow_min_inliers
    return bool(f.score >= min_inl and f.shared_m >= min_path and f.score >= icfg.grow_margin * f.second
                and f.score >= f.second + icfg.grow_min_lead and _spread_ok(f, icfg, se2, walk_len))


def grow(raw: np.ndarray, path: np.ndarray, walk_of: np.ndarray, n_walks: int, nk: np.ndarray, nq: np.ndarray,
         rot_abs: np.ndarray, rot_known: np.ndarray, rot_sig: np.ndarray, icfg: InitConfig,
         reference: int, eligible: np.ndarray, trace: list | None = None,
         edges: list | None = None) -> GrowResult:
    """Place walks incrementally against the growing map (module docstring). ``nk``, ``nq``: cross-walk
    candidate node pairs; ``rot_abs``/``rot_known``/``rot_sig``: per-walk magnetometer frame rotation;
    ``eligible``: walks that may be placed (skipped walks are not); ``trace``: a list that receives one
    dict per walk-to-map fit (diagnostics); ``edges``: accepted walk-pair fits (a, b, A_T_B (3,)) of the
    walk-pair RANSAC: a walk that fails the walk-to-map fit but has such an edge to a placed walk is placed
    through it (long walk pairs that share a long stretch)."""
    rng = np.random.default_rng(icfg.seed)
    wk, wq = walk_of[nk], walk_of[nq]
    T = np.zeros((n_walks, 3))
    comp = np.full(n_walks, -1)
    rnd = np.full(n_walks, -1)
    n_inl = np.zeros(n_walks, np.int64)
    shared = np.zeros(n_walks)
    method = np.full(n_walks, "", dtype=object)
    heading_used = rot_known.copy()
    cand_count = np.bincount(np.r_[wk, wq], minlength=n_walks)
    wlen = _walk_lengths(path, walk_of, n_walks, icfg)
    seed = reference
    c_id = 0
    while seed is not None:
        world_rot = rot_abs[seed] if rot_known[seed] else np.nan
        prior = np.where(rot_known, _wrap(rot_abs - world_rot), np.nan) if rot_known[seed] else np.full(n_walks, np.nan)
        placed = comp == c_id
        placed[seed] = True
        comp[seed] = c_id
        rnd[seed] = 0
        method[seed] = "seed"
        T[seed] = (0.0, 0.0, 0.0)
        for r in range(1, icfg.grow_max_rounds + 1):
            free = eligible & (comp < 0)
            m = (placed[wk] & free[wq]) | (placed[wq] & free[wk])
            if not m.any():
                break
            rows = np.flatnonzero(m)
            mnode = np.where(placed[wk[rows]], nk[rows], nq[rows])
            wnode = np.where(placed[wk[rows]], nq[rows], nk[rows])
            pm = world_xy(raw, T, walk_of, mnode)
            wof = walk_of[wnode]
            order = np.argsort(wof, kind="stable")
            bounds = np.r_[0, np.flatnonzero(np.diff(wof[order])) + 1, len(order)]
            new = []
            for b0, b1 in zip(bounds[:-1], bounds[1:]):
                idx = order[b0:b1]
                w = int(wof[idx[0]])
                args = (pm[idx], raw[wnode[idx], :2], wnode[idx], path[wnode[idx]], walk_of[mnode[idx]])
                f = None
                if np.isfinite(prior[w]):
                    f = fit_walk_to_map(*args, float(prior[w]), icfg, rng)
                    ok = _accept(f, icfg, se2=False, walk_len=wlen[w])
                else:
                    ok = False
                if not ok:
                    f2 = fit_walk_to_map(*args, None, icfg, rng)
                    if _accept(f2, icfg, se2=True, untrusted=not (np.isfinite(prior[w]) and heading_used[w])):
                        f, ok = f2, True
                if ok:
                    new.append((w, f))
                if trace is not None:
                    trace.append({"component": c_id, "round": r, "walk": w, "accepted": bool(ok),
                                  "score": f.score if f else 0, "second": f.second if f else 0,
                                  "shared_m": f.shared_m if f else 0.0, "method": f.method if f else "",
                                  "pairs": len(idx), "T": None if f is None else f.t.tolist()})
            if edges and not new:  # fallback when walk-to-map growth stalls
                got = {w for w, _ in new}
                for a, b, Tab in edges:
                    for u, v, rel in ((a, b, Tab), (b, a, _inv(Tab))):
                        if placed[u] and free[v] and v not in got:
                            t = _compose(T[u], rel)
                            new.append((v, WalkFit(t, 0, 0, 0.0, 1, "pair", np.zeros(0, bool))))
                            got.add(v)
            if not new:
                break
            for w, f in new:
                T[w] = f.t
                comp[w] = c_id
                placed[w] = True
                rnd[w] = r
                n_inl[w] = f.score
                shared[w] = f.shared_m
                method[w] = f.method
                if f.method in ("se2", "pair") and np.isfinite(prior[w]):
                    heading_used[w] = abs(_wrap(f.t[2] - prior[w])) < icfg.heading_outlier_sigmas * rot_sig[w]
            T = _refine_placed(T, placed, nk, nq, raw, walk_of, seed, prior, heading_used, rot_sig, icfg, wlen)
            off = np.abs(_wrap(T[:, 2] - prior)) > icfg.heading_outlier_sigmas * rot_sig
            heading_used &= ~(placed & np.isfinite(prior) & off)
        c_id += 1
        # next seed: the unplaced eligible walk with the most candidates (only if it can grow a group)
        free = eligible & (comp < 0)
        seed = int(np.argmax(np.where(free, cand_count, -1))) if free.any() else None
        if seed is not None and cand_count[seed] == 0:
            seed = None
    # walks never placed: own component each, rotated by the magnetometer when known
    rest = np.flatnonzero(comp < 0)
    ref_rot = rot_abs[reference] if rot_known[reference] else np.nan
    for w in rest:
        comp[w] = c_id
        c_id += 1
        if np.isfinite(ref_rot) and rot_known[w]:
            T[w, 2] = _wrap(rot_abs[w] - ref_rot)
    # components ordered: 0 = reference's; the rest keep their discovery order
    return GrowResult(T, comp, reference, rnd, n_inl, shared, method, heading_used & (comp >= 0))


def walked_lengths(path: np.ndarray, walk_of: np.ndarray, n_walks: int) -> np.ndarray:
    """Walked length (m) of each walk from the cumulative walked distance ``path`` of its nodes (0: none)."""
    hi = np.full(n_walks, -np.inf)
    lo = np.full(n_walks, np.inf)
    np.maximum.at(hi, walk_of, path)
    np.minimum.at(lo, walk_of, path)
    return np.where(np.isfinite(hi), hi - lo, 0.0)


def _walk_lengths(path: np.ndarray, walk_of: np.ndarray, n_walks: int, icfg: InitConfig) -> np.ndarray:
    """Walked length (m) of each walk, capped at grow_window_m (the length a rigid fit covers) when set."""
    wl = walked_lengths(path, walk_of, n_walks)
    return np.minimum(wl, icfg.grow_window_m) if icfg.grow_window_m > 0 else wl


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    t = a[:2] + _rot(a[2]) @ b[:2]
    return np.array([t[0], t[1], float(_wrap(a[2] + b[2]))])


def _inv(a: np.ndarray) -> np.ndarray:
    t = -_rot(a[2]).T @ a[:2]
    return np.array([t[0], t[1], -a[2]])


def _refine_placed(T, placed, nk, nq, raw, walk_of, ref, prior, heading_used, rot_sig, icfg: InitConfig,
                   walk_len: np.ndarray):
    """Refine the placed walks on the candidate pairs currently within the gate (twice, re-gating).

    Walks shorter than ``icfg.short_walk_m`` (walked length) keep their magnetometer rotation: their prior
    sigma is scaled by ``icfg.short_walk_rot_sigma_scale``. Over a short walk's few metres of lever arm
    Wi-Fi pairs, metres apart and correlated along the walk, turn it further from the truth than the
    magnetometer is (ILC F1: rotation error mean 11.2 deg when pairs may turn them, 7.2 deg for the
    magnetometer alone).
    """
    wk, wq = walk_of[nk], walk_of[nq]
    both = placed[wk] & placed[wq]
    pr = np.where(heading_used, prior, np.nan)
    rot_sig = np.where(walk_len < icfg.short_walk_m, rot_sig * icfg.short_walk_rot_sigma_scale, rot_sig)
    for _ in range(2):
        d = np.linalg.norm(world_xy(raw, T, walk_of, nk[both]) - world_xy(raw, T, walk_of, nq[both]), axis=1)
        sel = np.flatnonzero(both)[d < icfg.grow_gate_m * icfg.refine_gate_factor]
        T = refine_walks(T, placed, nk[sel], nq[sel], raw, walk_of, ref, pr, rot_sig, icfg)
    return T


# ------------------------------------------------------------------------------------- kNN-evidence growth
def _fit_offsets(p_own: np.ndarray, x_hat: np.ndarray, path: np.ndarray, rot: float | None,
                 icfg: InitConfig, rng: np.random.Generator) -> WalkFit | None:
    """Rigid fit of a walk's scans (own-frame p_own (m, 2)) to their map-localised positions x_hat (m, 2):
    translation-only with a known rotation, else SE(2) from 2-point samples. Score = inlier scans."""
    m = len(p_own)
    gate = icfg.grow_gate_m
    if m == 0:
        return None
    if rot is not None:
        R = _rot(rot)
        o = x_hat - p_own @ R.T
        inl = np.linalg.norm(o[:, None] - o[None], axis=2) < gate
        cnt = inl.sum(axis=1)
        h = int(np.argmax(cnt))
        th, t = rot, o[h]
    else:
        if m < 2:
            return None
        hyp = _se2_two_point_hypotheses(x_hat, p_own, gate, icfg.ransac_iterations, rng)
        if hyp is None:
            return None
        ths, ts, px, py = hyp
        cnt = (np.hypot(px - x_hat[None, :, 0], py - x_hat[None, :, 1]) < gate).sum(axis=1)
        h = int(np.argmax(cnt))
        th, t = float(ths[h]), ts[h]
    th, t, inl = _refine_on_inliers(p_own, x_hat, th, t, rot is None, gate)
    return WalkFit(np.array([t[0], t[1], float(_wrap(th))]), int(inl.sum()), m - int(inl.sum()),
                   covered_m(path[inl]) if inl.any() else 0.0, 0, "translation" if rot is not None else "se2", inl,
                   float(np.ptp(path[inl])) if inl.any() else 0.0)


def _accept_knn(f: WalkFit | None, icfg: InitConfig, se2: bool, walk_len: float | None = None,
                untrusted: bool = False) -> bool:
    if f is None:
        return False
    n = f.score + f.second
    min_path = _min_path(icfg, se2, untrusted)
    min_inl = icfg.grow_min_inliers_se2 if se2 else icfg.grow_min_inliers
    return bool(f.score >= min_inl and f.shared_m >= min_path and f.score >= icfg.grow_min_inlier_frac * n
                and _spread_ok(f, icfg, se2, walk_len))


def grow_knn(raw: np.ndarray, path: np.ndarray, walk_of: np.ndarray, n_walks: int, rm, row_node: np.ndarray,
             thr: np.ndarray, rot_abs: np.ndarray, rot_known: np.ndarray, rot_sig: np.ndarray, icfg: InitConfig,
             min_common: int, reference: int, eligible: np.ndarray, cand_count: np.ndarray,
             trace: list | None = None, start: GrowResult | None = None) -> tuple[GrowResult, np.ndarray, np.ndarray]:
    """Place walks incrementally by localising their scans on the map built so far.

    Each unplaced scan keeps its ``grow_knn_k`` nearest placed scans in RSS distance (eq. 9; updated as
    walks are placed). A scan is *covered* when its nearest placed scan is closer than ``thr`` (its own
    walk's window median, seed 001's d_med) times ``grow_cover_factor``; its map position is the mean
    position of its covered neighbours. A walk is fitted rigidly to its covered scans' map positions
    (:func:`_fit_offsets`) and accepted with at least ``grow_min_inliers`` inlier scans, a fraction
    ``grow_min_inlier_frac`` of its covered scans and ``grow_min_shared_m`` of shared path. Returns
    (GrowResult, link pairs node_k, node_q): every inlier scan with each covered neighbour.

    ``start``: a previous result (e.g. of :func:`grow` on candidate pairs) whose component 0 is the
    starting map: its walks stay placed and the kNN rounds extend it.
    """
    rng = np.random.default_rng(icfg.seed)
    K = icfg.grow_knn_k
    n_rows = len(row_node)
    row_walk = walk_of[row_node]
    T = np.zeros((n_walks, 3))
    comp = np.full(n_walks, -1)
    rnd = np.full(n_walks, -1)
    n_inl = np.zeros(n_walks, np.int64)
    shared = np.zeros(n_walks)
    method = np.full(n_walks, "", dtype=object)
    heading_used = rot_known.copy()
    if start is not None:
        s0 = start.component == 0
        T[s0], rnd[s0], n_inl[s0] = start.world_T_walk[s0], start.round_placed[s0], start.n_inliers[s0]
        shared[s0], method[s0], heading_used[s0] = start.shared_m[s0], start.method[s0], start.heading_used[s0]
        reference = start.reference
    link_k: list[np.ndarray] = []
    link_q: list[np.ndarray] = []
    rows_of = [np.flatnonzero(row_walk == w) for w in range(n_walks)]
    wlen = _walk_lengths(path, walk_of, n_walks, icfg)
    thr_eff = np.where(np.isfinite(thr), thr, np.nanmedian(thr) if np.isfinite(thr).any() else np.inf)
    thr_eff = thr_eff * icfg.grow_cover_factor
    seed = reference
    c_id = 0
    bs = 2048
    while seed is not None:
        prior = (np.where(rot_known, _wrap(rot_abs - rot_abs[seed]), np.nan) if rot_known[seed]
                 else np.full(n_walks, np.nan))
        best_d = np.full((n_rows, K), np.inf, np.float32)
        best_c = np.full((n_rows, K), -1, np.int64)
        placed = np.zeros(n_walks, bool)
        if start is not None and c_id == 0:
            placed = start.component == 0
            comp[placed] = 0
            new_walks = list(np.flatnonzero(placed))
        else:
            new_walks = [seed]
            comp[seed], rnd[seed], method[seed], T[seed] = c_id, 0, "seed", (0.0, 0.0, 0.0)
            placed[seed] = True
        for r in range(1, icfg.grow_max_rounds + 1):
            # merge the newly placed walks' scans into every unplaced scan's K nearest
            free = eligible & (comp < 0)
            new_rows = np.concatenate([rows_of[w] for w in new_walks]) if new_walks else np.zeros(0, np.int64)
            u_rows = np.flatnonzero(free[row_walk])
            if len(new_rows) and len(u_rows):
                for b0 in range(0, len(u_rows), bs):
                    ur = u_rows[b0:b0 + bs]
                    d, common = rm.block(ur, new_rows)
                    d[common < min_common] = np.inf
                    dd = np.concatenate([best_d[ur], d], axis=1)
                    cc = np.concatenate([best_c[ur], np.broadcast_to(new_rows, d.shape)], axis=1)
                    kk = min(K, dd.shape[1])
                    idx = np.argpartition(dd, kk - 1, axis=1)[:, :kk]
                    best_d[ur, :kk] = np.take_along_axis(dd, idx, axis=1)
                    best_c[ur, :kk] = np.take_along_axis(cc, idx, axis=1)
            pos = np.full((n_rows, 2), np.nan)
            pr = np.flatnonzero(placed[row_walk])
            pos[pr] = world_xy(raw, T, walk_of, row_node[pr])
            new = []
            for w in np.flatnonzero(free):
                rw = rows_of[w]
                if not len(rw):
                    continue
                bd = best_d[rw]
                ok_nb = bd < thr_eff[rw][:, None]
                cov = ok_nb[:, 0] | ok_nb.any(axis=1)
                if cov.sum() < icfg.grow_min_inliers:
                    continue
                rwc = rw[cov]
                nbm = ok_nb[cov]
                P = pos[best_c[rwc]]  # (c, K, 2)
                x_hat = np.nansum(P * nbm[:, :, None], axis=1) / nbm.sum(axis=1)[:, None]
                nodes = row_node[rwc]
                f, ok = None, False
                pth = path[nodes]
                win = icfg.grow_window_m
                starts = np.arange(pth.min(), max(pth.max() - win, pth.min()) + win / 2, win / 2) if win > 0 else [0]
                for s0 in starts:
                    sel = (pth >= s0) & (pth <= s0 + win) if win > 0 else np.ones(len(pth), bool)
                    if sel.sum() < icfg.grow_min_inliers:
                        continue
                    args = (raw[nodes[sel], :2], x_hat[sel], pth[sel])
                    fw, okw = None, False
                    if np.isfinite(prior[w]):
                        fw = _fit_offsets(*args, float(prior[w]), icfg, rng)
                        okw = _accept_knn(fw, icfg, se2=False, walk_len=wlen[w])
                    if not okw:
                        f2 = _fit_offsets(*args, None, icfg, rng)
                        if _accept_knn(f2, icfg, se2=True,
                                       untrusted=not (np.isfinite(prior[w]) and heading_used[w])):
                            fw, okw = f2, True
                    if okw and (f is None or not ok or fw.score > f.score):
                        full = np.zeros(len(pth), bool)
                        full[np.flatnonzero(sel)[fw.inliers]] = True
                        fw.inliers = full
                        f, ok = fw, True
                    elif f is None:
                        f = fw
                if trace is not None:
                    trace.append({"component": c_id, "round": r, "walk": int(w), "accepted": bool(ok), "phase": "knn",
                                  "score": f.score if f else 0, "second": f.second if f else 0,
                                  "shared_m": f.shared_m if f else 0.0, "method": f.method if f else "",
                                  "pairs": int(cov.sum()), "T": None if f is None else f.t.tolist()})
                if ok and len(f.inliers) == len(rwc):
                    inl_rows = rwc[f.inliers]
                    kk_ = np.repeat(row_node[inl_rows], K)
                    qq_ = best_c[inl_rows].ravel()
                    good = nbm[f.inliers].ravel() & (qq_ >= 0)
                    new.append((w, f, kk_[good], row_node[qq_[good]]))
            if not new:
                break
            new_walks = []
            for w, f, a, b in new:
                T[w] = f.t
                comp[w], rnd[w], n_inl[w], shared[w], method[w] = c_id, r, f.score, f.shared_m, f.method
                placed[w] = True
                new_walks.append(w)
                if f.method == "se2" and np.isfinite(prior[w]):
                    heading_used[w] = False
                link_k.append(a)
                link_q.append(b)
            lk, lq = np.concatenate(link_k), np.concatenate(link_q)
            T = _refine_placed(T, placed, lk, lq, raw, walk_of, seed, prior, heading_used, rot_sig, icfg, wlen)
            off = np.abs(_wrap(T[:, 2] - prior)) > icfg.heading_outlier_sigmas * rot_sig
            heading_used &= ~(placed & np.isfinite(prior) & off)
        c_id += 1
        free = eligible & (comp < 0)
        seed = int(np.argmax(np.where(free, cand_count, -1))) if free.any() else None
        if seed is not None and cand_count[seed] <= 0:
            seed = None
    rest = np.flatnonzero(comp < 0)
    for w in rest:
        comp[w] = c_id
        c_id += 1
        if rot_known[reference] and rot_known[w]:
            T[w, 2] = _wrap(rot_abs[w] - rot_abs[reference])
    lk = np.concatenate(link_k) if link_k else np.zeros(0, np.int64)
    lq = np.concatenate(link_q) if link_q else np.zeros(0, np.int64)
    return GrowResult(T, comp, reference, rnd, n_inl, shared, method, heading_used), lk, lq


# ------------------------------------------------------------------------------------- component merging
def _component_compass_offset(T: np.ndarray, walks: np.ndarray, rot_abs: np.ndarray, ref: int) -> float:
    """Rotation (rad) that takes a component's frame to the reference's by the compass: the circular mean
    over ``walks`` (bool, trusted heading) of rot_abs[w] - rot_abs[ref] - T[w, 2]."""
    return float(np.angle(np.mean(np.exp(1j * (rot_abs[walks] - rot_abs[ref] - T[walks, 2])))))


def merge_components(g: GrowResult, raw: np.ndarray, path: np.ndarray, walk_of: np.ndarray, nk: np.ndarray,
                     nq: np.ndarray, rot_abs: np.ndarray, rot_known: np.ndarray, rot_sig: np.ndarray,
                     icfg: InitConfig, trace: list | None = None) -> GrowResult:
    """Fit whole secondary components (groups of walks placed against each other but not against the
    reference's map) rigidly to component 0, largest first, until none is accepted.

    A component of several short walks pools their candidate pairs to the map: each walk alone may lack the
    shared path a fit needs while the group has it. The fit is :func:`fit_walk_to_map` with the component's
    own frame as the "walk" frame (translation-only when the magnetometer gives the component's rotation,
    SE(2) otherwise) and the same acceptance rules; shared path is summed over the component's walks.
    Single-walk components are not retried (the walk-to-map growth already failed them).
    """
    rng = np.random.default_rng(icfg.seed + 1)
    T, comp = g.world_T_walk.copy(), g.component.copy()
    heading_used = g.heading_used.copy()
    method = g.method.copy()
    ref = g.reference
    wk, wq = walk_of[nk], walk_of[nq]
    n_walks = len(T)
    walk_len = np.zeros(n_walks)
    np.maximum.at(walk_len, walk_of, path)
    merged_any = False
    while True:
        placed = comp == 0
        sizes = np.bincount(comp, minlength=int(comp.max()) + 1)
        order = [c for c in np.argsort(-sizes, kind="stable") if c > 0 and sizes[c] >= 2]
        done = False
        for c in order:
            members = comp == c
            m = (placed[wk] & members[wq]) | (placed[wq] & members[wk])
            if m.sum() < icfg.grow_min_inliers:
                continue
            rows = np.flatnonzero(m)
            mnode = np.where(placed[wk[rows]], nk[rows], nq[rows])
            cnode = np.where(placed[wk[rows]], nq[rows], nk[rows])
            pm = world_xy(raw, T, walk_of, mnode)
            pc = world_xy(raw, T, walk_of, cnode)
            # walked distance made distinct per walk so covered_m sums the component's walks
            cpath = path[cnode] + walk_of[cnode] * (np.ceil(walk_len.max()) + 10.0)
            prior = np.nan
            hm = members & heading_used & rot_known
            if rot_known[ref] and hm.any():
                prior = _component_compass_offset(T, hm, rot_abs, ref)
            f, ok = None, False
            if np.isfinite(prior):
                f = fit_walk_to_map(pm, pc, cnode, cpath, walk_of[mnode], prior, icfg, rng)
                ok = _accept(f, icfg, se2=False)
            if not ok:
                f2 = fit_walk_to_map(pm, pc, cnode, cpath, walk_of[mnode], None, icfg, rng)
                if _accept(f2, icfg, se2=True, untrusted=not np.isfinite(prior)):
                    f, ok = f2, True
            if trace is not None:
                trace.append({"phase": "merge", "component": int(c), "walks": int(members.sum()),
                              "accepted": bool(ok), "score": f.score if f else 0, "second": f.second if f else 0,
                              "shared_m": f.shared_m if f else 0.0, "method": f.method if f else "",
                              "pairs": len(rows), "T": None if f is None else f.t.tolist()})
            if not ok:
                continue
            for w in np.flatnonzero(members):
                T[w] = _compose(f.t, T[w])
            comp[members] = 0
            method[members] = "merge"
            if f.method == "se2":
                heading_used[members] = False
            done = merged_any = True
            break  # the map grew: recompute sizes and pairs
        if not done:
            break
    if not merged_any:
        return g
    placed = comp == 0
    prior_all = np.where(rot_known, _wrap(rot_abs - rot_abs[ref]), np.nan) if rot_known[ref] else np.full(n_walks,
                                                                                                        np.nan)
    T = _refine_placed(T, placed, nk, nq, raw, walk_of, ref, prior_all, heading_used, rot_sig, icfg,
                       _walk_lengths(path, walk_of, n_walks, icfg))
    # renumber the remaining components 1, 2, ... in their old order
    _, comp = np.unique(comp, return_inverse=True)
    return GrowResult(T, comp, ref, g.round_placed, g.n_inliers, g.shared_m, method, heading_used)


def orient_components(g: GrowResult, rot_abs: np.ndarray, rot_known: np.ndarray) -> GrowResult:
    """Rotate each component other than the reference's (about the origin, rigidly) so that its walks'
    magnetometer rotations agree with the reference's on average (circular mean over its walks whose
    heading is trusted). A further component is seeded in its seed walk's own PDR frame, whose start
    heading is arbitrary; without this, its walks would start the joint solve up to 180 deg from their
    heading priors. Components without a trusted heading, or a reference without one, are left as they are.
    """
    ref = g.reference
    if not rot_known[ref]:
        return g
    T = g.world_T_walk.copy()
    for c in np.unique(g.component):
        members = g.component == c
        hm = members & g.heading_used & rot_known
        if c == g.component[ref] or not hm.any():
            continue
        off = _component_compass_offset(T, hm, rot_abs, ref)
        for w in np.flatnonzero(members):
            T[w] = _compose(np.array([0.0, 0.0, off]), T[w])
    return GrowResult(T, g.component, ref, g.round_placed, g.n_inliers, g.shared_m, g.method, g.heading_used)
