"""A predicted placement error per walk, in metres, from the evidence that holds the walk where it is.

The placed walks are treated as rigid bodies (x, y, theta each) held by the cross-walk pairs of the final
solve (position differences, sigma PAIR_SIGMA_M, robust weights at the final residuals as in the
walk-level refinement), the position ties between walks (their own sigma) and the compass (a rotation
prior of COMPASS_SIGMA_RAD per walk with one). The covariance of each walk's frame is the pseudo-inverse
of that information matrix — the gauge left free, so the figure is an error *relative to the map as a
whole*, as a map aligned to the building by one rigid fit has it. A walk's figure combines its position
sigma with its rotation sigma times its own radius.

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
F2, B1, F6 and IPIN (docs/optimize.md). Pairs of consecutive scans are not independent, so the covariance
alone is too small; CALIBRATION scales the product to the walks' median real error (docs/optimize.md: on
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
# walks; above this many placed walks the dense pseudo-inverse is skipped (NaN): O(n^3)
MAX_WALKS = 1500


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
    if len(act) < 2 or len(act) > MAX_WALKS:
        return out
    T = walk_frames(walks, poses)
    col = np.full(walks.n_walks, -1)
    col[act] = np.arange(len(act))
    H = _pairs_information(T, pk, pq, np.full(len(pk), PAIR_SIGMA_M), placed, col, walks)
    H += _pairs_information(T, ties.node_a, ties.node_b, ties.sigma_m, placed, col, walks)
    rot = act[compass[act]]
    H[3 * col[rot] + 2, 3 * col[rot] + 2] += 1.0 / COMPASS_SIGMA_RAD**2
    C = np.linalg.pinv(H, rcond=1e-9, hermitian=True)
    i = 3 * col[act]
    radius = np.array([geometry.extent_m(walks.raw[walks.starts[w]:walks.ends[w], :2]) for w in act])
    var = C[i, i] + C[i + 1, i + 1] + C[i + 2, i + 2] * radius**2
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


def _pairs_information(T: np.ndarray, a: np.ndarray, b: np.ndarray, sigma: np.ndarray, placed: np.ndarray,
                       col: np.ndarray, walks: WalkSet) -> np.ndarray:
    """Dense information matrix of the position differences of node pairs (a, b) between placed walks."""
    nv = 3 * int((col >= 0).sum())
    wa, wb = walks.walk_of[a], walks.walk_of[b]
    m = placed[wa] & placed[wb] & (wa != wb)
    if not m.any():
        return np.zeros((nv, nv))
    J, _, w = linearise(T, a[m], b[m], wa[m], wb[m], col, nv, walks)
    s = np.r_[sigma[m], sigma[m]] / PAIR_SIGMA_M  # linearise whitens by PAIR_SIGMA_M
    return np.asarray((J.T @ sp.diags(w / s**2) @ J).todense())
