"""`rmbuild.slam.incremental`: place walks added after an optimize against its solution, without re-solving.

After ``rmbuild ingest --append`` the workspace holds the walks the last optimize placed (the *old* walks,
their node ids unchanged) followed by new ones. Instead of solving everything again, the old walks that
optimize put into the map keep their optimised poses, and only the others are placed and solved:

1. **The map as it is.** Each old linked walk's own-frame poses are replaced by its optimised poses, so
   its frame is the identity and its scans sit where the map has them.
2. **Placement**, with the full run's evidence restricted to the free walks (the new ones and the old walks
   the last optimize could not link): Wi-Fi vicinity candidates of their scans against all scans (the
   paper's median-window rule), pair growth from the map (:class:`rmbuild.slam.placement.grow.PairEvidence`),
   then rounds of continuity joins (:func:`rmbuild.slam.placement.link.link_components`), groups of tied
   walks fitted onto the map as one rigid body (the full run's merges) and kNN scan growth
   (:class:`rmbuild.slam.placement.grow.ScanEvidence`). Each walk's compass gives its rotation relative to
   the map (the map's own compass rotation: the circular mean over the held walks). The held walks never
   move: there is no walk-level refinement.
3. **The solve** (Levenberg-Marquardt, gtsam): odometry of the placed free walks (chain-reduced), fuzzy
   vicinity factors (eq. 10) on the candidates and scan links between a placed free walk and the map,
   those within the placement gate first, then re-selected within d_max after each solve; a robust range
   factor per continuity tie, compass heading priors where the walk's compass was trusted, and a tight
   prior on every old node a factor touches: the old solution stays as it is.

What the full run does and this does not: no run-matched candidate search over all scans, no anisotropic
pairs, no same-walk pairs, no step-length scale rounds, and the old walks do not move.
docs/api.md says when a full re-run is the better choice.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import gtsam
import numpy as np
import pandas as pd

from rmbuild import geometry
from rmbuild.config.optimize import OptimizeConfig
from rmbuild.errors import InputError
from rmbuild.slam import powed
from rmbuild.slam.chains import add_chain_odometry, fill_chains, keyframe_mask
from rmbuild.slam.evidence.base import Links, RotationPriors, Ties
from rmbuild.slam.evidence.compass import HEADING_PRIOR_CAUCHY_K, HEADING_PRIOR_EVERY_N, CompassSource
from rmbuild.slam.evidence.continuity import JOIN_CAUCHY_K, ContinuitySource
from rmbuild.slam.factors import X, fuzzy_error, poses_to_values, values_to_poses, vicinity_factor, vicinity_noise
from rmbuild.slam.pairs import RowMeta, window_median
from rmbuild.slam.placement.edges import RANSAC_SEED
from rmbuild.slam.placement.grow import KNN_K, MAX_ROUNDS, GrowthEvidence, PairEvidence, ScanEvidence
from rmbuild.slam.placement.link import link_components
from rmbuild.slam.placement.merge import _merge_one as merge_onto
from rmbuild.slam.placement.model import GrowState
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.result import OptimizeResult
from rmbuild.slam.rfmodel import RFModel, calibrate
from rmbuild.slam.rss import RssMatrix
from rmbuild.slam.solve import KEYFRAME_MAX_GAP, levenberg_marquardt
from rmbuild.types import Dataset, Fingerprints

log = logging.getLogger(__name__)
Progress = Callable[[str, dict], None] | None

# m and rad; 1-sigma of the priors that hold the old nodes the new factors touch (the old solution is kept)
HOLD_SIGMA_M = 0.01
HOLD_SIGMA_RAD = 0.001
# solves; the first uses the links within the placement gate, each further one those within d_max at the
# poses it starts from (the full run's default outer_iterations)
SOLVES = 3
# Wi-Fi vicinity candidates kept per scan of a free walk (the cap per node of the paper's rule in
# rmbuild.slam.pairs.SearchParams.max_pairs_per_node)
CANDIDATES_PER_SCAN = 10
# fingerprint rows per block of the candidate search's distance products
BLOCK_ROWS = 2048
# kNN growth / continuity-join alternations at most (the full run's merge rounds)
LINK_ROUNDS = 3


@dataclass
class PreviousSolution:
    """The last optimize's outputs: ``poses`` (optimize/poses: walk_id, step, t_s, x_m, y_m, heading_rad,
    linked), ``walks`` (optimize/walks), ``pairs`` (optimize/pairs) and its ``report`` (reference_walk,
    frame, ...)."""

    poses: pd.DataFrame
    walks: pd.DataFrame
    pairs: pd.DataFrame
    report: dict


@dataclass
class _Split:
    """Old nodes (the previous solution's rows, a prefix of the dataset's), and per walk: old, held (old and
    in the map: kept as it is) and free (to place)."""

    n_old_nodes: int
    old: np.ndarray
    held: np.ndarray
    free: np.ndarray


def split_walks(dataset: Dataset, walks: WalkSet, prev: PreviousSolution) -> _Split:
    """Which walks are old, held and free. Raises InputError when the previous solution's poses are not the
    first rows of the dataset's (it ran on other data) or when there is no walk to place."""
    pp, dp = prev.poses, dataset.poses
    n_old = len(pp)
    same = n_old <= len(dp) and all(
        np.array_equal(pp[c].to_numpy(), dp[c].to_numpy()[:n_old]) for c in ("step", "t_s")
    ) and bool((pp["walk_id"].astype(str).to_numpy() == dp["walk_id"].astype(str).to_numpy()[:n_old]).all())
    if not same:
        raise InputError("the last optimize ran on other walks than this workspace's earlier ingest; "
                         "--incremental only adds walks appended since (run a full `rmbuild optimize --force`)")
    old_ids = set(pp["walk_id"].astype(str))
    old = np.array([w in old_ids for w in walks.walk_ids])
    if old.all():
        raise InputError("no new walks since the last optimize: --incremental places walks added with "
                         "`rmbuild ingest --append`")
    in_map = pp.groupby(pp["walk_id"].astype(str), sort=False)["linked"].first()
    held = old & np.array([bool(in_map.get(w, False)) for w in walks.walk_ids]) & walks.keep
    if not held.any():
        raise InputError("the last optimize placed no walk in a map: nothing to add to (run a full "
                         "`rmbuild optimize --force`)")
    return _Split(n_old, old, held, walks.keep & ~held)


