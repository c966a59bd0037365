"""Walk-level refinement: the placed walks as rigid bodies, moved jointly to agree with their links.

A robust Gauss-Newton over the frames (x, y, theta) of the placed walks: each link (k, q) between two
placed walks contributes the 2-D difference of its nodes' world positions (sigma PAIR_SIGMA_M), each walk
with a trusted compass a rotation prior; both with a Cauchy weight (scale ROBUST_C sigmas) on the
*norm* of the 2-D difference. Solved by iteratively reweighted Gauss-Newton (one sparse solve per
iteration: a sparse LU, or conjugate gradients for a venue-month's thousands of frames). Written out
because neither library fits: scipy's ``least_squares`` applies its robust loss per scalar residual (x and y
apart, an anisotropic kernel), and gtsam has no built-in factor for a node pair seen through two walk
frames.
"""

from __future__ import annotations

import numpy as np

from rmbuild import geometry
from rmbuild.slam.problem import WalkSet

# m; 1-sigma of a link's position difference (Wi-Fi's resolution)
PAIR_SIGMA_M = 3.0
# Cauchy scale (sigmas) of links and rotation priors
ROBUST_C = 2.0
# Gauss-Newton iterations per refinement
ITERATIONS = 8
# links within GATE_FACTOR x the placement gate of each other are used
GATE_FACTOR = 1.5
# m of walked length; a shorter walk keeps its compass rotation (its prior's sigma times
# SHORT_WALK_ROT_SIGMA_SCALE): over a few metres of lever arm, links metres apart turn it further from the
# truth than the compass (docs/notes/optimize.md: ILC F1 rotation error 11.2 -> 7.9 deg)
SHORT_WALK_M = 40.0
SHORT_WALK_ROT_SIGMA_SCALE = 0.1
# unknowns (3 per placed walk); from this many on each Gauss-Newton step is solved by conjugate gradients
# preconditioned by each walk's own 3 x 3 block (the links hold hundreds of walks to each other: a direct
# factorisation fills in; a venue-month's 2,900 unknowns took 0.30 s dense, 0.50 s by a sparse LU and
# 3-30 ms by CG in 25-60 iterations, agreeing with the dense solution to 1e-10 m; docs/notes/scale.md)
ITERATIVE_SOLVE_MIN_VARS = 600
# CG stops when the residual is this small relative to the right-hand side (else, after CG_MAX_ITERATIONS,
# the sparse LU solves the step)
CG_RELATIVE_TOL = 1e-12
CG_MAX_ITERATIONS = 1000


def refine_walks(T: np.ndarray, active: np.ndarray, nk: np.ndarray, nq: np.ndarray, walks: WalkSet, ref: int,
                 rot_prior: np.ndarray, rot_sig: np.ndarray, iterations: int = ITERATIONS,
                 fixed: np.ndarray | None = None) -> np.ndarray:
    """Robust Gauss-Newton over rigid walk frames T (n_walks, 3) of the ``active`` walks (module docstring).

    ``rot_prior`` (n_walks,) rad, NaN where none; the reference walk's position is fixed, its rotation too
    unless it has a rotation prior; ``fixed`` (n_walks,) walks whose frames do not move at all (an
    incremental run's held map). Returns new T.
    """
    import scipy.sparse as sp  # imported here: ~0.3 s at import, which `optimize --incremental` (no refinement) skips

    T = T.copy()
    held = fixed & active if fixed is not None else np.zeros(len(T), bool)
    var = active & ~held  # the unknowns; held walks' links count, their frames are constants
    act = np.flatnonzero(var)
    if not len(act) or (len(act) < 2 and not np.isfinite(rot_prior[ref]) and not held.any()):
        return T
    col = np.full(len(T), -1)
    col[act] = np.arange(len(act))
    nv = 3 * len(act)
    walk_of = walks.walk_of
    wa, wb = walk_of[nk], walk_of[nq]
    keep = active[wa] & active[wb] & (wa != wb) & (var[wa] | var[wb])
    nk, nq, wa, wb = nk[keep], nq[keep], wa[keep], wb[keep]
    pw = np.flatnonzero(var & np.isfinite(rot_prior))
    for _ in range(iterations):
        J, res, w = linearise(T, nk, nq, wa, wb, col, nv, walks)
        e = geometry.wrap(T[pw, 2] - rot_prior[pw]) / rot_sig[pw]
        Jp = sp.coo_matrix((1.0 / rot_sig[pw], (np.arange(len(pw)), 3 * col[pw] + 2)), shape=(len(pw), nv))
        J = sp.vstack([J, Jp]).tocsr()
        res = np.r_[res, e]
        w = np.r_[w, 1.0 / (1.0 + (np.abs(e) / ROBUST_C) ** 2)]
        A = (J.T @ sp.diags(w) @ J).tocsr()
        g = J.T @ (w * res)
        # gauge: reference position (and rotation without a prior), unless held walks fix the frame; tiny
        # damping for unconnected walks
        gauge = np.zeros(nv)
        if col[ref] >= 0 and not held.any():
            k = 3 * col[ref]
            gauge[k:k + (2 if np.isfinite(rot_prior[ref]) else 3)] = 1e9
        dx = _solve((A + sp.diags(gauge) + sp.identity(nv) * 1e-6).tocsc(), -g)
        if not np.all(np.isfinite(dx)):
            break
        T[act, 0] += dx[0::3]
        T[act, 1] += dx[1::3]
        T[act, 2] = geometry.wrap(T[act, 2] + dx[2::3])
        if np.max(np.abs(dx)) < 1e-4:
            break
    return T


