"""Wi-Fi vicinity evidence: scans that look alike were recorded near each other (Gu et al., eq. 9-10).

- Search (:mod:`rmbuild.slam.pairs`): candidate node pairs by RSS distance, run-matched (default) or the
  paper's median-window rule.
- Placement: the cross-walk candidates are the links walks are fitted with; the fingerprints localise
  scans on the placed map (kNN growth).
- Solve: the pool is every candidate consistent with the placement (cross-walk pairs inside one placed
  component, same-walk pairs that agree with the walk's own dead reckoning); each solve uses the pool pairs
  within d_max at the poses it starts from, as eq. 10's fuzzy range factors — or, for two nodes walking
  (anti)parallel, as anisotropic factors whose across/along sigma ratio is estimated from the solved pairs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild import geometry
from rmbuild.config.optimize import WifiConfig
from rmbuild.slam import powed
from rmbuild.slam.evidence.base import EvidenceSource, Links, SolveState, Update
from rmbuild.slam.factors import (
    anisotropic_factor,
    anisotropic_noise,
    fuzzy_error,
    vicinity_factor,
    vicinity_noise,
)
from rmbuild.slam.held import Holding
from rmbuild.slam.pairs import RowMeta, SearchParams, median_window_pairs, run_matched_candidates, window_median
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.rfmodel import RFModel, calibrate
from rmbuild.slam.rss import RssMatrix

# A same-walk pair is kept when its two nodes lie, by the walk's own dead reckoning, within this distance
# (m) plus WITHIN_DRIFT_PER_M times the path walked between them (dead-reckoning drift).
WITHIN_GATE_M = 3.0
WITHIN_DRIFT_PER_M = 0.02
# Anisotropic pairs: two nodes walk (anti)parallel within this angle (deg); the estimated across/along
# ratio is clamped to [ACROSS_RATIO_MIN, 1], needs ACROSS_MIN_PAIRS pairs in range and asks for another
# solve when it moves by more than ACROSS_TOL (docs/notes/optimize.md, step 7).
PARALLEL_MAX_DEG = 10.0
ACROSS_RATIO_MIN = 0.25
ACROSS_MIN_PAIRS = 50
ACROSS_TOL = 0.02
# deg; a walk whose pose headings differ from its direction of motion by more than this (median over its
# steps; e.g. a device yaw instead of a step heading) keeps isotropic pairs, with a warning.
HEADING_MOTION_MAX_DEG = 20.0
# Scans sparser than this along the walks (median metres walked between consecutive scans of a walk), or
# fewer per walk than SPARSE_SCANS_PER_WALK, get a warning. With the real floors' scans thinned (docs/notes/
# optimize.md, "Scan rate") MS ILC site1/F1 linked 88 of 106 walks with its own scans (2.7 m apart, 14 per
# walk), 41 with one scan per 5 s (6.9 m, 5 per walk), 19 with Android 9's four per two minutes (2.8 m,
# 4 per walk); IPIN 2023 -2 (2.0 m, 34 per walk) linked 28 of 28, 26 at 6.1 m and 14 per walk, 20 at 9.9 m.
SPARSE_SCAN_SPACING_M = 4.0
SPARSE_SCANS_PER_WALK = 8

CandidatesHook = Callable[[pd.DataFrame, WalkSet], pd.DataFrame]


def search_params(cfg: WifiConfig) -> SearchParams:
    return SearchParams(window_steps=cfg.window_steps, min_common_aps=cfg.min_common_aps, within_walk=cfg.within_walk)


@dataclass
class ScanSimilarity:
    """What kNN placement needs of the fingerprints: the eq. 9 distance matrix, the node of each row, each
    row's own-walk window median (its similarity threshold), the shared APs a neighbour needs and the data
    set's RF model."""

    rss: RssMatrix
    row_node: np.ndarray
    threshold: np.ndarray
    min_common: int
    rf: RFModel


