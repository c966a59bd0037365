"""Session continuity: walks recorded one after the other by one device are not independent.

A surveyor (or a cleaner, a robot) records walk after walk; where one recording ends, the next usually
starts nearby, and the shorter the gap the nearer (MS ILC 2.0: with a gap under 10 s 79-88 % of the next
walks start within 5 m of where the last one ended; a 10-60 s gap moves the start by 0.2-0.5 m per second).
The heading across a join is not kept (phones turn ~100°), so a join ties *positions* only.

- Joins: the walks of one device in time order, each next walk starting 0 ... ``max_gap_s`` after the
  previous one ended. A device whose walks overlap in time has clocks that are not comparable (relative
  to each file's start) or several devices under one id: no joins for it (the report names it).
- Radio check: the last scans of one walk and the first of the next (JOIN_SCAN_S around the join) must not
  look far apart — the RSS distance's likelihood ratio near/far under the data set's own RF model
  (:mod:`rmbuild.slam.rfmodel`) must be at least JOIN_MIN_LR; a join without scans on either side is kept
  only when its gap is below JOIN_BLIND_MAX_GAP_S.
- Placement: the joins are position ties (:meth:`ties`) with a 1-sigma of JOIN_SIGMA_M + ``speed_m_s`` x
  gap; they join components of walks that Wi-Fi placed apart (:mod:`rmbuild.slam.placement.link`).
- Solve: each join between two walks of one placed component is a robust (Cauchy) range factor between the
  two poses, measuring 0 m with that sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from rmbuild.config.optimize import ContinuityConfig
from rmbuild.slam.evidence.base import EvidenceSource, StaticFactors, Ties
from rmbuild.slam.factors import X
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.rfmodel import RFModel
from rmbuild.slam.rss import RssMatrix

# m; 1-sigma of a join with no gap (the surveyor resumes where the last recording ended)
JOIN_SIGMA_M = 2.0
# s; scans this close to a walk's end / start take part in the radio check at a join
JOIN_SCAN_S = 5.0
# the radio check keeps a join whose RSS distance is at least this likely near as far
JOIN_MIN_LR = 1.0
# s; a join with no scan near it on one side is kept only below this gap
JOIN_BLIND_MAX_GAP_S = 10.0
# Cauchy kernel width (sigmas) of a join in the solve: a surveyor who did walk elsewhere stops pulling
JOIN_CAUCHY_K = 1.0


@dataclass
class Joins:
    """Consecutive walks of one device: walk a then walk b, the last node of a and the first of b, the gap
    (s), the RSS distance at the join (dB, NaN without scans) and whether the join is kept."""

    walk_a: np.ndarray
    walk_b: np.ndarray
    node_a: np.ndarray
    node_b: np.ndarray
    gap_s: np.ndarray
    rss_db: np.ndarray
    kept: np.ndarray


class ContinuitySource(EvidenceSource):
    """Ties between consecutive walks of one device (module docstring)."""

    name = "continuity"

    def __init__(self, walks: WalkSet, cfg: ContinuityConfig, rf: RFModel, rss: RssMatrix, row_node: np.ndarray):
        self.warnings: list[str] = []
        self.cfg = cfg
        self.walks = walks
        self.overlapping: list[str] = []
        self.joins = find_joins(walks, cfg.max_gap_s, self.overlapping) if cfg.use else _no_joins()
        self.joins.rss_db = join_rss(walks, self.joins, rss, row_node)
        lr_ok = rf.log_lr(self.joins.rss_db) >= np.log(JOIN_MIN_LR)
        blind = ~np.isfinite(self.joins.rss_db)
        self.joins.kept = np.where(blind, self.joins.gap_s < JOIN_BLIND_MAX_GAP_S, lr_ok)
        self.sigma = JOIN_SIGMA_M + cfg.speed_m_s * self.joins.gap_s
        self.used = np.zeros(len(self.joins.gap_s), bool)

    def ties(self) -> Ties:
        k = self.joins.kept
        return Ties(self.joins.node_a[k], self.joins.node_b[k], self.sigma[k])

    def static_factors(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> StaticFactors:
        """A robust range factor (0 m, sigma of the gap) per kept join inside one placed component."""
        comp = placement.component
        j = self.joins
        self.used = j.kept & (comp[j.walk_a] == comp[j.walk_b]) & walks.keep[j.walk_a] & walks.keep[j.walk_b]
        out = []
        for a, b, s in zip(j.node_a[self.used].tolist(), j.node_b[self.used].tolist(), self.sigma[self.used].tolist()):
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(JOIN_CAUCHY_K),
                                                   gtsam.noiseModel.Isotropic.Sigma(1, s))
            out.append(gtsam.RangeFactorPose2(X(a), X(b), 0.0, noise))
        return StaticFactors(out, {"continuity": len(out)})

    def required_nodes(self) -> np.ndarray:
        return np.r_[self.joins.node_a[self.used], self.joins.node_b[self.used]].astype(np.int64)

    def report(self) -> dict:
        j = self.joins
        return {"joins": int(len(j.gap_s)), "kept": int(j.kept.sum()), "in_solve": int(self.used.sum()),
                "median_gap_s": float(np.median(j.gap_s)) if len(j.gap_s) else None,
                # devices whose walks overlap in time: no joins (several devices under one id, or clocks
                # that restart with each recording)
                "devices_overlapping": self.overlapping}


def _no_joins() -> Joins:
    e = np.zeros(0, np.int64)
    return Joins(e, e, e, e, np.zeros(0), np.zeros(0), np.zeros(0, bool))


def find_joins(walks: WalkSet, max_gap_s: float, overlapping: list[str]) -> Joins:
    """Consecutive walks of each device with a gap in [0, max_gap_s] (module docstring); the devices whose
    walks overlap in time are appended to ``overlapping``."""
    dev = walks.device if walks.device is not None else np.full(walks.n_walks, "", dtype=object)
    ok = walks.keep & (walks.ends > walks.starts)
    t0 = np.where(ok, walks.t_s[np.minimum(walks.starts, walks.n - 1)], np.nan)
    t1 = np.where(ok, walks.t_s[np.maximum(walks.ends - 1, 0)], np.nan)
    rows: list[tuple[int, int, float]] = []
    for d in np.unique(dev[ok]):
        if d == "":
            continue
        ws = np.flatnonzero(ok & (dev == d))
        ws = ws[np.argsort(t0[ws], kind="stable")]
        gaps = t0[ws[1:]] - t1[ws[:-1]]
        if (gaps < 0).any():  # several devices under one id, or clocks relative to each recording
            overlapping.append(str(d))
            continue
        rows += [(int(a), int(b), float(g)) for a, b, g in zip(ws[:-1], ws[1:], gaps) if g <= max_gap_s]
    if not rows:
        return _no_joins()
    a, b, g = (np.array(x) for x in zip(*rows))
    return Joins(a, b, walks.ends[a] - 1, walks.starts[b], g.astype(float), np.full(len(a), np.nan),
                 np.ones(len(a), bool))


def join_rss(walks: WalkSet, j: Joins, rss: RssMatrix, row_node: np.ndarray) -> np.ndarray:
    """Per join: the smallest RSS distance (dB) between a scan of walk a in its last JOIN_SCAN_S and a scan
    of walk b in its first JOIN_SCAN_S (NaN when either side has none)."""
    out = np.full(len(j.gap_s), np.nan)
    t_row, w_row = walks.t_s[row_node], walks.walk_of[row_node]
    for i, (a, b) in enumerate(zip(j.walk_a.tolist(), j.walk_b.tolist())):
        ra = np.flatnonzero((w_row == a) & (t_row >= walks.t_s[j.node_a[i]] - JOIN_SCAN_S))
        rb = np.flatnonzero((w_row == b) & (t_row <= walks.t_s[j.node_b[i]] + JOIN_SCAN_S))
        if len(ra) and len(rb):
            d, _ = rss.block(ra, rb)
            out[i] = float(d.min())
    return out