def optimize_incremental(dataset: Dataset, fingerprints: Fingerprints, cfg: OptimizeConfig, prev: PreviousSolution,
                         progress: Progress = None) -> OptimizeResult:
    """Place the walks not in ``prev``'s map against it and solve only them (module docstring)."""
    timing: dict[str, float] = {}
    t_all = t0 = time.perf_counter()
    walks, warnings = WalkSet.from_dataset(dataset, fingerprints, cfg.single_step_walks, cfg.compass.default_sigma_rad)
    sp = split_walks(dataset, walks, prev)
    prev_xyt = prev.poses[["x_m", "y_m", "heading_rad"]].to_numpy(float)
    held_nodes = sp.held[walks.walk_of]
    held_nodes[sp.n_old_nodes:] = False
    raw = walks.raw.copy()
    raw[held_nodes] = prev_xyt[held_nodes[:sp.n_old_nodes]]
    mw = replace(walks, raw=raw)  # the held walks in the map's frame (identity frames)
    timing["set_up"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    ref = _reference(mw, prev, sp.held)
    st, (lk, lq), ties, rot, prior, plog = _place(walks, mw, sp.held, ref, cfg, prev.report.get("vicinity") or {})
    placed = sp.free & (st.comp == 0)
    if progress:
        progress("init", {"linked": int((st.comp == 0).sum()), "walks": walks.n_walks})
    init_xyt = mw.apply_frames(st.T)
    timing["init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    solved = _solve(mw, init_xyt, placed, sp.held, (lk, lq), ties, rot, prior, st.heading_used, cfg, progress)
    timing["solve"] = time.perf_counter() - t0

    final_xyt, init_out = solved.xyt.copy(), init_xyt.copy()
    old_unplaced = np.flatnonzero((sp.old & ~placed)[walks.walk_of][:sp.n_old_nodes])
    final_xyt[old_unplaced] = init_out[old_unplaced] = prev_xyt[old_unplaced]  # as the last optimize left them
    in_map = (sp.held | placed)[walks.walk_of]
    pairs = _pairs_table(mw, solved, init_xyt, cfg)
    new_ids = [walks.walk_ids[w] for w in np.flatnonzero(~sp.old)]
    unplaced = [walks.walk_ids[w] for w in np.flatnonzero(sp.free & ~placed & ~sp.old)]
    if unplaced:
        warnings.append(f"{len(unplaced)} of {len(new_ids)} new walk(s) could not be placed against the map "
                        f"({', '.join(unplaced[:5])}{', ...' if len(unplaced) > 5 else ''}): left out of it; "
                        "a full `rmbuild optimize --force` may link them")
    for wmsg in warnings:
        log.warning(wmsg)
    timing["total"] = time.perf_counter() - t_all
    walks_df = _walk_table(walks, prev, sp, st, placed, pairs)
    stats = _stats(walks, prev, sp, placed, solved, pairs, new_ids, timing, warnings)
    return OptimizeResult(
        poses=walks.poses_frame(dataset.poses, final_xyt).assign(linked=in_map),
        initial_poses=walks.poses_frame(dataset.poses, init_out).assign(linked=in_map),
        pairs=pd.concat([prev.pairs, pairs], ignore_index=True) if len(prev.pairs) else pairs,
        candidates=pairs, walks=walks_df, stats=stats, cost_history=solved.history,
        placement_log=pd.DataFrame(plog), solve_starts=solved.starts,
    )


def _reference(mw: WalkSet, prev: PreviousSolution, held: np.ndarray) -> int:
    """The previous reference walk when it is held, else the longest held walk."""
    ref = str(prev.report.get("reference_walk") or "")
    if ref in mw.walk_ids and held[mw.walk_ids.index(ref)]:
        return mw.walk_ids.index(ref)
    return int(np.argmax(np.where(held, mw.walk_lengths(), -1.0)))


@dataclass
class _Locator:
    """What :class:`ScanEvidence` asks of the fingerprints (as the Wi-Fi source's scan locator); ``rss`` over the
    APs the free scans saw (:func:`ap_subset`): every distance asked for has a free scan on one side."""

    rss: RssMatrix
    row_node: np.ndarray
    threshold: np.ndarray
    min_common: int


def free_window_median(rss: RssMatrix, meta: RowMeta, rows: np.ndarray, cfg: OptimizeConfig) -> np.ndarray:
    """Each free scan's similarity threshold, its own walk's window median (:func:`window_median` on the
    free walks' rows only; the held rows, never localised, NaN)."""
    idx = np.flatnonzero(rows)
    out = np.full(len(rows), np.nan, np.float32)
    sub = RssMatrix(rss.a[idx], rss.b[idx], rss.sq[idx], rss.cnt[idx])
    out[idx] = window_median(sub, RowMeta(*(getattr(meta, f)[idx] for f in ("node", "walk", "step", "t_s", "path_m"))),
                             cfg.wifi.window_steps)
    return out


def _rf_model(report: dict | None, walks: WalkSet, rss: RssMatrix, meta: RowMeta, rows: np.ndarray,
              cfg: OptimizeConfig) -> RFModel:
    """The data set's RF model: the one the last optimize calibrated (its report), else calibrated on the
    free walks' scans."""
    if report and all(k in report for k in ("near_mu", "near_sigma", "far_mu", "far_sigma")):
        return RFModel(float(report["near_mu"]), float(report["near_sigma"]), float(report["far_mu"]),
                       float(report["far_sigma"]), int(report.get("n_near", 0)), int(report.get("n_far", 0)))
    idx = np.flatnonzero(rows)
    sub = RssMatrix(rss.a[idx], rss.b[idx], rss.sq[idx], rss.cnt[idx])
    return calibrate(sub, meta.walk[idx], walks.raw[meta.node[idx], :2], meta.path_m[idx], meta.t_s[idx],
                     cfg.wifi.min_common_aps)


def _place(walks: WalkSet, mw: WalkSet, held: np.ndarray, ref: int, cfg: OptimizeConfig, vicinity: dict):
    """kNN growth of the free walks from the held ones (component 0, identity frames); then the walks left
    over joined along continuity ties (turned to the compass first) and, when some were, growth again.
    ``vicinity``: the last optimize's report of the Wi-Fi evidence (its RF model and RSS exponent, which
    the new walks are compared in too)."""
    fp = powed.compared(mw, cfg.wifi, cfg.wifi.rss_exponent or float(vicinity.get("rss_exponent", 0.0))).fingerprints
    rss = RssMatrix.from_fingerprints(fp, cfg.wifi.fill_dbm)
    meta = RowMeta(fp.node, mw.walk_of[fp.node], mw.step[fp.node], mw.t_s[fp.node], mw.path[fp.node])
    free_rows = mw.keep[meta.walk] & ~held[meta.walk]
    # every distance the placement asks for has a free scan on one side: the APs the free scans saw suffice
    free_rss = ap_subset(rss, free_rows)
    locator = _Locator(free_rss, fp.node, free_window_median(free_rss, meta, free_rows, cfg), cfg.wifi.min_common_aps)
    rf = _rf_model(vicinity.get("rf_model"), walks, rss, meta, free_rows, cfg)
    ties = ContinuitySource(walks, cfg.continuity, rf, rss, fp.node).ties()
    rot = CompassSource(mw, cfg.compass).rotation_priors()
    prior = map_rotation_priors(rot, held)
    st = GrowState.empty(mw.n_walks, ref, rot.known)
    st.comp[held] = 0
    st.method[held] = "previous"
    plog: list[dict] = []
    (pk, pq), held_knn = scan_neighbours(locator, meta, free_rows, held[meta.walk])
    links = Links(pk, pq)
    rng = np.random.default_rng(RANSAC_SEED)
    st = _grow(_HeldPairs(mw, pk, pq, [], cfg.placement), st, mw, rot, prior, plog)
    for _ in range(LINK_ROUNDS):
        n_before = int((st.comp == 0).sum())
        st = _join_and_merge(st, mw, ties, links, rot, prior, cfg, rng, plog)
        ev = _HeldScanEvidence(mw, locator, cfg.placement, held, held_knn)
        st = _grow(ev, st, mw, rot, prior, plog, restart=True)
        lk, lq = ev.links()
        links = Links(np.r_[links.node_k, lk], np.r_[links.node_q, lq])
        if int((st.comp == 0).sum()) == n_before:
            break
    st.comp[st.comp < 0] = 1 + np.arange(int((st.comp < 0).sum()))
    return st, (links.node_k, links.node_q), ties, rot, prior, plog


def scan_neighbours(loc: _Locator, meta: RowMeta, rows: np.ndarray, held_rows: np.ndarray):
    """One pass of distance products for the free walks' scans (``rows``, bool over the fingerprint rows)
    against all scans, for two things (returned as ((k, q), (best_d, best_c))):

    * the Wi-Fi vicinity candidates by the paper's rule (Gu et al. 2017, eq. 9 and the window median): each
      free scan keeps the CANDIDATES_PER_SCAN scans of other walks nearest in RSS distance that are nearer
      than its own walk's window median and share enough APs (node pairs k, q);
    * each free scan's KNN_K nearest scans among the held walks' (``held_rows``) that share enough APs: the
      distances (float32, inf where fewer) and their rows (-1), the start of the kNN growth, whose held
      map never changes (:class:`_HeldScanEvidence`).

    One block per BLOCK_ROWS free scans (the full run's run-matched search compares every scan with every
    other)."""
    rss = loc.rss
    held_cols = np.flatnonzero(held_rows)
    kk = min(KNN_K, len(held_cols))
    best_d = np.full((len(rows), KNN_K), np.inf, np.float32)
    best_c = np.full((len(rows), KNN_K), -1, np.int64)
    out_k, out_q = [], []
    todo = np.flatnonzero(rows)
    for b0 in range(0, len(todo), BLOCK_ROWS):
        r = todo[b0:b0 + BLOCK_ROWS]
        d, common = rss.block(r)
        d[common < loc.min_common] = np.inf
        del common
        if kk:
            dh = d[:, held_cols]
            nb = np.argpartition(dh, kk - 1, axis=1)[:, :kk]
            best_d[r, :kk] = np.take_along_axis(dh, nb, axis=1)
            best_c[r, :kk] = held_cols[nb]
            del dh
        d[meta.walk[r][:, None] == meta.walk[None, :]] = np.inf
        d[~(d < loc.threshold[r][:, None])] = np.inf
        k = min(CANDIDATES_PER_SCAN, d.shape[1])
        nb = np.argpartition(d, k - 1, axis=1)[:, :k]
        ok = np.isfinite(np.take_along_axis(d, nb, axis=1)).ravel()
        out_k.append(np.repeat(loc.row_node[r], k)[ok])
        out_q.append(loc.row_node[nb.ravel()][ok])
    empty = np.zeros(0, np.int64)
    pairs = (np.concatenate(out_k) if out_k else empty), (np.concatenate(out_q) if out_q else empty)
    return pairs, (best_d, best_c)


def ap_subset(rss: RssMatrix, rows: np.ndarray) -> RssMatrix:
    """``rss`` restricted to the APs some of ``rows`` saw, its squared norms and AP counts kept: the
    distances of those rows to any row are the full matrix's (a pair's shared APs and dot product need no
    other AP; equal up to the rounding of the products), the distances between two other rows are not."""
    aps = rss.b[rows].any(axis=0)
    return RssMatrix(rss.a[:, aps], rss.b[:, aps], rss.sq, rss.cnt)


class _HeldPairs(PairEvidence):
    """Pair growth (the full run's first growth) from the held walks: component 0 starts as the map."""

    def start_component(self, st: GrowState, seed: int, c_id: int) -> np.ndarray:
        return st.comp == 0


class _HeldScanEvidence(ScanEvidence):
    """kNN scan growth (:class:`ScanEvidence`) that starts from each free scan's nearest held scans found
    once (:func:`scan_neighbours`) instead of comparing every free scan with every held scan again at
    each restart: only the scans of free walks placed since are merged in."""

    def __init__(self, walks: WalkSet, sim: _Locator, cfg, held: np.ndarray, held_knn: tuple[np.ndarray, np.ndarray]):
        super().__init__(walks, sim, cfg)
        self.held, self.held_knn = held, held_knn

    def start_component(self, st: GrowState, seed: int, c_id: int) -> np.ndarray:
        placed = super().start_component(st, seed, c_id)
        if c_id == 0:  # component 0: the held walks and the free walks placed so far
            self.best_d, self.best_c = (a.copy() for a in self.held_knn)
            self._new_walks = [w for w in self._new_walks if not self.held[w]]
        return placed


def _join_and_merge(st: GrowState, mw: WalkSet, ties: Ties, links: Links, rot: RotationPriors, prior: np.ndarray,
                    cfg: OptimizeConfig, rng: np.random.Generator, plog: list) -> GrowState:
    """The walks not placed yet, each turned to its compass, joined to the map and to each other along
    continuity ties (:func:`rmbuild.slam.placement.link.link_components`); each group of two or more walks
    joined so is then fitted onto the map as one rigid body from its Wi-Fi pairs (as the full run's
    merges: a group pools the evidence its short walks lack alone). Returns the state with the walks still
    apart unplaced again."""
    left = st.comp < 0
    if not left.any():
        return st
    st.comp[left] = 1 + np.arange(int(left.sum()))
    turn = left & np.isfinite(prior)
    st.T[turn, 2] = prior[turn]
    if len(ties):
        st, _ = link_components(st, mw, ties, links, rot, cfg.placement, plog)
    sizes = np.bincount(st.comp)
    for c in np.flatnonzero(sizes >= 2):
        if c > 0:
            merge_onto(st, mw, links.node_k, links.node_q, rot, cfg.placement, rng, int(c), 0, plog)
    st.comp[st.comp != 0] = -1
    return st


def _grow(ev: GrowthEvidence, st: GrowState, mw: WalkSet, rot: RotationPriors, prior: np.ndarray,
          plog: list, restart: bool = False) -> GrowState:
    """Growth rounds from component 0 (kept as it is: no refinement of placed walks); ``restart``: a
    :class:`ScanEvidence` (it keeps component 0 and frees the rest)."""
    if restart and isinstance(ev, ScanEvidence):
        st = ev.restart(st, rot)
    placed = ev.start_component(st, st.reference, 0)
    for r in range(1, MAX_ROUNDS + 1):
        free = mw.keep & (st.comp < 0)
        new = ev.round(st, placed, free, prior, 0, r, plog)
        if not new:
            break
        for w, f in new:
            st.place(w, f, 0, r)
            placed[w] = True
            ev.placed(st, w, f, prior, rot)
    return st


def map_rotation_priors(rot: RotationPriors, held: np.ndarray) -> np.ndarray:
    """Each walk frame's rotation in the map frame by its compass (NaN where unknown, all NaN when no held
    walk has a compass): its compass rotation minus the map's (the circular mean over the held walks, whose
    frames are the map's)."""
    ok = held & rot.known
    if not ok.any():
        return np.full(len(rot.theta), np.nan)
    map_rot = float(geometry.circular_mean(rot.theta[ok]))
    return np.where(rot.known, geometry.wrap(rot.theta - map_rot), np.nan)


@dataclass
class _Solved:
    xyt: np.ndarray
    pk: np.ndarray  # the vicinity pairs of the last solve
    pq: np.ndarray
    n_odometry: int
    n_held: int
    n_heading: int
    n_keyframes: int
    iterations: int
    history: list[float]
    starts: list[int]


def _solve(mw: WalkSet, xyt0: np.ndarray, placed: np.ndarray, held: np.ndarray, links: tuple[np.ndarray, np.ndarray],
           ties: Ties, rot: RotationPriors, prior: np.ndarray, heading_used: np.ndarray, cfg: OptimizeConfig,
           progress: Progress) -> _Solved:
    """Levenberg-Marquardt over the placed free walks and the held nodes their links and ties touch."""
    w_of = mw.walk_of
    lk, lq = links
    in_solve = placed | held
    ta, tb = w_of[ties.node_a], w_of[ties.node_b]
    tie_use = (placed[ta] | placed[tb]) & in_solve[ta] & in_solve[tb]
    use = (placed[w_of[lk]] | placed[w_of[lq]]) & in_solve[w_of[lk]] & in_solve[w_of[lq]] & (w_of[lk] != w_of[lq])
    pk, pq = np.minimum(lk[use], lq[use]), np.maximum(lk[use], lq[use])
    if len(pk):
        pk, pq = np.unique(np.c_[pk, pq], axis=0).T
    heading = _heading_nodes(mw, placed & heading_used & np.isfinite(prior), cfg)
    required = np.zeros(mw.n, bool)
    required[np.r_[pk, pq, heading, ties.node_a[tie_use], ties.node_b[tie_use]].astype(np.int64)] = True
    starts, ends = mw.starts[placed], mw.ends[placed]
    kf = keyframe_mask(mw.n, starts, ends, required, KEYFRAME_MAX_GAP)
    kf_idx = np.flatnonzero(kf)
    base = gtsam.NonlinearFactorGraph()
    n_odo = add_chain_odometry(base, mw.raw, starts, ends, kf, cfg.odometry)
    held_kf = kf_idx[held[w_of[kf_idx]]]
    _add_priors(base, mw, xyt0, held_kf, (ties.node_a[tie_use], ties.node_b[tie_use], ties.sigma_m[tie_use]),
                heading, _map_compass_rotation(rot, held))
    out = _Solved(xyt0.copy(), pk, pq, n_odo, len(held_kf), len(heading), len(kf_idx), 0, [], [])
    if not len(kf_idx) or not placed.any():
        return out
    values = poses_to_values(xyt0[kf_idx], nodes=kf_idx)
    vnoise = vicinity_noise(cfg.wifi)
    current, gate = xyt0, cfg.placement.gate_m
    for s in range(SOLVES):
        near = np.hypot(*(current[pk, :2] - current[pq, :2]).T) < gate
        g = gtsam.NonlinearFactorGraph(base)
        for a, b in zip(pk[near].tolist(), pq[near].tolist()):
            g.add(vicinity_factor(a, b, cfg.wifi, vnoise))
        out.starts.append(len(out.history))
        out.history.append(float(g.error(values)))
        values, it = levenberg_marquardt(g, values, cfg, out.history, progress, s, "COLAMD")
        out.iterations += it
        full = current.copy()
        full[kf_idx] = values_to_poses(values, nodes=kf_idx)
        current = fill_chains(full, mw.raw, starts, ends, kf)
        out.pk, out.pq = pk[near], pq[near]
        gate = cfg.wifi.d_max
    out.xyt = current
    return out


def _add_priors(graph: gtsam.NonlinearFactorGraph, mw: WalkSet, xyt0: np.ndarray, held_kf: np.ndarray,
                ties: tuple[np.ndarray, np.ndarray, np.ndarray], heading: np.ndarray, map_rot: float) -> None:
    """The static factors besides odometry: the hold priors on the old nodes in the solve, a robust range
    factor (0 m, sigma of the gap) per continuity tie, and a robust compass prior per heading node."""
    hold = gtsam.noiseModel.Diagonal.Sigmas(np.array([HOLD_SIGMA_M, HOLD_SIGMA_M, HOLD_SIGMA_RAD]))
    for i in held_kf.tolist():
        graph.add(gtsam.PriorFactorPose2(X(i), gtsam.Pose2(*xyt0[i]), hold))
    for a, b, sg in zip(*(t.tolist() for t in ties)):
        tie_noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(JOIN_CAUCHY_K),
                                                   gtsam.noiseModel.Isotropic.Sigma(1, sg))
        graph.add(gtsam.RangeFactorPose2(X(a), X(b), 0.0, tie_noise))
    for i in heading.tolist():
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(HEADING_PRIOR_CAUCHY_K),
                                               gtsam.noiseModel.Isotropic.Sigma(1, float(mw.yaw_sigma[i])))
        graph.add(gtsam.PoseRotationPrior2D(X(i), gtsam.Pose2(0, 0, mw.yaw_abs[i] - map_rot), noise))