def _solve(A, b: np.ndarray) -> np.ndarray:
    """A x = b for the symmetric positive definite normal matrix A (sparse, csc): sparse LU below
    ITERATIVE_SOLVE_MIN_VARS unknowns, block-Jacobi conjugate gradients from there on (the same solution to
    ~1e-10; the sparse LU when CG does not converge)."""
    from scipy.sparse.linalg import spsolve

    if A.shape[0] < ITERATIVE_SOLVE_MIN_VARS:
        return spsolve(A, b)
    x = block_jacobi_cg(A.tocsr(), b, CG_RELATIVE_TOL, CG_MAX_ITERATIONS)
    return x if x is not None else spsolve(A, b)


def block_jacobi_cg(A, b: np.ndarray, rel_tol: float, max_iterations: int) -> np.ndarray | None:
    """Conjugate gradients on A x = b (A sparse, symmetric positive definite, unknowns in consecutive
    triples: one walk's frame) preconditioned by the inverse of A's 3 x 3 diagonal blocks; None when the
    residual is not below ``rel_tol`` x |b| after ``max_iterations``."""
    coo = A.tocoo()
    on = coo.row // 3 == coo.col // 3
    blocks = np.zeros((A.shape[0] // 3, 3, 3))
    blocks[coo.row[on] // 3, coo.row[on] % 3, coo.col[on] % 3] = coo.data[on]
    inv = np.linalg.inv(blocks)

    def precondition(r: np.ndarray) -> np.ndarray:
        return np.einsum("kij,kj->ki", inv, r.reshape(-1, 3)).ravel()

    x = np.zeros_like(b)
    r = b.astype(float, copy=True)
    stop = rel_tol * np.linalg.norm(b)
    if np.linalg.norm(r) <= stop:
        return x
    z = precondition(r)
    p, rz = z.copy(), r @ z
    for _ in range(max_iterations):
        ap = A @ p
        alpha = rz / (p @ ap)
        x += alpha * p
        r -= alpha * ap
        if np.linalg.norm(r) <= stop:
            return x
        z = precondition(r)
        rz, rz_old = r @ z, rz
        p = z + (rz / rz_old) * p
    return None


def linearise(T, nk, nq, wa, wb, col, nv, walks: WalkSet):
    """(J, whitened residuals, Cauchy weights) of the links' position differences."""
    import scipy.sparse as sp

    pa = walks.world_xy(T, nk)
    pb = walks.world_xy(T, nq)
    r = (pa - pb) / PAIR_SIGMA_M
    wr = 1.0 / (1.0 + (np.hypot(r[:, 0], r[:, 1]) / ROBUST_C) ** 2)
    # d(R x + t)/d theta = perp(R x) with perp(v) = (-v_y, v_x); relative to the rotated part only
    ra = pa - T[wa, :2]
    rb = pb - T[wb, :2]
    m = len(nk)
    i, j = np.arange(m), np.arange(m) + m
    rows = np.r_[i, i, i, j, j, j, i, i, j, j]
    cols = np.r_[3 * col[wa], 3 * col[wb], 3 * col[wa] + 2, 3 * col[wa] + 1, 3 * col[wb] + 1,
                 3 * col[wa] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2, 3 * col[wb] + 2]
    # x rows: +t_ax, -t_bx, +(-ra_y) th_a, -(-rb_y) th_b ; y rows: +t_ay, -t_by, +ra_x th_a, -rb_x th_b
    vals = np.r_[np.ones(m), -np.ones(m), -ra[:, 1], np.ones(m), -np.ones(m), ra[:, 0], rb[:, 1],
                 np.zeros(m), -rb[:, 0], np.zeros(m)] / PAIR_SIGMA_M
    va, vb = col[wa] >= 0, col[wb] >= 0  # a held walk's frame is a constant: no column
    on = np.r_[va, vb, va, va, vb, va, vb, vb, vb, vb]
    J = sp.coo_matrix((vals[on], (rows[on], cols[on])), shape=(2 * m, nv)).tocsr()
    return J, np.r_[r[:, 0], r[:, 1]], np.r_[wr, wr]


def refine_placed(T: np.ndarray, placed: np.ndarray, nk: np.ndarray, nq: np.ndarray, walks: WalkSet, ref: int,
                  prior: np.ndarray, heading_used: np.ndarray, rot_sig: np.ndarray, gate_m: float,
                  walk_len: np.ndarray, fixed: np.ndarray | None = None) -> np.ndarray:
    """Refine the placed walks on the links currently within GATE_FACTOR x ``gate_m`` (twice, re-gating).

    Walks shorter than SHORT_WALK_M keep their compass rotation (a tighter prior); ``prior`` is used only
    where ``heading_used``.
    """
    wk, wq = walks.walk_of[nk], walks.walk_of[nq]
    both = placed[wk] & placed[wq]
    pr = np.where(heading_used, prior, np.nan)
    rot_sig = np.where(walk_len < SHORT_WALK_M, rot_sig * SHORT_WALK_ROT_SIGMA_SCALE, rot_sig)
    for _ in range(2):
        d = np.linalg.norm(walks.world_xy(T, nk[both]) - walks.world_xy(T, nq[both]), axis=1)
        sel = np.flatnonzero(both)[d < gate_m * GATE_FACTOR]
        T = refine_walks(T, placed, nk[sel], nq[sel], walks, ref, pr, rot_sig, fixed=fixed)
    return T
