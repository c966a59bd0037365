"""An RF similarity model calibrated on the data set itself: how the RSS distance of two scans relates to
how far apart they were recorded, without any ground truth.

The ruler is each walk's own dead reckoning: over a few tens of metres walked, the distance between two of
a walk's scans is known to about a metre. Pairs of scans of one walk recorded at least MIN_DT_S apart (so
the radio has decorrelated) give the RSS distance of *near* pairs (< NEAR_M apart by dead reckoning) and of
*far* pairs (FAR_M[0]-FAR_M[1] apart); their medians and spreads (robust, MAD) describe the venue. Two
different walks see the same place through a different day, body and phone orientation, so cross-walk
distances run higher than same-walk ones; the offsets BETWEEN_WALK_NEAR_DB / _FAR_DB are one pair of
constants for all venues (docs/optimize.md, "RF model"). The model then gives, for an RSS distance r, the
likelihood ratio LR(r) = p(r | near) / p(r | far) of two Gaussians, and the distance r* where LR = 1.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from rmbuild.slam.rss import RssMatrix

# s; same-walk pairs closer in time than this share their radio noise and are not used
MIN_DT_S = 10.0
# m of walked path; same-walk pairs further apart than this are not used (dead reckoning drifts)
MAX_PATH_M = 30.0
# m; "near" and "far" by dead reckoning
NEAR_M = 5.0
FAR_M = (15.0, 30.0)
# dB; cross-walk RSS distances minus same-walk ones, near and far (measured with truth on five MS ILC floors:
# near +0.97 to +1.63, median 1.36; far +2.61 to +4.15, median 3.43; the leave-one-floor-out medians are
# within 0.1 dB of these)
BETWEEN_WALK_NEAR_DB = 1.3
BETWEEN_WALK_FAR_DB = 3.4
# the far pairs' spread across walks over the same-walk one (same floors: 0.88-1.49, median 1.25)
BETWEEN_WALK_FAR_SPREAD = 1.25
# pairs each class needs for a calibration; below that the fallback model is used (and said)
MIN_PAIRS = 30
# dB; used when a data set has too few same-walk pairs (medians of the five floors' cross-walk figures)
FALLBACK = (23.0, 3.3, 30.5, 4.0)


@dataclass(frozen=True)
class RFModel:
    """Cross-walk RSS distance (dB) of near and far scan pairs: Gaussian mean and spread each; ``n_near``,
    ``n_far`` the same-walk pairs it was calibrated on (0 for the fallback)."""

    near_mu: float
    near_sigma: float
    far_mu: float
    far_sigma: float
    n_near: int = 0
    n_far: int = 0

    def log_lr(self, r: np.ndarray | float) -> np.ndarray:
        """ln p(r | near) - ln p(r | far) for RSS distances r (dB)."""
        r = np.asarray(r, dtype=float)
        zn = (r - self.near_mu) / self.near_sigma
        zf = (r - self.far_mu) / self.far_sigma
        return -0.5 * zn**2 + 0.5 * zf**2 + np.log(self.far_sigma / self.near_sigma)

    def threshold_db(self, log_lr: float = 0.0) -> float:
        """The RSS distance (dB) between the two means where ln LR equals ``log_lr`` (bisection)."""
        lo, hi = self.near_mu - 3 * self.near_sigma, self.far_mu
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if self.log_lr(mid) > log_lr:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def report(self) -> dict:
        return {**{k: round(v, 2) if isinstance(v, float) else v for k, v in asdict(self).items()},
                "threshold_db": round(self.threshold_db(), 2)}


def calibrate(rss: RssMatrix, walk_of_row: np.ndarray, own_xy: np.ndarray, path_m: np.ndarray, t_s: np.ndarray,
              min_common: int) -> RFModel:
    """The model of one data set from its same-walk scan pairs (module docstring).

    Per fingerprint row: ``walk_of_row`` its walk, ``own_xy`` (n, 2) its position in its walk's own frame,
    ``path_m`` metres walked, ``t_s`` time. ``min_common``: APs a pair must share.
    """
    ii, jj = same_walk_pairs(walk_of_row, path_m, t_s)
    if not len(ii):
        return RFModel(*FALLBACK)
    d = np.hypot(*(own_xy[ii] - own_xy[jj]).T)
    r, common = rss.pairs(ii, jj)
    ok = common >= min_common
    near, far = r[ok & (d < NEAR_M)], r[ok & (d > FAR_M[0]) & (d < FAR_M[1])]
    if len(near) < MIN_PAIRS or len(far) < MIN_PAIRS:
        return RFModel(*FALLBACK)
    return RFModel(float(np.median(near)) + BETWEEN_WALK_NEAR_DB, _mad(near),
                   float(np.median(far)) + BETWEEN_WALK_FAR_DB, _mad(far) * BETWEEN_WALK_FAR_SPREAD,
                   int(len(near)), int(len(far)))


def _mad(x: np.ndarray) -> float:
    return max(float(1.4826 * np.median(np.abs(x - np.median(x)))), 0.5)


def same_walk_pairs(walk_of_row: np.ndarray, path_m: np.ndarray, t_s: np.ndarray,
                     max_pairs_per_walk: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (i < j) of one walk, >= MIN_DT_S apart in time and <= MAX_PATH_M apart in walked path
    (a walk with many scans is subsampled to ``max_pairs_per_walk`` pairs, deterministically)."""
    out_i, out_j = [], []
    rng = np.random.default_rng(0)
    for w in np.unique(walk_of_row):
        rows = np.flatnonzero(walk_of_row == w)
        a, b = np.triu_indices(len(rows), 1)
        keep = ((np.abs(t_s[rows[a]] - t_s[rows[b]]) >= MIN_DT_S)
                & (np.abs(path_m[rows[a]] - path_m[rows[b]]) <= MAX_PATH_M))
        a, b = a[keep], b[keep]
        if len(a) > max_pairs_per_walk:
            pick = np.sort(rng.choice(len(a), max_pairs_per_walk, replace=False))
            a, b = a[pick], b[pick]
        out_i.append(rows[a])
        out_j.append(rows[b])
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)
