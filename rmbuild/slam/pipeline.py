"""`rmbuild.slam.optimize`: align every walk into one frame from Wi-Fi alone and optimise the pose graph.

Pure and in-memory: takes a :class:`Dataset`, its :class:`Fingerprints` and an :class:`OptimizeConfig`,
returns an :class:`OptimizeResult`. Progress is reported through ``progress(phase, info)`` callbacks
(phases "pair_search", "init", "build", "solve"); nothing is printed.

Pipeline (``cfg.pipeline``):
- "robust": run-matched candidates → walks grown onto the map one by one (RANSAC fits to the placed
  walks, kNN rounds, component merging; ``init.method = "grow"``) and refined at walk level → joint pose
  graph (odometry, fuzzy vicinity factors on pairs consistent with the initialisation, magnetometer heading
  priors, gauge/anchors) on its keyframes (``slam/chains.py``: steps with only odometry eliminated, put
  back after each solve) solved by LM with METIS in an outer loop that keeps only the pairs currently
  within d_max → fold/shrink and odometry checks.
- "paper": seed 001 — every walk at the origin, median-window pairs, one LM solve.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
import pandas as pd

from rmbuild.config.optimize import OptimizeConfig, VicinityConfig
from rmbuild.errors import InputError
from rmbuild.slam.chains import add_chain_odometry, fill_chains, keyframe_mask
from rmbuild.slam.factors import (
    X,
    anisotropic_factor,
    anisotropic_noise,
    compose_se2,
    pair_offsets,
    poses_to_values,
    relative_se2,
    values_to_poses,
    vicinity_factor,
    vicinity_noise,
)
from rmbuild.slam.grow import grow, grow_knn, merge_components, orient_components, walked_lengths
from rmbuild.slam.init import InitResult, _covered_m, initialise, walk_abs_rotation, yaw_sigma
from rmbuild.slam.pairs import RowMeta, median_window_pairs, run_matched_candidates, window_median
from rmbuild.slam.rss import RssMatrix
from rmbuild.slam.scale import scaled_raw, update_scales
from rmbuild.types import Dataset, Fingerprints

log = logging.getLogger(__name__)
Progress = Callable[[str, dict], None] | None

_TRACE: list | None = None  # diagnostics hook: set to a list to receive the grow placement trace

POSE_OUT_COLUMNS = ["walk_id", "step", "t_s", "x_m", "y_m", "heading_rad"]


@dataclass
class OptimizeResult:
    """What :func:`optimize` returns.

    ``poses`` / ``initial_poses``: walk_id, step, t_s, x_m, y_m, heading_rad in the common frame (the
    reference walk's own frame, or the building frame with anchors), rows as ``dataset.poses``.
    ``pairs``: the vicinity factors of the final solve: node_k, node_q, walk_k, walk_q, kind, rss_dist,
    common, init_dist_m, final_dist_m, final_error (eq. 10 e), in_range (d < d_max at the end), injected,
    anisotropic (an along/across factor, VicinityConfig.across_ratio).
    ``candidates``: every pair the search produced (before verification), with ``used`` and ``injected``.
    ``walks``: per walk: walk_id, n_poses, linked, component, reference, n_cross_pairs, shared_path_m,
    n_partner_walks, world_T_walk_x_m / _y_m / _theta_rad, extent_ratio, confidence (0-1), heading_known,
    placement (how the walk got its initial frame), scale, scale_fitted, anchored (placed by anchors).
    ``stats``: factor counts, costs, iterations, time_s per phase, cost_history, warnings, ... (JSON-able).
    """

    poses: pd.DataFrame
    initial_poses: pd.DataFrame
    pairs: pd.DataFrame
    candidates: pd.DataFrame
    walks: pd.DataFrame
    stats: dict
    cost_history: list[float] = field(default_factory=list)


def _is_parallel(rel: np.ndarray, vcfg: VicinityConfig) -> np.ndarray:
    """Relative headings (rad) within parallel_max_deg of parallel or antiparallel."""
    return np.abs(np.cos(rel)) >= np.cos(np.radians(vcfg.parallel_max_deg))


def _anisotropic_pairs(xyt: np.ndarray, k: np.ndarray, q: np.ndarray, walk_of: np.ndarray, iso_walk: np.ndarray,
                       vcfg: VicinityConfig, across: float):
    """(mask, θq - θk, noise): which pairs (k, q) get an anisotropic factor at poses xyt — (anti)parallel,
    neither node on an ``iso_walk`` walk, none when the across ratio is 1 —, their current relative
    heading and the shared noise model (None when no pair does)."""
    _, _, rel = pair_offsets(xyt, k, q)
    if across >= 1:
        return np.zeros(len(k), bool), rel, None
    par = _is_parallel(rel, vcfg) & ~(iso_walk[walk_of[k]] | iso_walk[walk_of[q]])
    return par, rel, (anisotropic_noise(vcfg, across) if par.any() else None)


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
            out[w] = np.degrees(np.median(np.abs(np.angle(np.exp(1j * (raw[s + 1:e, 2][moving] - motion))))))
    return out


def estimate_across_ratio(xyt: np.ndarray, k: np.ndarray, q: np.ndarray, vcfg: VicinityConfig) -> tuple[float, int]:
    """(ratio, n): RMS across / RMS along of the offsets of the (anti)parallel pairs among (k, q) that are
    within d_max at poses xyt, clamped to [across_ratio_min, 1]; 1 when fewer than across_min_pairs."""
    along, acr, rel = pair_offsets(xyt, k, q)
    m = _is_parallel(rel, vcfg) & (np.hypot(along, acr) < vcfg.d_max)
    n = int(m.sum())
    if n < vcfg.across_min_pairs:
        return 1.0, n
    ratio = math.sqrt(float(np.mean(acr[m] ** 2)) / max(float(np.mean(along[m] ** 2)), 1e-12))
    return float(np.clip(ratio, vcfg.across_ratio_min, 1.0)), n


# ----------------------------------------------------------------------------------------------- checks
def _check_inputs(dataset: Dataset, fp: Fingerprints, cfg: OptimizeConfig) -> tuple[np.ndarray, list[str]]:
    """Validate; returns (keep mask over walks, warnings)."""
    poses = dataset.poses
    if poses is None or len(poses) == 0:
        raise InputError("no poses: the dataset has no walk poses to optimise")
    for col in ("walk_id", "step", "t_s", "x_m", "y_m", "heading_rad"):
        if col not in poses:
            raise InputError(f"poses table lacks column {col!r}")
    bad = poses[["t_s", "x_m", "y_m", "heading_rad"]].isna().any(axis=1).to_numpy()
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise InputError(f"NaN in poses (first at node {r}, walk {poses['walk_id'].iloc[r]!s}, "
                         f"step {poses['step'].iloc[r]}); fix or drop those steps")
    if fp is None or len(fp) == 0:
        raise InputError("no Wi-Fi fingerprints: no pose node has a Wi-Fi reading attached")
    if fp.node.min() < 0 or fp.node.max() >= len(poses):
        raise InputError("fingerprint node ids outside the poses table")
    warnings: list[str] = []
    sizes = poses.groupby("walk_id", sort=False).size()
    keep = np.ones(len(dataset.walks), bool)
    for i, wid in enumerate(dataset.walks["walk_id"]):
        nwk = int(sizes.get(wid, 0))
        if nwk < 2:
            if cfg.single_step_walks == "error":
                raise InputError(f"walk {wid!s} has {nwk} pose(s); a walk needs at least 2 steps")
            keep[i] = False
            warnings.append(f"walk {wid!s} has {nwk} pose(s): skipped (kept at its raw pose, unlinked)")
    return keep, warnings


def _anchor_nodes(anchors: pd.DataFrame, poses: pd.DataFrame, slices: dict[str, slice],
                  max_gap_s: float = 0.0) -> np.ndarray:
    """Node id of the pose nearest in time to each anchor; InputError when an anchor lies more than
    ``max_gap_s`` outside its walk's time span."""
    for col in ("walk_id", "t_s", "x_m", "y_m"):
        if col not in anchors:
            raise InputError(f"anchors table lacks column {col!r}")
    t = poses["t_s"].to_numpy(float)
    out = np.empty(len(anchors), np.int64)
    for i, (wid, ta) in enumerate(zip(anchors["walk_id"].astype(str), anchors["t_s"].to_numpy(float))):
        if wid not in slices:
            raise InputError(f"anchor {i}: unknown walk {wid!r}")
        s = slices[wid]
        tt = t[s]
        if not np.isfinite(ta) or not (tt[0] - max_gap_s <= ta <= tt[-1] + max_gap_s):
            raise InputError(f"anchor {i}: t_s={ta} is outside walk {wid}'s time span [{tt[0]}, {tt[-1]}] "
                             f"(by more than solve.anchor_max_gap_s = {max_gap_s:g} s)")
        out[i] = s.start + int(np.argmin(np.abs(tt - ta)))
    return out


# ----------------------------------------------------------------------------------------------- helpers
def _poses_df(dataset: Dataset, xyt: np.ndarray) -> pd.DataFrame:
    p = dataset.poses
    return pd.DataFrame({
        "walk_id": p["walk_id"].to_numpy(), "step": p["step"].to_numpy(), "t_s": p["t_s"].to_numpy(float),
        "x_m": xyt[:, 0], "y_m": xyt[:, 1], "heading_rad": xyt[:, 2],
    })


def _apply_frames(raw: np.ndarray, starts, ends, T: np.ndarray) -> np.ndarray:
    out = raw.copy()
    for w, (s, e) in enumerate(zip(starts, ends)):
        out[s:e] = compose_se2(T[w], raw[s:e])
    return out


def _extent(xy: np.ndarray) -> float:
    """RMS distance (m) of positions from their centroid."""
    return float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1)))) if len(xy) else 0.0


