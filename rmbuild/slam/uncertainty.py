"""A predicted placement error per walk, in metres, from the evidence that holds the walk where it is.

The placed walks are treated as rigid bodies (x, y, theta each) held by the cross-walk pairs of the final
solve (position differences, sigma PAIR_SIGMA_M, robust weights at the final residuals as in the
walk-level refinement), the position ties between walks (their own sigma) and the compass (a rotation
prior of COMPASS_SIGMA_RAD per walk with one). The covariance of each walk's frame is its 3 x 3 block of the
pseudo-inverse of that information matrix — the gauge left free, so the figure is an error *relative to the
map as a whole*, as a map aligned to the building by one rigid fit has it. Only those blocks are computed
(:func:`marginal_blocks`): from the inverse of the information with each connected group's translation
added (the pseudo-inverse's blocks to rounding) up to EXACT_MAX_WALKS placed walks; from each walk's own
block (its frame given the others') beyond, where the exact blocks cost the cube of the walks (a venue-year's
4,000). A walk's figure combines its position sigma with its rotation sigma times its own radius.

The covariance knows how much evidence holds a walk, not whether the evidence is right: a walk placed by
a position tie (its previous recording's end) that its own scans contradict got one of the smallest
figures. So the figure grows with the RF check's disagreement: times exp(RF_INFLATION * (RF_LOG_LR_TRUSTED
- mean log likelihood ratio)) for a walk whose scans support its place less than RF_LOG_LR_TRUSTED (walks
the check did not judge: unchanged). And a walk whose component a continuity tie placed (a device's next
recording attached where the last one ended: the radio could not join them) keeps that join's
uncertainty whatever pairs the solve found afterwards: its figure is combined (root sum of squares) with
the data set's median tie sigma (each tie's: 2 m + 0.4 m/s times its gap). On MS ILC site1/F1 such
walks were a median 8.0 m off against 3.9 m for those placed by their own radio, with predicted figures of
5.6 and 5.0 m; with the tie's sigma the rank correlation went 0.34 -> 0.48 there, and was unchanged on
F2, B1, F6 and IPIN (docs/notes/optimize.md). Pairs of consecutive scans are not independent, so the covariance
alone is too small; CALIBRATION scales the product to the walks' median real error (docs/notes/optimize.md: on
five real floors the median ratio real / predicted was 0.8-3.4 before it, median 2.0; the rank correlation
with the real per-walk error, each floor with the inflation's two numbers chosen on the other four, went
from 0.27 / 0.13 / 0.49 / 0.37 / 0.61 to 0.23 / 0.42 / 0.56 / 0.54 / 0.63 on MS ILC site1/F1, site1/F2,
site2/B1, site2/F6 and IPIN 2023 -2). Walks that are not placed get NaN.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from rmbuild import geometry
from rmbuild.slam.evidence.base import Ties
from rmbuild.slam.placement.refine import PAIR_SIGMA_M, linearise
from rmbuild.slam.problem import WalkSet

COMPASS_SIGMA_RAD = 0.1
# the covariance's figure times this: the median real / predicted error on the real floors (module docstring)
CALIBRATION = 2.0
# mean log likelihood ratio (near vs far) of a walk's scans from which its placement counts as supported
RF_LOG_LR_TRUSTED = 2.0
# growth of the predicted error per unit of mean log likelihood ratio below RF_LOG_LR_TRUSTED
RF_INFLATION = 0.2
# placed walks; up to this many the blocks are the pseudo-inverse's (a dense factorisation: 1,000 walks
# ~1 s); beyond, each walk's own block. On a venue-month's 150k poses (274 walks) the walks' figures from their
# own blocks were 0.96x the pseudo-inverse's (median; rank correlation 0.996; docs/notes/scale.md)
EXACT_MAX_WALKS = 1500


def walk_frames(walks: WalkSet, poses: np.ndarray) -> np.ndarray:
    """(n_walks, 3) each walk's frame at ``poses``: its own dead reckoning fitted rigidly onto them."""
    T = np.zeros((walks.n_walks, 3))
    for w in range(walks.n_walks):
        s, e = walks.starts[w], walks.ends[w]
        if e - s >= 2:
            T[w] = geometry.fit_rigid(walks.raw[s:e, :2], poses[s:e, :2])
    return T


