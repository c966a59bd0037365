"""Levenberg-Marquardt for venue-month pose graphs, each step solved by conjugate gradients.

A venue walked a thousand times over makes every separator of a direct elimination cut hundreds of walks:
the dense cliques cost tens of seconds per step (docs/notes/performance.md). Here each damped step
``(JᵀJ + λI) δ = Jᵀb`` (gtsam's whitened, robustly weighted linearisation) is solved by preconditioned
conjugate gradients. The preconditioner is two-level, the walks being its subdomains:

- fine: each walk's chain (its odometry between successive keyframes, its priors, its pairs' diagonal
  terms), a banded matrix factorised exactly (LAPACK's banded Cholesky: no fill);
- coarse: the rigid motion of each walk (3 unknowns per walk), solved by a sparse LU — what a walk's own
  block leaves free and only the pairs between walks fix.

They are combined as deflation (A-DEF2: the walks' solve, then the coarse correction of its residual; CG
starts from the coarse solution), so that a walk whose chain alone is nearly singular in its rigid motion (no
prior) does no harm.
"""

from __future__ import annotations

import gtsam
import numpy as np
import scipy.linalg
import scipy.sparse as sp

from rmbuild.blas import one_blas_thread

# conjugate-gradient iterations per LM step at most, and the residual reduction that ends them
CG_MAX_ITERATIONS = 200
CG_RELATIVE_TOL = 1e-6
BAND = 5  # a keyframe's 3 unknowns and its successor's: the upper bandwidth of a walk's chain


class _System:
    """One damped normal system and its two-level preconditioner (module docstring)."""

    def __init__(self, H: sp.csr_matrix, walk_col: np.ndarray, Z: sp.csr_matrix):
        self.H = H
        self.band = _walk_band(H, walk_col)
        self.Z = Z
        self.E = _coarse_factor((Z.T @ (H @ Z)).tocsc())

    def coarse(self, r: np.ndarray) -> np.ndarray:
        return self.Z @ self.E(self.Z.T @ r)

    def precondition(self, r: np.ndarray) -> np.ndarray:
        """The walks' band solve, then the coarse correction of what it leaves (deflation's A-DEF2: one coarse
        solve per iteration; with CG started from the coarse solution)."""
        t = scipy.linalg.cho_solve_banded((self.band, False), r)
        return t + self.coarse(r - self.H @ t)

    def solve(self, g: np.ndarray) -> tuple[np.ndarray, int]:
        """CG from the coarse solution; returns (δ, iterations)."""
        x = self.coarse(g)
        r = g - self.H @ x
        z = self.precondition(r)
        p = z.copy()
        rz = r @ z
        stop = CG_RELATIVE_TOL * np.linalg.norm(g)
        for it in range(1, CG_MAX_ITERATIONS + 1):
            hp = self.H @ p
            alpha = rz / (p @ hp)
            x += alpha * p
            r -= alpha * hp
            if np.linalg.norm(r) <= stop:
                return x, it
            z = self.precondition(r)
            rz, rz_old = r @ z, rz
            p = z + (rz / rz_old) * p
        return x, CG_MAX_ITERATIONS


def _coarse_factor(E: sp.csc_matrix):
    """A solver of the coarse system E (3 unknowns per walk, sparse: a walk meets tens of others): a sparse LU
    with a symmetric minimum-degree ordering and no pivoting (E is positive definite). A venue-month's 2,856
    unknowns: 0.20 s and 1.7 ms a solve, where the dense Cholesky took 0.21 s and 11 ms; a venue-year's
    12,000: the dense one took 10.5 s and 0.3 s (docs/notes/scale.md). The dense Cholesky when the LU fails."""
    from scipy.sparse.linalg import splu

    try:
        lu = splu(E, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return lu.solve
    except RuntimeError:  # exactly singular to SuperLU
        c = scipy.linalg.cho_factor(E.toarray())
        return lambda r: scipy.linalg.cho_solve(c, r)


def _walk_band(H: sp.csr_matrix, walk_col: np.ndarray) -> np.ndarray:
    """The upper band (LAPACK's banded Cholesky factor) of each walk's chain: H's entries between a keyframe and
    itself or its successor in the same walk. Dropping the others (cross-walk terms, a within-walk pair's
    coupling of keyframes further apart) drops whole off-diagonal blocks of factors, so what is left stays
    positive definite; CG makes up for them."""
    coo = sp.triu(H, format="coo")
    keep = (walk_col[coo.row] == walk_col[coo.col]) & (coo.col // 3 - coo.row // 3 <= 1)
    ab = np.zeros((BAND + 1, H.shape[0]))
    ab[BAND + coo.row[keep] - coo.col[keep], coo.col[keep]] = coo.data[keep]
    return scipy.linalg.cholesky_banded(ab, lower=False)


def rigid_basis(xyt: np.ndarray, walk: np.ndarray, n_walks: int) -> sp.csr_matrix:
    """(3n, 3·n_walks): each walk's rigid motion (a small translation and a rotation about its centroid) in
    its poses' tangent spaces (gtsam's Pose2 retraction acts on the right: δ = Ad(p⁻¹)·t)."""
    n = len(xyt)
    cx = np.bincount(walk, xyt[:, 0], n_walks) / np.maximum(np.bincount(walk, minlength=n_walks), 1)
    cy = np.bincount(walk, xyt[:, 1], n_walks) / np.maximum(np.bincount(walk, minlength=n_walks), 1)
    x, y, th = xyt[:, 0] - cx[walk], xyt[:, 1] - cy[walk], xyt[:, 2]
    c, s = np.cos(th), np.sin(th)
    # Ad(p⁻¹) = [[c, s, s·x − c·y], [−s, c, c·x + s·y], [0, 0, 1]] for p = (x, y, θ)
    blocks = np.zeros((n, 3, 3))
    blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 0, 2] = c, s, s * x - c * y
    blocks[:, 1, 0], blocks[:, 1, 1], blocks[:, 1, 2] = -s, c, c * x + s * y
    blocks[:, 2, 2] = 1.0
    rows = np.broadcast_to(3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None], (n, 3, 3))
    cols = np.broadcast_to(3 * walk[:, None, None] + np.arange(3)[None, None, :], (n, 3, 3))
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n_walks))