def _inject_false_pairs(cand: pd.DataFrame, frac: float, n_nodes: int, walk: np.ndarray,
                        fp_nodes: np.ndarray, seed: int) -> pd.DataFrame:
    """Test hook: replace a fraction of candidate pairs by random cross-walk pairs of scanned nodes."""
    rng = np.random.default_rng(seed + 7919)
    n_bad = int(round(frac * len(cand)))
    if n_bad == 0:
        cand["injected"] = False
        return cand
    drop = rng.choice(len(cand), n_bad, replace=False)
    keep = cand.drop(index=cand.index[drop]).copy()
    keep["injected"] = False
    a = rng.choice(fp_nodes, 4 * n_bad)
    b = rng.choice(fp_nodes, 4 * n_bad)
    ok = walk[a] != walk[b]
    a, b = a[ok][:n_bad], b[ok][:n_bad]
    fake = pd.DataFrame({"node_k": np.minimum(a, b), "node_q": np.maximum(a, b), "rss_dist": np.nan,
                         "common": 0, "kind": "cross", "injected": True})
    return pd.concat([keep, fake], ignore_index=True)


# ----------------------------------------------------------------------------------------------- solve
def _levenberg_marquardt(graph, values, cfg: OptimizeConfig, history: list, progress: Progress, outer: int,
                         ordering: str):
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.solve.max_iterations)
    params.setRelativeErrorTol(cfg.solve.relative_error_tol)
    params.setAbsoluteErrorTol(cfg.solve.absolute_error_tol)
    params.setOrderingType(ordering)
    params.setlambdaInitial(cfg.solve.lm_lambda_initial)
    params.setlambdaFactor(cfg.solve.lm_lambda_factor)
    params.setUseFixedLambdaFactor(cfg.solve.lm_fixed_lambda_factor)
    params.setDiagonalDamping(cfg.solve.lm_diagonal_damping)

    def hook(it, before, after):
        history.append(float(after))
        if progress:
            progress("solve", {"outer": outer, "iteration": int(it), "cost_before": float(before),
                               "cost_after": float(after), "max_iterations": cfg.solve.max_iterations})

    params.iterationHook = hook
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    return result, int(opt.iterations())


