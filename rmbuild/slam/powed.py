"""The powed RSS representation, its exponent chosen on each data set itself.

Torres-Sospedra et al. (2015) found that fingerprints compare better when readings are mapped to
``((rss − fill) / range) ** β`` than as dBm: strong readings, which say most about where a scan was taken,
weigh more than the weak ones near the detection floor. Which β suits a venue depends on its radio: on the
MS ILC floors and IPIN 2023 the best one ranges from 1 (as read) to 2. rmbuild chooses it per data set
with the ruler of the RF model (``rfmodel.py``) — pairs of scans of one walk whose separation the walk's
own dead reckoning knows: the β whose RSS distance best tells *near* pairs from *far* ones (area under the
ROC curve) is used when it does so clearly better than the readings as read. Values are mapped back onto
a dBm-like scale (``fill + range · x**β``), so the RF model and the gates keep their units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild.config.optimize import WifiConfig
from rmbuild.slam import devices
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.rfmodel import FAR_M, NEAR_M, same_walk_pairs
from rmbuild.slam.rss import RssMatrix
from rmbuild.types import Fingerprints

# dB above the fill level that maps to 1 (readings of -30 dBm and above with fill -110)
RANGE_DB = 80.0
# the exponents tried when the config leaves the choice to the data
CANDIDATES = (1.0, 1.25, 1.5, 2.0, 2.5)
# same-walk pairs the choice is made on at most (a deterministic subsample beyond)
MAX_PAIRS = 200_000
# AUC a β must gain over the readings as read (β = 1) to be used: smaller gains did not carry over to the
# placed map (docs/optimize.md, step 1)
MIN_AUC_GAIN = 0.03
# pairs each class (near, far) needs; with fewer the readings are used as read (β = 1)
MIN_PAIRS = 30


def powed(fp: Fingerprints, beta: float, fill_dbm: float) -> Fingerprints:
    """``fp`` with every reading r mapped to ``fill + RANGE_DB · ((r − fill) / RANGE_DB) ** beta``."""
    if beta == 1.0:
        return fp
    x = np.clip((fp.rss_dbm - fill_dbm) / RANGE_DB, 0.0, None)
    return Fingerprints(fp.node, fp.bssids, (fill_dbm + RANGE_DB * x**beta).astype(np.float32), fp.count)


def auc(near: np.ndarray, far: np.ndarray) -> float:
    """P(a near pair's RSS distance < a far pair's), ties counted half (Mann-Whitney)."""
    s = np.r_[near, far]
    order = np.argsort(s, kind="stable")
    ranks = np.empty(len(s))
    ranks[order] = np.arange(1, len(s) + 1)
    _, inv, cnt = np.unique(s, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=ranks)
    ranks = (sums / cnt)[inv]  # mean rank within ties
    u_near = ranks[: len(near)].sum() - len(near) * (len(near) + 1) / 2
    return float(1.0 - u_near / (len(near) * len(far)))


def choose(fp: Fingerprints, walks: WalkSet, fill_dbm: float, min_common: int) -> tuple[float, dict[float, float]]:
    """The candidate β whose RSS distance separates one walk's near scan pairs (< NEAR_M by its dead
    reckoning) from its far ones (FAR_M) best — 1 unless it gains MIN_AUC_GAIN over it —, and each
    candidate's AUC ({} when too few pairs)."""
    node = fp.node
    ii, jj = same_walk_pairs(walks.walk_of[node], walks.path[node], walks.t_s[node])
    if len(ii) > MAX_PAIRS:
        pick = np.sort(np.random.default_rng(0).choice(len(ii), MAX_PAIRS, replace=False))
        ii, jj = ii[pick], jj[pick]
    d = np.hypot(*(walks.raw[node[ii], :2] - walks.raw[node[jj], :2]).T)
    near, far = d < NEAR_M, (d > FAR_M[0]) & (d < FAR_M[1])
    scores: dict[float, float] = {}
    for beta in CANDIDATES:
        r, common = RssMatrix.from_fingerprints(powed(fp, beta, fill_dbm), fill_dbm).pairs(ii, jj)
        ok = common >= min_common
        if (ok & near).sum() < MIN_PAIRS or (ok & far).sum() < MIN_PAIRS:
            return 1.0, {}
        scores[beta] = auc(r[ok & near], r[ok & far])
    best = max(scores, key=lambda b: scores[b])
    return (best if scores[best] >= scores[1.0] + MIN_AUC_GAIN else 1.0), scores


def for_data(fp: Fingerprints, walks: WalkSet, exponent: float, fill_dbm: float,
             min_common: int) -> tuple[Fingerprints, float, dict[float, float]]:
    """``fp`` in the powed representation: with ``exponent`` > 0 that β, else the data's choice
    (:func:`choose`); and β and the candidates' AUCs."""
    beta, scores = (float(exponent), {}) if exponent > 0 else choose(fp, walks, fill_dbm, min_common)
    return powed(fp, beta, fill_dbm), beta, scores


@dataclass(frozen=True)
class Compared:
    """The fingerprints the Wi-Fi evidence compares and how they were made: the phones' offsets removed
    (``offsets_db``, :mod:`rmbuild.slam.devices`), then the powed representation of exponent ``beta``
    (``auc``: each candidate's AUC when it was chosen here)."""

    fingerprints: Fingerprints
    offsets_db: dict[str, float]
    beta: float
    auc: dict[float, float]


def compared(walks: WalkSet, cfg: WifiConfig, exponent: float | None = None) -> Compared:
    """``walks``' fingerprints as the Wi-Fi evidence compares them; ``exponent`` (> 0) overrides the
    config's ``rss_exponent`` (the incremental run keeps the exponent its map was built with)."""
    fp, offsets = devices.rf_fingerprints(walks, cfg.calibrate_devices)
    fp, beta, auc_ = for_data(fp, walks, exponent or cfg.rss_exponent, cfg.fill_dbm, cfg.min_common_aps)
    return Compared(fp, offsets, beta, auc_)
