"""Per-walk step-length scale of the dead reckoning (phone PDR: an uncalibrated step length per user).

The pose graph has no scale variable: each walk's odometry increments are multiplied by a per-walk scale
s_w before the factors are built, and s_w is re-estimated between solves (:func:`update_scales`):

1. the scale the solve already gave the walk, from its solved vs. measured body-frame increments,
   ``s_inc = Σ u_meas·u_solved / Σ |u_meas|²`` (close to s_w: the odometry factors are stiff);
2. the residual stretch ``r`` its Wi-Fi evidence asks for: the walk's solved positions of its in-range
   cross-walk pair nodes are fitted to their partners' positions with a robust (Cauchy IRLS) scale +
   translation model ``b ≈ t + r·a`` (rotation is held by the magnetometer priors), with a Gaussian
   prior s_w ~ 1;
3. ``s_w = clamp(s_inc · r)``; optionally all fitted scales are normalised to a median of 1
   (without anchors the map's overall scale is not observable by vicinity factors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import OdometryConfig

# a walk's scale is fitted only with at least SCALE_MIN_PAIRS cross pairs within range spread over at least
# SCALE_MIN_SPAN_M of its solved path: over a short span the pairs' metres of spread swamp a few per cent
# of stretch (docs/notes/optimize.md: ILC F1 with 15 m fitted 46 walks and went 6.9 -> 10.8 m)
SCALE_MIN_PAIRS = 20
SCALE_MIN_SPAN_M = 60.0
# m; Cauchy scale of the robust fit of pair residuals
SCALE_ROBUST_M = 3.0
# relative 1-sigma of the prior s_w ~ 1
SCALE_PRIOR_SIGMA = 0.15


def scaled_raw(raw: np.ndarray, starts: np.ndarray, ends: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``raw`` poses with each walk's positions scaled by its s_w about the walk's first pose."""
    out = raw.copy()
    for w, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
        if e - s < 2 or scale[w] == 1.0:
            continue
        out[s:e, :2] = raw[s, :2] + scale[w] * (raw[s:e, :2] - raw[s, :2])
    return out


def increment_scale(raw_seg: np.ndarray, solved_seg: np.ndarray) -> float:
    """Closed-form scale of a walk's solved vs. measured translation increments (body frame)."""
    um = geometry.increments(raw_seg)[:, :2]
    us = geometry.increments(solved_seg)[:, :2]
    den = float((um * um).sum())
    return float((um * us).sum() / den) if den > 0 else 1.0


@dataclass
class ScaleFit:
    ratio: float  # residual stretch r of the walk's solved path asked for by its pairs
    n_pairs: int
    span_m: float
    ok: bool


def fit_stretch(a: np.ndarray, b: np.ndarray, s_cur: float) -> ScaleFit:
    """Robust fit of ``b ≈ t + r·a`` (a: own pair nodes, b: partners) with the prior s_cur·r ~ 1."""
    n = len(a)
    span = float(np.hypot(*(a.max(axis=0) - a.min(axis=0)))) if n else 0.0
    if n < SCALE_MIN_PAIRS or span < SCALE_MIN_SPAN_M:
        return ScaleFit(1.0, n, span, False)
    c = SCALE_ROBUST_M
    lam = 1.0 / SCALE_PRIOR_SIGMA**2  # prior information on s (per unit of s²)
    wts = np.ones(n)
    r = 1.0
    for _ in range(8):
        ws = wts.sum()
        am = (wts[:, None] * a).sum(axis=0) / ws
        bm = (wts[:, None] * b).sum(axis=0) / ws
        ac, bc = a - am, b - bm
        A = float((wts * (ac * bc).sum(axis=1)).sum()) / c**2
        B = float((wts * (ac * ac).sum(axis=1)).sum()) / c**2
        r = (A + lam * s_cur) / (B + lam * s_cur**2)
        e = np.hypot(*(r * ac - bc).T)
        wts = 1.0 / (1.0 + (e / c) ** 2)
    return ScaleFit(float(r), n, span, True)


def update_scales(current: np.ndarray, raw: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                  scale: np.ndarray, eligible: np.ndarray, pk: np.ndarray, pq: np.ndarray, walk_of: np.ndarray,
                  ocfg: OdometryConfig, normalize: bool) -> tuple[np.ndarray, np.ndarray]:
    """New per-walk scales from the solved poses ``current`` and the cross pairs (pk, pq) near each other.

    Returns (new scale, fitted mask). Walks not ``eligible`` or without enough spread pairs keep theirs.
    """
    new = scale.copy()
    n_w = len(scale)
    wk, wq = walk_of[pk], walk_of[pq]
    cross = wk != wq
    pk, pq, wk, wq = pk[cross], pq[cross], wk[cross], wq[cross]
    n_used = np.bincount(wk, minlength=n_w) + np.bincount(wq, minlength=n_w)
    s_inc = np.ones(n_w)
    fitted = np.zeros(n_w, bool)
    for w in np.flatnonzero(eligible):
        s, e = starts[w], ends[w]
        if e - s < 2 or n_used[w] < SCALE_MIN_PAIRS:
            continue
        own = np.r_[pk[wk == w], pq[wq == w]]
        a = current[own, :2]
        if float(np.hypot(*(a.max(axis=0) - a.min(axis=0)))) < SCALE_MIN_SPAN_M:
            continue
        s_inc[w] = increment_scale(raw[s:e], current[s:e])  # raw is unscaled: the walk's total scale
        fitted[w] = True
    for w in np.flatnonzero(fitted):
        own = np.r_[pk[wk == w], pq[wq == w]]
        other = np.r_[pq[wk == w], pk[wq == w]]
        f = fit_stretch(current[own, :2], current[other, :2], s_inc[w])
        new[w] = s_inc[w] * f.ratio
    if normalize and fitted.sum() >= 2:
        g = float(np.median(new[fitted]))  # median: one badly scaled walk does not shift the others
        new[fitted] /= g
    new = np.clip(new, ocfg.scale_min, ocfg.scale_max)
    return new, fitted