def optimize(
    dataset: Dataset,
    fingerprints: Fingerprints,
    cfg: OptimizeConfig,
    anchors: pd.DataFrame | None = None,
    progress: Progress = None,
) -> OptimizeResult:
    """Align all walks of ``dataset`` into one frame and optimise the pose graph (see module docstring).

    Raises :class:`InputError` for no poses, no fingerprints, NaN in poses, a single-step walk (when
    ``cfg.single_step_walks == "error"``) and anchors outside their walk's time span or of unknown walks.
    Walks with no verified link to the reference walk are reported (``walks.linked``, warnings).
    """
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    keep_walk, warnings = _check_inputs(dataset, fingerprints, cfg)
    poses = dataset.poses
    n = len(poses)
    walk_ids = [str(w) for w in dataset.walks["walk_id"]]
    slices = dataset.walk_slices()
    slices = {str(k): v for k, v in slices.items()}
    n_walks = len(walk_ids)
    starts = np.array([slices[w].start if w in slices else 0 for w in walk_ids])
    ends = np.array([slices[w].stop if w in slices else 0 for w in walk_ids])
    walk_of = dataset.walk_index()
    raw = poses[["x_m", "y_m", "heading_rad"]].to_numpy(float)
    step_len = np.r_[0.0, np.hypot(np.diff(raw[:, 0]), np.diff(raw[:, 1]))]
    step_len[starts[starts < n]] = 0.0
    path = np.cumsum(step_len)
    path -= np.repeat(path[starts], ends - starts)  # per-walk walked distance
    paper = cfg.pipeline == "paper"
    active = keep_walk[walk_of]

    # ------------------------------------------------------------------ pair search
    t0 = time.perf_counter()
    fp = fingerprints.subset(active[fingerprints.node])
    rm = RssMatrix.from_fingerprints(fp, cfg.pairs.fill_dbm)
    meta = RowMeta(fp.node, walk_of[fp.node], poses["step"].to_numpy()[fp.node],
                   poses["t_s"].to_numpy(float)[fp.node], path[fp.node])
    if paper:
        cand, _ = median_window_pairs(rm, meta, cfg.pairs, progress)
    else:
        cand = run_matched_candidates(rm, meta, cfg.pairs, progress)
    cand["node_k"] = fp.node[cand["row_k"].to_numpy()]
    cand["node_q"] = fp.node[cand["row_q"].to_numpy()]
    cand = cand.drop(columns=["row_k", "row_q"])
    cand = _inject_false_pairs(cand, cfg.inject_false_pairs, n, walk_of, fp.node, cfg.init.seed)
    cand = cand.reset_index(drop=True)
    timing["pair_search"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ initialisation
    t0 = time.perf_counter()
    abs_rot, abs_known, abs_sig = walk_abs_rotation(poses, starts, ends, cfg.init)
    abs_known &= keep_walk
    ref_idx = None
    if cfg.reference_walk:
        if cfg.reference_walk not in walk_ids:
            raise InputError(f"reference_walk {cfg.reference_walk!r} is not a walk of this dataset")
        ref_idx = walk_ids.index(cfg.reference_walk)
    nk_all, nq_all = cand["node_k"].to_numpy(), cand["node_q"].to_numpy()
    cross = walk_of[nk_all] != walk_of[nq_all]
    if cfg.init.method == "grow":
        init = _grow_init(raw, path, walk_of, n_walks, cand[cross], abs_rot, abs_known, abs_sig, cfg, ref_idx,
                          keep_walk, rm, fp.node, meta)
    elif cfg.init.method == "ransac":
        init = initialise(raw, path, walk_of, n_walks, cand[cross].reset_index(drop=True), abs_rot, abs_known,
                          abs_sig, cfg.init, ref_idx)
    else:
        init = _origin_init(cand[cross], walk_of, n_walks, ref_idx)
    if init.links is not None and len(init.links[0]):
        # scan links that placed walks on the map (kNN evidence) join the candidate pool
        lk, lq = init.links
        extra = pd.DataFrame({"node_k": np.minimum(lk, lq), "node_q": np.maximum(lk, lq), "rss_dist": np.nan,
                              "common": 0, "kind": "cross", "injected": False})
        cand = pd.concat([cand, extra], ignore_index=True).drop_duplicates(["node_k", "node_q"])
        cand = cand.reset_index(drop=True)
        nk_all, nq_all = cand["node_k"].to_numpy(), cand["node_q"].to_numpy()
        cross = walk_of[nk_all] != walk_of[nq_all]
    T = init.world_T_walk.copy()
    if progress:
        progress("init", {"linked": int(init.linked.sum()), "walks": n_walks})

    anchor_nodes = np.zeros(0, np.int64)
    if anchors is not None and len(anchors):
        anchor_nodes = _anchor_nodes(anchors, poses, slices, cfg.solve.anchor_max_gap_s)
    init_xyt = _apply_frames(raw, starts, ends, T)
    gauge_full, gauge_rot_only, anchored = _place_with_anchors(init_xyt, anchors, anchor_nodes, walk_of, init, T)
    anchored &= keep_walk
    init_xyt = _apply_frames(raw, starts, ends, T)
    timing["init"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ vicinity pairs to use
    t0 = time.perf_counter()
    comp_of_node = init.component[walk_of]
    same_comp = comp_of_node[nk_all] == comp_of_node[nq_all]
    d_init = np.hypot(*(init_xyt[nk_all, :2] - init_xyt[nq_all, :2]).T)
    if paper:
        pool = np.ones(len(cand), bool)
        first = pool.copy()
    else:
        # pool: cross pairs inside one linked component (re-admitted by the outer loop when the solve
        # brings them within d_max) and within-walk pairs consistent with the walk's own PDR geometry
        pool = cross & same_comp
        gate0 = cfg.init.grow_gate_m if cfg.init.method == "grow" else cfg.init.ransac_gate_m
        first = pool & (d_init < gate0)
        if cfg.pairs.within_walk:
            d_raw = np.hypot(*(raw[nk_all, :2] - raw[nq_all, :2]).T)
            gate = cfg.pairs.within_gate_m + cfg.pairs.within_drift_per_m * np.abs(path[nk_all] - path[nq_all])
            ok_within = ~cross & (d_raw < gate)
            pool |= ok_within
            first |= ok_within
    cand["init_dist_m"] = d_init
    pool_idx = np.flatnonzero(pool)
    # graduated kernel (solve.gnc_factors): pairs touching a walk long enough to drift get a widened band
    # in the first solves; every other pair keeps d_max throughout
    gnc = () if paper else tuple(cfg.solve.gnc_factors)
    walk_len = walked_lengths(path, walk_of, n_walks)
    widen = (walk_len[walk_of[nk_all]] >= cfg.solve.gnc_min_walk_m) | (walk_len[walk_of[nq_all]] >=
                                                                          cfg.solve.gnc_min_walk_m)
    vc = cfg.vicinity

    def band(f: float) -> np.ndarray:
        """Per pool pair: the band's outer edge (m) in a solve widened by f."""
        return vc.d_min + np.where(widen[pool_idx], f, 1.0) * (vc.d_max - vc.d_min)

    if gnc:
        first[pool_idx] |= pool[pool_idx] & (d_init[pool_idx] < band(gnc[0]))
    pk, pq = nk_all[pool_idx], nq_all[pool_idx]

    # ------------------------------------------------------------------ static factors
    static = gtsam.NonlinearFactorGraph()
    # odometry factors are built per solve from the scaled PDR (per-walk step-length scale, all 1 unless
    # cfg.solve.estimate_scale)
    scale = np.ones(n_walks)
    raw_s = raw
    # nodes that carry a factor other than odometry: the keyframes of the chain reduction
    required = np.zeros(n, bool)
    required[pk] = required[pq] = True
    n_prior = 0
    ref = init.reference
    every = cfg.solve.heading_prior_every_n
    heading_priors = (not paper and every > 0 and bool(init.heading_known[init.reference]))
    for r in gauge_full:
        s = starts[r]
        if heading_priors and init.component[r] == 0 and init.heading_known[r]:
            # the magnetometer priors fix the map's rotation; pin only the reference position
            static.add(gtsam.PoseTranslationPrior2D(X(s), gtsam.Pose2(*init_xyt[s]),
                                                    gtsam.noiseModel.Isotropic.Sigma(2, cfg.solve.gauge_sigma_m)))
            n_prior += 1
            continue
        static.add(gtsam.PriorFactorPose2(X(s), gtsam.Pose2(*init_xyt[s]), gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.solve.gauge_sigma_m, cfg.solve.gauge_sigma_m, cfg.solve.gauge_sigma_rad]))))
        n_prior += 1
    for r in gauge_rot_only:
        s = starts[r]
        static.add(gtsam.PoseRotationPrior2D(X(s), gtsam.Pose2(*init_xyt[s]),
                                             gtsam.noiseModel.Isotropic.Sigma(1, cfg.solve.gauge_sigma_rad)))
        n_prior += 1
    for w in np.flatnonzero(~keep_walk):  # skipped walks: pinned where they are
        required[starts[w]:ends[w]] = True
        for i in range(starts[w], ends[w]):
            static.add(gtsam.PriorFactorPose2(X(i), gtsam.Pose2(*init_xyt[i]),
                                              gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
            n_prior += 1
    n_anchor = 0
    required[anchor_nodes] = True
    for i, node in enumerate(anchor_nodes):
        static.add(gtsam.PoseTranslationPrior2D(
            X(node), gtsam.Pose2(float(anchors["x_m"].iloc[i]), float(anchors["y_m"].iloc[i]), 0.0),
            gtsam.noiseModel.Isotropic.Sigma(2, cfg.solve.anchor_sigma_m)))
        n_anchor += 1
    n_heading = 0
    if heading_priors:
        yaw = poses["yaw_abs_rad"].to_numpy(float)
        ysig = yaw_sigma(poses, cfg.init) * cfg.solve.heading_prior_sigma_scale
        world_rot = init.abs_rot[ref]
        if len(anchor_nodes):
            world_rot = init.abs_rot[ref] - _frame_rotation_from(T, init, ref)
        for w in np.flatnonzero(init.heading_known):
            idx = np.arange(starts[w], ends[w], every)
            idx = idx[np.isfinite(yaw[idx])]
            if not len(idx):
                continue
            # prior heading of pose i in the common frame: its yaw_abs minus the reference frame's rotation
            required[idx] = True
            for i in idx:
                noise = gtsam.noiseModel.Isotropic.Sigma(1, float(ysig[i]))
                if cfg.solve.heading_prior_cauchy_k > 0:
                    noise = gtsam.noiseModel.Robust.Create(
                        gtsam.noiseModel.mEstimator.Cauchy.Create(cfg.solve.heading_prior_cauchy_k), noise)
                static.add(gtsam.PoseRotationPrior2D(X(int(i)), gtsam.Pose2(0, 0, yaw[i] - world_rot), noise))
                n_heading += 1
    # odometry: between consecutive steps, or between consecutive keyframes (solve.chain_reduction)
    required[starts[keep_walk]] = True  # gauges sit on walk starts
    if cfg.solve.chain_reduction:
        kf = keyframe_mask(n, starts[keep_walk], ends[keep_walk], required, cfg.solve.keyframe_max_gap)
    else:
        kf = np.ones(n, bool)
    kf_idx = np.flatnonzero(kf)
    odo_graph = gtsam.NonlinearFactorGraph()
    n_odo = add_chain_odometry(odo_graph, raw_s, starts[keep_walk], ends[keep_walk], kf, cfg.odometry)

    def to_values(xyt: np.ndarray) -> gtsam.Values:
        return poses_to_values(xyt[kf_idx], nodes=kf_idx)

    def from_values(v: gtsam.Values) -> np.ndarray:
        full = np.zeros((n, 3))
        full[kf_idx] = values_to_poses(v, nodes=kf_idx)
        return fill_chains(full, raw_s, starts[keep_walk], ends[keep_walk], kf)
    timing["build"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ joint solve, outer loop
    t0 = time.perf_counter()
    vnoise = vicinity_noise(cfg.vicinity) if cfg.vicinity.kernel != "custom_factor" else None
    # anisotropic pairs (VicinityConfig.across_ratio): a fixed ratio, or 1 (isotropic) until it is
    # estimated after the first solve; across_used: the ratio of the latest solve
    aniso_ok = not paper and vc.kernel == "range_tls" and vc.d_min == 0
    # the along/across axes are the poses' headings: they must be the walking direction. A walk whose
    # headings are not (a device yaw, say) keeps isotropic pairs; when no walk's are, all pairs are
    heading_off = np.zeros(n_walks, bool)
    if aniso_ok and vc.across_ratio < 1:
        dev = heading_motion_deviation_deg(raw, starts, ends)
        heading_off = keep_walk & (dev > vc.heading_motion_max_deg)
        if heading_off.any() and heading_off.sum() == keep_walk.sum():
            aniso_ok = False
            warnings.append(f"pose headings differ from the walking direction (median {np.median(dev[keep_walk]):.0f} "
                            f"deg > {vc.heading_motion_max_deg:g}): anisotropic pairs off, every pair isotropic")
        elif heading_off.any():
            names = ", ".join(walk_ids[w] for w in np.flatnonzero(heading_off)[:5])
            warnings.append(f"{int(heading_off.sum())} walk(s) whose pose headings differ from the walking "
                            f"direction (median > {vc.heading_motion_max_deg:g} deg: {names}"
                            f"{', ...' if heading_off.sum() > 5 else ''}) keep isotropic pairs")
    across = across_used = vc.across_ratio if aniso_ok and vc.across_ratio > 0 else 1.0
    across_auto = aniso_ok and vc.across_ratio == 0
    # walks whose step-length scale is still moving (by > scale_extend_move in the last round, while the
    # rounds go on): their pairs stay isotropic, since anisotropic pairs hold a walk's stretch in place
    # and its scale would stall short of the truth
    settling = np.zeros(n_walks, bool)
    settling_used = settling.copy()
    across_n = 0
    values = to_values(init_xyt)
    # gtsam 4.3's METIS ordering corrupts memory on graphs with isolated variables (a skipped one-pose
    # walk) and gains nothing on small graphs: COLAMD there
    ordering = cfg.solve.ordering
    if (~keep_walk).any() or len(kf_idx) < cfg.solve.metis_min_poses:
        ordering = "COLAMD"
    cost_history: list[float] = []
    current = init_xyt
    active_pairs = first[pool_idx]
    iterations = 0
    initial_cost = None
    n_vic_used = 0
    outer_done = 0
    est_scale = cfg.solve.estimate_scale and not paper
    # solves: the widened ones, the outer loop's and one per scale round; a scale round beyond
    # scale_iterations (while the last one still moved some s_w by > scale_extend_move) adds one
    n_solves = len(gnc) + cfg.solve.outer_iterations + (cfg.solve.scale_iterations if est_scale else 0)
    scale_rounds = 0
    scale_last_move = 0.0
    scale_fitted = np.zeros(n_walks, bool)
    outer = 0
    while outer < n_solves:
        # graduated kernel: widened band (same slope) for the first len(gnc) solves, long-walk pairs only
        f_band = gnc[outer] if outer < len(gnc) else 1.0
        wide_cfg = replace(vc, d_max=vc.d_min + f_band * (vc.d_max - vc.d_min), e_max=f_band * vc.e_max)
        wide_noise = vnoise if f_band == 1.0 or vnoise is None else vicinity_noise(wide_cfg)
        graph = gtsam.NonlinearFactorGraph(odo_graph)
        graph.push_back(static)
        sel = np.flatnonzero(active_pairs)
        wide_sel = widen[pool_idx[sel]] & (f_band != 1.0)
        across_used, settling_used = across, settling.copy()
        par, rel, anoise = _anisotropic_pairs(current, pk[sel], pq[sel], walk_of, settling | heading_off, vc, across)
        for k, q, wd, pa, rt in zip(pk[sel].tolist(), pq[sel].tolist(), wide_sel.tolist(), par.tolist(),
                                    rel.tolist()):
            if pa and not wd:
                graph.add(anisotropic_factor(k, q, rt, anoise))
            else:
                graph.add(vicinity_factor(k, q, wide_cfg, wide_noise) if wd else vicinity_factor(k, q, vc, vnoise))
        if initial_cost is None:
            initial_cost = float(graph.error(values))
            cost_history.append(initial_cost)
        values, it = _levenberg_marquardt(graph, values, cfg, cost_history, progress, outer, ordering)
        iterations += it
        outer_done += 1
        n_vic_used = len(sel)
        current = from_values(values)
        d_now = np.hypot(*(current[pk, :2] - current[pq, :2]).T)
        f_next = gnc[outer + 1] if outer + 1 < len(gnc) else 1.0
        new_active = d_now < band(f_next)
        last = outer == n_solves - 1
        in_gnc = outer < len(gnc)  # a widened solve is always followed by the next one
        scale_moved = False
        extend = (est_scale and cfg.solve.scale_iterations <= scale_rounds < cfg.solve.scale_max_iterations
                  and scale_last_move > cfg.solve.scale_extend_move)
        if est_scale and ((not last and scale_rounds < cfg.solve.scale_iterations) or extend):
            eligible = keep_walk & init.linked
            sgate = cfg.solve.scale_pair_gate_m or cfg.vicinity.d_max
            near = d_now < sgate
            new_scale, fitted = update_scales(current, raw, starts, ends, scale, eligible, pk[near],
                                              pq[near], walk_of, cfg.solve,
                                              cfg.solve.scale_normalize and not len(anchor_nodes))
            scale_fitted |= fitted
            scale_rounds += 1
            scale_last_move = float(np.max(np.abs(new_scale - scale), initial=0.0))
            settling = np.abs(new_scale - scale) > cfg.solve.scale_extend_move
            scale_moved = scale_last_move > cfg.solve.scale_tol
            if extend and scale_moved:
                n_solves += 1  # the rescaled graph is solved once more
                last = False
            log.debug("scale round %d: %s", scale_rounds, np.round(new_scale, 3).tolist())
            if scale_moved:
                # start the next solve from the current poses stretched about each walk's centroid
                moved = current.copy()
                for w in np.flatnonzero(new_scale != scale):
                    a, b = starts[w], ends[w]
                    c = current[a:b, :2].mean(axis=0)
                    moved[a:b, :2] = c + (new_scale[w] / scale[w]) * (current[a:b, :2] - c)
                scale = new_scale
                raw_s = scaled_raw(raw, starts, ends, scale)
                odo_graph = gtsam.NonlinearFactorGraph()
                add_chain_odometry(odo_graph, raw_s, starts[keep_walk], ends[keep_walk], kf, cfg.odometry)
                values = to_values(moved)
        # the across ratio is re-estimated after every solve
        across_moved = False
        scale_busy = est_scale and (scale_rounds < cfg.solve.scale_iterations or (
            scale_rounds < cfg.solve.scale_max_iterations and scale_last_move > cfg.solve.scale_extend_move))
        if not scale_busy:
            settling[:] = False
        if across_auto:
            stat = new_active & ~(heading_off[walk_of[pk]] | heading_off[walk_of[pq]])
            across_new, across_n = estimate_across_ratio(current, pk[stat], pq[stat], vc)
            across_moved = abs(across_new - across) > vc.across_tol
            if across_moved and last and across == 1.0 and across_new < 1.0:
                n_solves += 1  # the first anisotropic solve comes after the last isotropic one
                last = False
            across = across_new
            log.debug("across ratio %.3f from %d parallel pairs", across, across_n)
        if paper or last or (np.array_equal(new_active, active_pairs) and not scale_moved and not in_gnc
                                  and not across_moved):
            break
        active_pairs = new_active
        outer += 1
    # the last solve's pairs are "the vicinity factors finally used"
    use = np.zeros(len(cand), bool)
    use[pool_idx[active_pairs]] = True
    cand["used"] = use
    pk, pq = nk_all[use], nq_all[use]
    final_graph = gtsam.NonlinearFactorGraph(odo_graph)
    final_graph.push_back(static)
    par, rel, anoise = _anisotropic_pairs(current, pk, pq, walk_of, settling_used | heading_off, vc, across_used)
    for k, q, pa, rt in zip(pk.tolist(), pq.tolist(), par.tolist(), rel.tolist()):
        final_graph.add(anisotropic_factor(k, q, rt, anoise) if pa else vicinity_factor(k, q, vc, vnoise))
    final_cost = float(final_graph.error(values))
    init_cost_all = float(final_graph.error(to_values(init_xyt)))
    timing["solve"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ checks
    t0 = time.perf_counter()
    sig = np.array([cfg.odometry.sigma_x_m, cfg.odometry.sigma_y_m, 1 / math.sqrt(cfg.odometry.mu)])
    odo_res = []
    extent_ratio = np.full(n_walks, np.nan)
    for w in np.flatnonzero(keep_walk):
        s, e = starts[w], ends[w]
        du = relative_se2(current[s:e]) - relative_se2(raw_s[s:e])
        du[:, 2] = np.angle(np.exp(1j * du[:, 2]))
        odo_res.append(du / sig)
        er = _extent(raw_s[s:e, :2])
        extent_ratio[w] = _extent(current[s:e, :2]) / er if er > 0 else 1.0
    odo_rms = float(np.sqrt(np.mean(np.concatenate(odo_res) ** 2))) if odo_res else 0.0
    rejected = False
    if odo_rms > cfg.solve.max_odometry_rms_sigma:
        warnings.append(f"solution rejected: odometry residual RMS {odo_rms:.1f} sigma > "
                        f"{cfg.solve.max_odometry_rms_sigma}; initial poses returned")
        rejected = True
    shrunk = np.flatnonzero(extent_ratio < cfg.solve.min_extent_ratio)
    for w in shrunk:
        warnings.append(f"walk {walk_ids[w]} shrank to {extent_ratio[w]:.2f} of its raw PDR extent (folded?)")
    if np.nanmedian(extent_ratio) < cfg.solve.min_extent_ratio and not rejected:
        warnings.append("solution rejected: the map shrank (median walk extent ratio "
                        f"{np.nanmedian(extent_ratio):.2f}); initial poses returned")
        rejected = True
    if rejected:
        current = init_xyt.copy()
    timing["checks"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ report tables
    final_d = np.hypot(*(current[pk, :2] - current[pq, :2]).T)
    e_fin = cfg.vicinity.e_max * np.clip((final_d - cfg.vicinity.d_min) / (cfg.vicinity.d_max - cfg.vicinity.d_min),
                                         0, 1)
    used = cand[use].reset_index(drop=True)
    pairs = pd.DataFrame({
        "node_k": pk, "node_q": pq,
        "walk_k": np.asarray(walk_ids, dtype=object)[walk_of[pk]],
        "walk_q": np.asarray(walk_ids, dtype=object)[walk_of[pq]],
        "kind": used["kind"].to_numpy(), "rss_dist": used["rss_dist"].to_numpy(),
        "common": used["common"].to_numpy(), "init_dist_m": d_init[use], "final_dist_m": final_d,
        "final_error": e_fin, "in_range": final_d < cfg.vicinity.d_max,
        "injected": used["injected"].to_numpy(), "anisotropic": par,
    })
    walks_df = _walk_table(walk_ids, starts, ends, keep_walk, init, T, pairs, walk_of, path, extent_ratio,
                           anchored, cfg)
    walks_df["scale"] = scale
    walks_df["scale_fitted"] = scale_fitted
    unlinked = np.flatnonzero(keep_walk & ~walks_df["linked"].to_numpy() & ~anchored)
    by_anchor = int((anchored & ~walks_df["linked"].to_numpy()).sum())
    if len(unlinked):
        # one line however many walks (a 100-walk floor can leave dozens): the full list is optimize/walks
        names = ", ".join(walk_ids[w] for w in unlinked[:5]) + (", ..." if len(unlinked) > 5 else "")
        also = f"; {by_anchor} more placed by anchors alone" if by_anchor else ""
        warnings.append(f"{len(unlinked)} of {int(keep_walk.sum())} walk(s) not linked to the reference walk "
                        f"{walk_ids[ref]} ({names}): their placement is not constrained by Wi-Fi{also} "
                        "(optimize/walks.parquet: linked, anchored, component)")
    if n_walks > 1 and walks_df["linked"].sum() <= 1:
        warnings.append("all walks are disconnected: no verified cross-walk Wi-Fi links")
    for wmsg in warnings:
        log.warning(wmsg)
    timing["total"] = time.perf_counter() - t_all
    n_cross = int((pairs["kind"] == "cross").sum())
    stats = {
        "pipeline": cfg.pipeline,
        "factors": {"odometry": int((ends - starts)[keep_walk].clip(min=1).sum() - keep_walk.sum()),
                    "odometry_in_solve": n_odo, "vicinity": int(len(pk)), "vicinity_within": int(len(pk) - n_cross),
                    "vicinity_cross": n_cross, "vicinity_in_final_solve": int(n_vic_used), "prior": n_prior,
                    "anchor": n_anchor, "heading": n_heading},
        "walks": n_walks, "poses": n, "poses_solved": int(len(kf_idx)), "fingerprints": int(len(fp)),
        "candidates": int(len(cand)), "candidates_cross": int(cross.sum()),
        "walk_pairs_tested": len(init.fits), "walk_pairs_accepted": int(sum(f.accepted for f in init.fits)),
        "reference_walk": walk_ids[ref], "linked_walks": int(walks_df["linked"].sum()),
        "anchored_only_walks": by_anchor,
        "components": int(init.component.max() + 1) if n_walks else 0,
        "initial_cost": init_cost_all, "final_cost": final_cost, "first_solve_initial_cost": initial_cost,
        "iterations": iterations, "outer_iterations": outer_done, "ordering": ordering, "cost_history": cost_history,
        "odometry_residual_rms_sigma": odo_rms, "median_extent_ratio": float(np.nanmedian(extent_ratio)),
        "rejected": rejected, "time_s": timing, "warnings": warnings,
        # the anisotropic pairs of the final solve and their across/along sigma ratio (1 = isotropic)
        "vicinity": {"across_ratio": float(across_used), "estimated": bool(across_auto),
                     "estimated_from_pairs": across_n, "anisotropic_pairs": int(par.sum())},
        "scale": {"estimated": bool(est_scale), "rounds": scale_rounds, "fitted_walks": int(scale_fitted.sum()),
                  # over the fitted walks (the others keep 1)
                  "min": float(scale[scale_fitted].min()) if scale_fitted.any() else 1.0,
                  "max": float(scale[scale_fitted].max()) if scale_fitted.any() else 1.0},
    }
    return OptimizeResult(
        poses=_poses_df(dataset, current), initial_poses=_poses_df(dataset, init_xyt), pairs=pairs,
        candidates=cand, walks=walks_df, stats=stats, cost_history=cost_history,
    )


def _frame_rotation_from(T: np.ndarray, init: InitResult, ref: int) -> float:
    """Rotation (rad) applied to the reference frame by anchor placement (T[ref] after vs before)."""
    return float(T[ref, 2] - init.world_T_walk[ref, 2])


def _grow_init(raw, path, walk_of, n_walks, cand_cross: pd.DataFrame, abs_rot, abs_known, abs_sig,
               cfg: OptimizeConfig, ref_idx: int | None, keep_walk: np.ndarray, rm: RssMatrix,
               row_node: np.ndarray, meta: RowMeta) -> InitResult:
    """Walk frames by incremental walk-to-map placement (rmbuild/slam/grow.py).

    Without a user-given reference the walk with the most cross-walk candidates seeds the map. When that
    walk's component ends up smaller (in walked path) than another one — its candidates were look-alikes
    of a small corner, say — growth is run again from the best-connected walk of the largest component
    and the larger of the two reference components is kept (``init.reselect_reference``).
    """
    nk, nq = cand_cross["node_k"].to_numpy(), cand_cross["node_q"].to_numpy()
    cnt = np.bincount(np.r_[walk_of[nk], walk_of[nq]], minlength=n_walks).astype(float)
    args = (raw, path, walk_of, n_walks, cand_cross, abs_rot, abs_known, abs_sig, cfg, keep_walk, rm, row_node,
            meta, cnt)
    if ref_idx is not None:
        return _grow_from(ref_idx, *args)
    res = _grow_from(int(np.argmax(np.where(keep_walk, cnt, -1))), *args)
    if not cfg.init.reselect_reference:
        return res
    wlen = walked_lengths(path, walk_of, n_walks) * keep_walk
    size = np.bincount(res.component, weights=wlen)
    big = int(np.argmax(size))
    if big == 0 or size[big] <= size[0]:
        return res
    in_big = res.component == big
    alt = _grow_from(int(np.argmax(np.where(in_big & keep_walk, cnt, -1))), *args)
    alt_size = float(wlen[alt.component == 0].sum())
    log.info("reference walk reselected: its component had %.0f m of walks, another %.0f m; regrown: %.0f m",
             size[0], size[big], alt_size)
    return alt if alt_size > size[0] else res


def _grow_from(ref_idx: int, raw, path, walk_of, n_walks, cand_cross: pd.DataFrame, abs_rot, abs_known, abs_sig,
               cfg: OptimizeConfig, keep_walk: np.ndarray, rm: RssMatrix, row_node: np.ndarray, meta: RowMeta,
               cnt: np.ndarray) -> InitResult:
    """One growth (pairs, kNN rounds, merges) from the reference walk ``ref_idx``."""
    nk, nq = cand_cross["node_k"].to_numpy(), cand_cross["node_q"].to_numpy()
    known = abs_known & cfg.init.use_abs_heading
    links = None
    g = None
    edges = None
    if cfg.init.grow_pair_edges:
        pw = initialise(raw, path, walk_of, n_walks, cand_cross.reset_index(drop=True), abs_rot, abs_known, abs_sig,
                        cfg.init, ref_idx)
        edges = [(f.a, f.b, f.T) for f in pw.fits if f.accepted]
    if cfg.init.grow_evidence in ("pairs", "both"):
        g = grow(raw, path, walk_of, n_walks, nk, nq, abs_rot, known, abs_sig, cfg.init, ref_idx, keep_walk,
                 trace=_TRACE, edges=edges)
    if cfg.init.grow_evidence in ("knn", "both"):
        thr = window_median(rm, meta, cfg.pairs.L_window_steps)
        g, lk, lq = grow_knn(raw, path, walk_of, n_walks, rm, row_node, thr, abs_rot, known, abs_sig, cfg.init,
                             cfg.pairs.min_common_aps, ref_idx, keep_walk, cnt, trace=_TRACE, start=g)
        links = (lk, lq)
    if cfg.init.merge_components:
        # kNN links (when present) are within-component evidence; the candidate pairs carry the
        # between-component evidence a merge is fitted on. A merge grows the map, so the kNN rounds get
        # another go at the walks still left over, then merging again, until the map stops growing.
        for _ in range(cfg.init.merge_rounds):
            n_placed = int((g.component == 0).sum())
            g = merge_components(g, raw, path, walk_of, nk, nq, abs_rot, known, abs_sig, cfg.init, trace=_TRACE)
            if int((g.component == 0).sum()) == n_placed:
                break
            if links is not None:
                g, lk, lq = grow_knn(raw, path, walk_of, n_walks, rm, row_node, thr, abs_rot, known, abs_sig,
                                     cfg.init, cfg.pairs.min_common_aps, ref_idx, keep_walk, cnt, trace=_TRACE,
                                     start=g)
                links = (np.r_[links[0], lk], np.r_[links[1], lq])
    g = orient_components(g, abs_rot, known)
    res = InitResult(g.world_T_walk, g.component, g.component == 0, g.reference, [], g.heading_used & known,
                     abs_rot)
    res.grow = g
    res.links = links
    return res


def _origin_init(cand_cross: pd.DataFrame, walk_of: np.ndarray, n_walks: int, ref_idx: int | None) -> InitResult:
    """Paper: every walk at the origin; components from any cross-walk pair."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = walk_of[cand_cross["node_k"].to_numpy()]
    b = walk_of[cand_cross["node_q"].to_numpy()]
    A = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_walks, n_walks))
    _, comp = connected_components(A, directed=False)
    ref = int(ref_idx) if ref_idx is not None else int(np.argmax(np.bincount(np.r_[a, b], minlength=n_walks)))
    c = np.where(comp == comp[ref], -1, comp)
    _, comp = np.unique(c, return_inverse=True)
    return InitResult(np.zeros((n_walks, 3)), comp, comp == 0, ref, [], np.zeros(n_walks, bool),
                      np.zeros(n_walks))


def _place_with_anchors(init_xyt, anchors, anchor_nodes, walk_of, init: InitResult, T):
    """Move each component onto its anchors (SE(2) with >= 2 anchors more than 1 m apart, else translation)
    by updating T in place. Returns (walks needing a full gauge prior, walks needing a rotation prior,
    bool per walk: placed in the building frame by anchors — its component got an SE(2), or a translation
    and the walk has its own magnetometer rotation)."""
    from rmbuild.evaluate.trajectory import align_se2, rotation_angle_rad

    full, rot_only = [], []
    anchored = np.zeros(len(init.component), bool)
    n_comp = int(init.component.max()) + 1 if len(init.component) else 0
    th_ref = 0.0  # rotation the anchors gave the reference component (components are rotated in its frame)
    for c in range(n_comp):
        walks_c = np.flatnonzero(init.component == c)
        root = init.reference if c == 0 else int(walks_c[0])
        m = init.component[walk_of[anchor_nodes]] == c if len(anchor_nodes) else np.zeros(0, bool)
        if m.sum() == 0:
            full.append(root)
            continue
        src = init_xyt[anchor_nodes[m], :2]
        dst = anchors[["x_m", "y_m"]].to_numpy(float)[m]
        if m.sum() >= 2 and np.ptp(dst, axis=0).max() > 1.0:
            R, t = align_se2(src, dst)
            th = rotation_angle_rad(R)
            anchored[walks_c] = True
        else:
            # one anchor: the position only; the rotation is the reference component's (a further
            # component was turned to its magnetometer in the reference walk's frame)
            th = th_ref
            c_, s_ = np.cos(th), np.sin(th)
            t = (dst - src @ np.array([[c_, -s_], [s_, c_]]).T).mean(axis=0)
            rot_only.append(root)
            anchored[walks_c] = np.asarray(init.heading_known, bool)[walks_c]
        if c == 0:
            th_ref = th
        T[walks_c] = compose_se2(np.array([t[0], t[1], th]), T[walks_c])
    return full, rot_only, anchored


def _walk_table(walk_ids, starts, ends, keep, init: InitResult, T, pairs, walk_of, path, extent_ratio,
                anchored: np.ndarray, cfg: OptimizeConfig) -> pd.DataFrame:
    n_walks = len(walk_ids)
    n_cross = np.zeros(n_walks, np.int64)
    n_in = np.zeros(n_walks, np.int64)
    partners: list[set] = [set() for _ in range(n_walks)]
    cr = pairs[pairs["kind"] == "cross"]
    wk = walk_of[cr["node_k"].to_numpy()]
    wq = walk_of[cr["node_q"].to_numpy()]
    inr = cr["in_range"].to_numpy()
    for a, b, ok in zip(wk.tolist(), wq.tolist(), inr.tolist()):
        n_cross[a] += 1
        n_cross[b] += 1
        n_in[a] += ok
        n_in[b] += ok
        partners[a].add(b)
        partners[b].add(a)
    shared = np.zeros(n_walks)
    for w in range(n_walks):
        nodes = np.r_[cr["node_k"].to_numpy()[wk == w], cr["node_q"].to_numpy()[wq == w]]
        shared[w] = _covered_m(path[nodes]) if len(nodes) else 0.0
    linked = init.linked & keep
    frac_in = np.where(n_cross > 0, n_in / np.maximum(n_cross, 1), 0.0)
    conf = np.where(linked, np.clip(shared / (4 * cfg.init.min_shared_path_m), 0, 1) * frac_in, 0.0)
    conf[init.reference] = 1.0 if keep[init.reference] else 0.0
    return pd.DataFrame({
        "walk_id": walk_ids, "n_poses": ends - starts, "linked": linked,
        "component": init.component.astype(np.int64), "reference": np.arange(n_walks) == init.reference,
        "n_cross_pairs": n_cross, "n_partner_walks": [len(p) for p in partners], "shared_path_m": shared,
        "world_T_walk_x_m": T[:, 0], "world_T_walk_y_m": T[:, 1], "world_T_walk_theta_rad": T[:, 2],
        "heading_known": init.heading_known, "extent_ratio": extent_ratio, "confidence": conf,
        "placement": _placement(init, linked, anchored, n_walks), "anchored": anchored,
    })


def _placement(init: InitResult, linked: np.ndarray, anchored: np.ndarray, n_walks: int) -> np.ndarray:
    """How each walk got its initial frame: "reference", "translation" / "se2" (walk-to-map fit with the
    compass rotation / without), "pair" (a walk-pair RANSAC edge), "merge" (its component was fitted to the
    map as one body), "anchor" (not linked, placed by anchors), "" (neither, or an initialisation other
    than "grow")."""
    g = getattr(init, "grow", None)
    out = np.full(n_walks, "", dtype=object)
    if g is not None:
        out[:] = g.method
    out[init.reference] = "reference"
    out[~linked] = ""
    out[~linked & anchored] = "anchor"
    return out