class WifiSource(EvidenceSource):
    """Wi-Fi vicinity pairs (module docstring)."""

    name = "wifi"

    def __init__(self, walks: WalkSet, cfg: WifiConfig, progress=None, candidates_hook: CandidatesHook | None = None,
                 holding: Holding | None = None):
        """``holding``: a held map (:mod:`rmbuild.slam.held`): the search looks only for pairs with a scan of
        a walk not held, the scans are compared as the held map's were (its RSS exponent) and its RF model
        is kept; pairs between two held walks never join the pool."""
        self.warnings: list[str] = []
        self.cfg = cfg
        self.walks = walks
        self.fixed = holding.fixed if holding is not None else np.zeros(walks.n_walks, bool)
        self.density = walks.scan_density()
        line = sparse_scans_warning(*self.density)
        self.warnings += [line] if line else []
        self.compared = powed.compared(walks, cfg, holding.state.rss_exponent if holding is not None else None)
        fp = self.compared.fingerprints
        self.rss = RssMatrix.from_fingerprints(fp, cfg.fill_dbm)
        self.meta = RowMeta(fp.node, walks.walk_of[fp.node], walks.step[fp.node], walks.t_s[fp.node],
                            walks.path[fp.node])
        params = search_params(cfg)
        only = ~self.fixed[self.meta.walk] if holding is not None else None
        if cfg.search == "median_window":
            cand, _ = median_window_pairs(self.rss, self.meta, params, progress, only)
        else:
            cand = run_matched_candidates(self.rss, self.meta, params, progress, only)
        cand["node_k"] = fp.node[cand["row_k"].to_numpy()]
        cand["node_q"] = fp.node[cand["row_q"].to_numpy()]
        cand = cand.drop(columns=["row_k", "row_q"])
        cand["injected"] = False
        if candidates_hook is not None:
            cand = candidates_hook(cand, walks)
        self.candidates = cand.reset_index(drop=True)
        self.rf = RFModel(*holding.state.rf_model, 0, 0) if holding is not None else calibrate(
            self.rss, self.meta.walk, walks.raw[fp.node, :2], self.meta.path_m, self.meta.t_s, cfg.min_common_aps)
        c = self.candidates[self._is_cross(self.candidates)]
        self._links = Links(c["node_k"].to_numpy(), c["node_q"].to_numpy())  # the search's cross pairs
        self._locator: ScanSimilarity | None = None

    # ------------------------------------------------------------------------------------ placement
    def _is_cross(self, cand: pd.DataFrame) -> np.ndarray:
        w = self.walks.walk_of
        return w[cand["node_k"].to_numpy()] != w[cand["node_q"].to_numpy()]

    def links(self) -> Links:
        return self._links

    def scan_locator(self) -> ScanSimilarity:
        """The locator (computed once: placement asks for it several times)."""
        if self._locator is None:
            thr = window_median(self.rss, self.meta, self.cfg.window_steps)
            self._locator = ScanSimilarity(self.rss, self.walks.fingerprints.node, thr, self.cfg.min_common_aps,
                                           self.rf)
        return self._locator

    # ------------------------------------------------------------------------------------ solve set-up
    def prepare(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        """The pool of pairs consistent with the placement and the first solve's selection."""
        cand = self.candidates
        if placement.links is not None and len(placement.links[0]):
            lk, lq = placement.links  # scan links that placed walks on the map join the pool
            extra = pd.DataFrame({"node_k": np.minimum(lk, lq), "node_q": np.maximum(lk, lq), "rss_dist": np.nan,
                                  "common": 0, "kind": "cross", "injected": False})
            cand = pd.concat([cand, extra], ignore_index=True).drop_duplicates(["node_k", "node_q"])
            cand = cand.reset_index(drop=True)
        self.candidates = cand
        nk, nq = cand["node_k"].to_numpy(), cand["node_q"].to_numpy()
        cross = self._is_cross(cand)
        comp = placement.component[walks.walk_of]
        d_init = np.hypot(*(init_xyt[nk, :2] - init_xyt[nq, :2]).T)
        self.candidates["init_dist_m"] = d_init
        if placement.gate_m is None:  # a placement that verified nothing (origin): every candidate
            pool = np.ones(len(cand), bool)
            first = pool.copy()
        else:
            pool = cross & (comp[nk] == comp[nq])
            first = pool & (d_init < placement.gate_m)
            if self.cfg.within_walk:
                d_raw = np.hypot(*(walks.raw[nk, :2] - walks.raw[nq, :2]).T)
                gate = WITHIN_GATE_M + WITHIN_DRIFT_PER_M * np.abs(walks.path[nk] - walks.path[nq])
                ok_within = ~cross & (d_raw < gate)
                pool |= ok_within
                first |= ok_within
        pool &= ~(self.fixed[walks.walk_of[nk]] & self.fixed[walks.walk_of[nq]])  # held-held: no information
        self.pool_idx = np.flatnonzero(pool)
        self.pk, self.pq = nk[self.pool_idx], nq[self.pool_idx]
        self.active = first[self.pool_idx]
        self._setup_anisotropy(walks)

    def _setup_anisotropy(self, walks: WalkSet) -> None:
        cfg = self.cfg
        aniso_ok = cfg.d_min == 0
        self.heading_off = np.zeros(walks.n_walks, bool)
        if aniso_ok and cfg.across_ratio < 1:
            dev = heading_motion_deviation_deg(walks.raw, walks.starts, walks.ends)
            self.heading_off = walks.keep & (dev > HEADING_MOTION_MAX_DEG)
            off, kept = int(self.heading_off.sum()), int(walks.keep.sum())
            if off and off == kept:
                aniso_ok = False
                self.warnings.append(f"pose headings differ from the walking direction (median "
                                     f"{np.median(dev[walks.keep]):.0f} deg > {HEADING_MOTION_MAX_DEG:g}): "
                                     "anisotropic pairs off, every pair isotropic")
            elif off:
                names = ", ".join(walks.walk_ids[w] for w in np.flatnonzero(self.heading_off)[:5])
                self.warnings.append(f"{off} walk(s) whose pose headings differ from the walking direction "
                                     f"(median > {HEADING_MOTION_MAX_DEG:g} deg: {names}{', ...' if off > 5 else ''}) "
                                     "keep isotropic pairs")
        self.across = cfg.across_ratio if aniso_ok and cfg.across_ratio > 0 else 1.0
        self.across_auto = aniso_ok and cfg.across_ratio == 0
        self.across_n = 0
        self._used = (self.active.copy(), self.across, np.zeros(walks.n_walks, bool))
        self.noise = vicinity_noise(cfg)

    def required_nodes(self) -> np.ndarray:
        return np.r_[self.pk, self.pq]

    # ------------------------------------------------------------------------------------ each solve
    def factors(self, state: SolveState) -> list:
        self._used = (self.active.copy(), self.across, state.settling.copy())
        return self._build(state.poses, *self._used)

    def final_factors(self, state: SolveState) -> list:
        active, across, settling = self._used
        self._final_par, _, _ = self._anisotropic(state.poses, self.pk[active], self.pq[active], settling, across)
        return self._build(state.poses, *self._used)

    def _build(self, poses: np.ndarray, active: np.ndarray, across: float, settling: np.ndarray) -> list:
        k, q = self.pk[active], self.pq[active]
        par, rel, anoise = self._anisotropic(poses, k, q, settling, across)
        return [anisotropic_factor(a, b, r, anoise) if p else vicinity_factor(a, b, self.cfg, self.noise)
                for a, b, p, r in zip(k.tolist(), q.tolist(), par.tolist(), rel.tolist())]

    def _anisotropic(self, poses, k, q, settling, across):
        """(mask, θq - θk, noise) of pairs (k, q): (anti)parallel, neither node on a settling or heading-off
        walk, none when the ratio is 1."""
        _, _, rel = pair_offsets(poses, k, q)
        if across >= 1:
            return np.zeros(len(k), bool), rel, None
        iso = settling | self.heading_off
        w = self.walks.walk_of
        par = is_parallel(rel) & ~(iso[w[k]] | iso[w[q]])
        return par, rel, (anisotropic_noise(self.cfg, across) if par.any() else None)

    def update(self, state: SolveState) -> Update:
        """Re-select the pairs within d_max and re-estimate the across ratio at the solved poses."""
        d_now = np.hypot(*(state.poses[self.pk, :2] - state.poses[self.pq, :2]).T)
        new_active = d_now < self.cfg.d_max
        changed = not np.array_equal(new_active, self.active)
        first_switch = moved = False
        if self.across_auto:
            w = self.walks.walk_of
            stat = new_active & ~(self.heading_off[w[self.pk]] | self.heading_off[w[self.pq]])
            new, self.across_n = estimate_across_ratio(state.poses, self.pk[stat], self.pq[stat], self.cfg.d_max)
            moved = abs(new - self.across) > ACROSS_TOL
            first_switch = moved and self.across == 1.0 and new < 1.0
            self.across = new
        self.active = new_active
        return Update(changed=changed or moved, first_switch=first_switch)

    def pairs_near(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        near = np.hypot(*(poses[self.pk, :2] - poses[self.pq, :2]).T) < self.cfg.d_max
        return self.pk[near], self.pq[near]

    # ------------------------------------------------------------------------------------ report
    def used_mask(self) -> np.ndarray:
        """bool over the candidates: the pairs of the last solve."""
        use = np.zeros(len(self.candidates), bool)
        use[self.pool_idx[self._used[0]]] = True
        return use

    def pairs_table(self, final_xyt: np.ndarray) -> pd.DataFrame:
        """The vicinity pairs of the last solve with their initial and final distances."""
        use = self.used_mask()
        used = self.candidates[use].reset_index(drop=True)
        pk, pq = used["node_k"].to_numpy(), used["node_q"].to_numpy()
        final_d = np.hypot(*(final_xyt[pk, :2] - final_xyt[pq, :2]).T)
        e_fin = fuzzy_error(final_d, self.cfg)
        ids = np.asarray(self.walks.walk_ids, dtype=object)
        w = self.walks.walk_of
        par = self._final_par
        return pd.DataFrame({
            "node_k": pk, "node_q": pq, "walk_k": ids[w[pk]], "walk_q": ids[w[pq]],
            "kind": used["kind"].to_numpy(), "rss_dist": used["rss_dist"].to_numpy(),
            "common": used["common"].to_numpy(), "init_dist_m": used["init_dist_m"].to_numpy(),
            "final_dist_m": final_d, "final_error": e_fin, "in_range": final_d < self.cfg.d_max,
            "injected": used["injected"].to_numpy(), "anisotropic": par,
        })

    def report(self) -> dict:
        across = self._used[1]
        return {"across_ratio": float(across), "estimated": bool(self.across_auto),
                "estimated_from_pairs": self.across_n, "rf_model": self.rf.report(),
                "device_offsets_db": {d: round(v, 2) for d, v in self.compared.offsets_db.items()},
                "rss_exponent": self.compared.beta,
                "rss_exponent_auc": {str(b): round(a, 4) for b, a in self.compared.auc.items()},
                "scan_spacing_m": round(self.density[0], 2), "scans_per_walk": round(self.density[1], 2)}


def sparse_scans_warning(spacing_m: float, per_walk: float) -> str | None:
    """The warning for Wi-Fi scans too sparse to place walks by (SPARSE_SCAN_SPACING_M, SPARSE_SCANS_PER_WALK),
    or None."""
    sparse = np.isfinite(spacing_m) and spacing_m > SPARSE_SCAN_SPACING_M
    few = np.isfinite(per_walk) and per_walk < SPARSE_SCANS_PER_WALK
    if not (sparse or few):
        return None
    return (f"Wi-Fi scans are sparse: a median {spacing_m:.1f} m of walking apart and {per_walk:.0f} per walk "
            f"(placement works best with scans at most {SPARSE_SCAN_SPACING_M:g} m apart and at least "
            f"{SPARSE_SCANS_PER_WALK} per walk); expect fewer walks linked, and placed less well. Record with "
            "Android's Wi-Fi scan throttling off (developer options) and in longer walks")


def is_parallel(rel: np.ndarray) -> np.ndarray:
    """Relative headings (rad) within PARALLEL_MAX_DEG of parallel or antiparallel."""
    return np.abs(np.cos(rel)) >= np.cos(np.radians(PARALLEL_MAX_DEG))


def pair_offsets(xyt: np.ndarray, k: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, across, θq - θk) of pairs (k, q) at poses xyt (n, 3): q's offset from k in q's heading frame
    (m) and the relative heading (rad, wrapped)."""
    d = xyt[q, :2] - xyt[k, :2]
    c, s = np.cos(xyt[q, 2]), np.sin(xyt[q, 2])
    rel = geometry.wrap(xyt[q, 2] - xyt[k, 2])
    return c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], rel


def estimate_across_ratio(xyt: np.ndarray, k: np.ndarray, q: np.ndarray, d_max: float) -> tuple[float, int]:
    """(ratio, n): RMS across / RMS along of the offsets of the (anti)parallel pairs among (k, q) within
    d_max at poses xyt, clamped to [ACROSS_RATIO_MIN, 1]; 1 when fewer than ACROSS_MIN_PAIRS."""
    along, acr, rel = pair_offsets(xyt, k, q)
    m = is_parallel(rel) & (np.hypot(along, acr) < d_max)
    n = int(m.sum())
    if n < ACROSS_MIN_PAIRS:
        return 1.0, n
    ratio = math.sqrt(float(np.mean(acr[m] ** 2)) / max(float(np.mean(along[m] ** 2)), 1e-12))
    return float(np.clip(ratio, ACROSS_RATIO_MIN, 1.0)), n


def heading_motion_deviation_deg(raw: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Per walk [starts, ends): the median |heading - direction of motion| (deg) over its steps that move
    by at least 0.1 m, pose i's heading against the direction from pose i-1 to pose i. 0 for step-based
    PDR, whose steps go where the heading points, and for a walk with no moving step."""
    out = np.zeros(len(starts))
    for w, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
        d = np.diff(raw[s:e, :2], axis=0)
        moving = np.hypot(d[:, 0], d[:, 1]) >= 0.1
        if moving.any():
            motion = np.arctan2(d[moving, 1], d[moving, 0])
            out[w] = np.degrees(np.median(np.abs(geometry.wrap(raw[s + 1:e, 2][moving] - motion))))
    return out