def normal_system(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n: int):
    """(JᵀJ as csr (3n, 3n), Jᵀb (3n,)) of the graph linearised at ``values`` (columns in key order)."""
    ijs = graph.linearize(values).sparseJacobian_()
    i, j, v = ijs[0].astype(np.int64) - 1, ijs[1].astype(np.int64) - 1, ijs[2]
    rhs = j == 3 * n
    m = int(i.max()) + 1
    b = np.zeros(m)
    b[i[rhs]] = v[rhs]
    J = sp.csr_matrix((v[~rhs], (i[~rhs], j[~rhs])), shape=(m, 3 * n))
    return (J.T @ J).tocsr(), J.T @ b


# Levenberg-Marquardt's damping: Nielsen's update as gtsam's (a rejected step multiplies lambda by a factor
# that doubles each time; an accepted one scales it by max(1/3, 1 - (2ρ - 1)³)), its bounds, and the least
# ratio of actual to predicted decrease that accepts a step
LAMBDA_UPPER = 1e5
LAMBDA_LOWER = 0.0
MIN_MODEL_FIDELITY = 1e-3


def _retract(values: gtsam.Values, keys: list[int], delta: np.ndarray) -> gtsam.Values:
    vv = gtsam.VectorValues()
    for k, d in zip(keys, delta.reshape(-1, 3)):
        vv.insert(k, d)
    return values.retract(vv)


def levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, walk: np.ndarray, n_walks: int,
                        max_iterations: int, lambda_initial: float, lambda_factor: float, relative_tol: float,
                        absolute_tol: float, hook) -> tuple[gtsam.Values, int]:
    """LM over Pose2 ``values`` (keys in ascending order, ``walk`` (n,) the walk of each) with each damped
    step solved by :class:`_System`'s CG; ``hook(iteration, cost_before, cost_after)`` after each accepted
    step. Stops as gtsam's LM: the iteration cap, a relative or absolute decrease below the tolerances, or
    lambda past LAMBDA_UPPER. Returns (values, iterations). BLAS runs on one thread (its products here are
    vectors against a matrix: two threads made the 150k case's CG 6x slower with the other core busy)."""
    with one_blas_thread():
        return _levenberg_marquardt(graph, values, walk, n_walks, max_iterations, lambda_initial, lambda_factor,
                                    relative_tol, absolute_tol, hook)


def _levenberg_marquardt(graph, values, walk, n_walks, max_iterations, lambda_initial, lambda_factor,
                         relative_tol, absolute_tol, hook) -> tuple[gtsam.Values, int]:
    keys = [int(k) for k in values.keys()]
    n = len(keys)
    walk3 = np.repeat(walk, 3)
    err = graph.error(values)
    lam, factor = lambda_initial, lambda_factor
    it = 0
    while it < max_iterations:
        H0, g = normal_system(graph, values, n)
        Z = rigid_basis(gtsam.utilities.extractPose2(values), walk, n_walks)
        accepted = False
        while lam < LAMBDA_UPPER:
            delta = _System((H0 + lam * sp.identity(3 * n, format="csr")).tocsr(), walk3, Z).solve(g)[0]
            predicted = delta @ g - 0.5 * delta @ (H0 @ delta)
            trial = _retract(values, keys, delta)
            new_err = graph.error(trial)
            if predicted > 0 and (err - new_err) / predicted > MIN_MODEL_FIDELITY:
                lam = max(LAMBDA_LOWER, lam * max(1 / 3, 1 - (2 * (err - new_err) / predicted - 1) ** 3))
                factor, accepted = 2.0, True
                break
            lam *= factor
            factor *= 2.0
        if not accepted:
            break
        it += 1
        hook(it, err, new_err)
        values, done = trial, err - new_err < relative_tol * err or new_err < absolute_tol
        err = new_err
        if done:
            break
    return values, it