def predicted_errors(walks: WalkSet, poses: np.ndarray, placed: np.ndarray, pk: np.ndarray, pq: np.ndarray,
                     ties: Ties, compass: np.ndarray, rf_log_lr: np.ndarray | None = None,
                     tied: np.ndarray | None = None) -> np.ndarray:
    """(n_walks,) predicted placement error (m) of each ``placed`` walk (module docstring). ``pk``, ``pq``:
    the cross-walk pairs of the final solve; ``compass``: walks with a trusted compass; ``rf_log_lr``: the
    RF check's mean log likelihood ratio per walk (NaN or None: not judged); ``tied``: walks whose component
    a continuity tie placed."""
    out = np.full(walks.n_walks, np.nan)
    act = np.flatnonzero(placed)
    if len(act) < 2:
        return out
    T = walk_frames(walks, poses)
    col = np.full(walks.n_walks, -1)
    col[act] = np.arange(len(act))
    H = _pairs_information(T, pk, pq, np.full(len(pk), PAIR_SIGMA_M), placed, col, walks)
    H = H + _pairs_information(T, ties.node_a, ties.node_b, ties.sigma_m, placed, col, walks)
    rot = act[compass[act]]
    H = H + sp.coo_matrix((np.full(len(rot), 1.0 / COMPASS_SIGMA_RAD**2), (3 * col[rot] + 2, 3 * col[rot] + 2)),
                          shape=H.shape)
    C = marginal_blocks(H.tocsr())
    radius = np.array([geometry.extent_m(walks.raw[walks.starts[w]:walks.ends[w], :2]) for w in act])
    var = C[:, 0, 0] + C[:, 1, 1] + C[:, 2, 2] * radius**2
    out[act] = CALIBRATION * np.sqrt(np.maximum(var, 0.0)) * rf_inflation(rf_log_lr, walks.n_walks)[act]
    if tied is not None and len(ties.sigma_m):
        on_tie = np.asarray(tied, bool) & np.isfinite(out)
        out[on_tie] = np.hypot(out[on_tie], float(np.median(ties.sigma_m)))
    return out


def rf_inflation(rf_log_lr: np.ndarray | None, n_walks: int) -> np.ndarray:
    """(n_walks,) factor >= 1 on each walk's predicted error from its RF check (module docstring)."""
    if rf_log_lr is None:
        return np.ones(n_walks)
    short = np.nan_to_num(RF_LOG_LR_TRUSTED - np.asarray(rf_log_lr, float), nan=0.0)
    return np.exp(RF_INFLATION * np.maximum(short, 0.0))


def marginal_blocks(H: sp.csr_matrix) -> np.ndarray:
    """(n, 3, 3) the diagonal 3 x 3 blocks of the covariance of the information H (3n, 3n; one walk's frame
    per consecutive triple): the pseudo-inverse's blocks up to EXACT_MAX_WALKS walks, each walk's own block
    inverted beyond (NaN where that block is singular)."""
    if H.shape[0] // 3 > EXACT_MAX_WALKS:
        return _own_blocks_inverted(H)
    return pinv_blocks(H.toarray())