def _heading_nodes(mw: WalkSet, walks: np.ndarray, cfg: OptimizeConfig) -> np.ndarray:
    """The nodes of ``walks`` that get a compass heading prior (every HEADING_PRIOR_EVERY_N-th with a yaw)."""
    if not cfg.compass.use:
        return np.zeros(0, np.int64)
    idx = [np.arange(mw.starts[w], mw.ends[w], HEADING_PRIOR_EVERY_N) for w in np.flatnonzero(walks)]
    nodes = np.concatenate(idx) if idx else np.zeros(0, np.int64)
    return nodes[np.isfinite(mw.yaw_abs[nodes])].astype(np.int64)


def _map_compass_rotation(rot: RotationPriors, held: np.ndarray) -> float:
    """The map frame's rotation in the compass world: the circular mean over the held walks with a compass."""
    ok = held & rot.known
    return float(geometry.circular_mean(rot.theta[ok])) if ok.any() else 0.0


def _pairs_table(mw: WalkSet, s: _Solved, init_xyt: np.ndarray, cfg: OptimizeConfig) -> pd.DataFrame:
    """The vicinity pairs of the last solve, in optimize/pairs' columns (rss_dist NaN: scan links)."""
    ids = np.asarray(mw.walk_ids, dtype=object)
    w = mw.walk_of
    d0 = np.hypot(*(init_xyt[s.pk, :2] - init_xyt[s.pq, :2]).T)
    d1 = np.hypot(*(s.xyt[s.pk, :2] - s.xyt[s.pq, :2]).T)
    n = len(s.pk)
    return pd.DataFrame({
        "node_k": s.pk.astype(np.int64), "node_q": s.pq.astype(np.int64), "walk_k": ids[w[s.pk]],
        "walk_q": ids[w[s.pq]], "kind": np.full(n, "cross", dtype=object), "rss_dist": np.full(n, np.nan),
        "common": np.zeros(n, np.int64), "init_dist_m": d0, "final_dist_m": d1,
        "final_error": fuzzy_error(d1, cfg.wifi), "in_range": d1 < cfg.wifi.d_max,
        "injected": np.zeros(n, bool), "anisotropic": np.zeros(n, bool),
    })