def pinv_blocks(H: np.ndarray) -> np.ndarray:
    """The diagonal 3 x 3 blocks of ``pinv(H, rcond=1e-9, hermitian=True)`` (H dense, symmetric positive
    semi-definite, translation invariant: a walk's x and y enter only through differences). Its null space
    is each connected group's x and y translation and the rotation of a walk without evidence (N,
    orthonormal) when the rest is positive definite; then pinv(H) = (H + N Nᵀ)⁻¹ − N Nᵀ, from one Cholesky
    factorisation. Otherwise (a group hanging on one point) the pseudo-inverse itself."""
    import scipy.linalg as sl
    from scipy.linalg.lapack import dpotri

    from rmbuild.blas import one_blas_thread

    N = _null_basis(H)
    i = np.arange(0, len(H), 3)
    with one_blas_thread():  # one factorisation: a second BLAS thread only waits on a busy machine's other core
        try:
            c, _ = sl.cho_factor(H + N @ N.T, lower=True, check_finite=False)
            d = np.abs(np.diag(c))
            if d.min() ** 2 < 1e-12 * d.max() ** 2:  # nearly singular beyond the null space found
                raise np.linalg.LinAlgError
            inv, info = dpotri(c, lower=1)  # (H + N Nᵀ)⁻¹, its lower triangle
            if info != 0:
                raise np.linalg.LinAlgError
            low = [[inv[i + max(a, b), i + min(a, b)] for b in range(3)] for a in range(3)]
            NN = [[np.einsum("ik,ik->i", N[i + a], N[i + b]) for b in range(3)] for a in range(3)]
            return np.stack([np.stack([low[a][b] - NN[a][b] for b in range(3)], axis=1) for a in range(3)], axis=1)
        except np.linalg.LinAlgError:
            C = np.linalg.pinv(H, rcond=1e-9, hermitian=True)
    return np.stack([np.stack([C[i + a, i + b] for b in range(3)], axis=1) for a in range(3)], axis=1)


def _null_basis(H: np.ndarray) -> np.ndarray:
    """(3n, k) orthonormal: the x and y translation of each of H's connected groups of walks, and the rotation
    of a walk without any evidence (a group of its own whose rotation nothing holds)."""
    from scipy.sparse.csgraph import connected_components

    n = len(H) // 3
    linked = np.abs(H).reshape(n, 3, n, 3).sum(axis=(1, 3)) > 0
    g, label = connected_components(sp.csr_matrix(linked), directed=False)
    size = np.bincount(label, minlength=g)
    free = (size[label] == 1) & (np.diag(H)[2::3] == 0)
    N = np.zeros((3 * n, 2 * g + int(free.sum())))
    for axis in range(2):
        N[3 * np.arange(n) + axis, 2 * label + axis] = 1.0 / np.sqrt(size[label])
    N[3 * np.flatnonzero(free) + 2, 2 * g + np.arange(int(free.sum()))] = 1.0
    return N


def _own_blocks_inverted(H: sp.csr_matrix) -> np.ndarray:
    """(n, 3, 3) each walk's own 3 x 3 block of H inverted (its frame's covariance given the others'); NaN
    where singular."""
    coo = H.tocoo()
    on = coo.row // 3 == coo.col // 3
    blocks = np.zeros((H.shape[0] // 3, 3, 3))
    np.add.at(blocks, (coo.row[on] // 3, coo.row[on] % 3, coo.col[on] % 3), coo.data[on])
    out = np.full_like(blocks, np.nan)
    ok = np.linalg.matrix_rank(blocks, hermitian=True) == 3
    out[ok] = np.linalg.inv(blocks[ok])
    return out


def _pairs_information(T: np.ndarray, a: np.ndarray, b: np.ndarray, sigma: np.ndarray, placed: np.ndarray,
                       col: np.ndarray, walks: WalkSet) -> sp.csr_matrix:
    """Sparse information matrix of the position differences of node pairs (a, b) between placed walks."""
    nv = 3 * int((col >= 0).sum())
    wa, wb = walks.walk_of[a], walks.walk_of[b]
    m = placed[wa] & placed[wb] & (wa != wb)
    if not m.any():
        return sp.csr_matrix((nv, nv))
    J, _, w = linearise(T, a[m], b[m], wa[m], wb[m], col, nv, walks)
    s = np.r_[sigma[m], sigma[m]] / PAIR_SIGMA_M  # linearise whitens by PAIR_SIGMA_M
    return (J.T @ sp.diags(w / s**2) @ J).tocsr()