def _walk_table(walks: WalkSet, prev: PreviousSolution, sp: _Split, st: GrowState, placed: np.ndarray,
                pairs: pd.DataFrame) -> pd.DataFrame:
    """optimize/walks: the previous rows of the old walks (re-placed ones updated), a row per new walk;
    ``added`` marks the new walks."""
    idx = {w: i for i, w in enumerate(walks.walk_ids)}
    n_pairs = (np.bincount(walks.walk_of[pairs["node_k"].to_numpy()], minlength=walks.n_walks)
               + np.bincount(walks.walk_of[pairs["node_q"].to_numpy()], minlength=walks.n_walks))
    rows = pd.DataFrame({
        "walk_id": walks.walk_ids, "n_poses": walks.ends - walks.starts, "linked": sp.held | placed,
        "component": st.comp.astype(np.int64), "reference": np.zeros(walks.n_walks, bool),
        "n_cross_pairs": n_pairs.astype(np.int64), "world_T_walk_x_m": st.T[:, 0], "world_T_walk_y_m": st.T[:, 1],
        "world_T_walk_theta_rad": st.T[:, 2], "heading_known": st.heading_used,
        "placement": np.where(placed, st.method, ""), "placement_round": st.rnd, "placement_inliers": st.n_inl,
        "anchored": np.zeros(walks.n_walks, bool), "scale": np.ones(walks.n_walks),
        "scale_fitted": np.zeros(walks.n_walks, bool), "added": ~sp.old,
    })
    redo = ~sp.held  # new walks and old walks the last run left out
    old_rows = prev.walks.assign(added=False)
    old_rows = old_rows[~old_rows["walk_id"].astype(str).map(lambda w: bool(redo[idx[w]]) if w in idx else False)]
    out = pd.concat([old_rows, rows[redo]], ignore_index=True)
    order = out["walk_id"].astype(str).map(idx).to_numpy()
    return out.iloc[np.argsort(order, kind="stable")].reset_index(drop=True)


def _stats(walks: WalkSet, prev: PreviousSolution, sp: _Split, placed: np.ndarray, s: _Solved, pairs: pd.DataFrame,
           new_ids: list[str], timing: dict, warnings: list[str]) -> dict:
    keep = walks.keep
    rep = prev.report
    n_new_placed = int((placed & ~sp.old).sum())
    return {
        "factors": {"odometry": int((walks.ends - walks.starts)[keep].clip(min=1).sum() - keep.sum()),
                    "odometry_in_solve": s.n_odometry, "vicinity": len(pairs), "vicinity_within": 0,
                    "vicinity_cross": len(pairs), "vicinity_in_final_solve": len(pairs), "prior": s.n_held,
                    "anchor": 0, "heading": s.n_heading},
        "walks": walks.n_walks, "poses": walks.n, "poses_solved": s.n_keyframes,
        "fingerprints": len(walks.fingerprints), "reference_walk": rep.get("reference_walk"),
        "frame": rep.get("frame", "reference walk"), "linked_walks": int((sp.held | placed).sum()),
        "iterations": s.iterations, "solves": len(s.starts), "cost_history": s.history,
        "final_cost": s.history[-1] if s.history else 0.0,
        "time_s": timing, "warnings": warnings,
        "incremental": {
            "new_walks": new_ids, "new_walks_placed": n_new_placed,
            "old_walks_held": int(sp.held.sum()),
            "old_walks_replaced": [walks.walk_ids[w] for w in np.flatnonzero(sp.old & placed)],
            "held_nodes_in_solve": s.n_held,
            "previous_linked_walks": rep.get("linked_walks"),
        },
    }
