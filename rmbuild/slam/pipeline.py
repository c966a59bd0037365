"""`rmbuild.slam.optimize`: align every walk into one frame and optimise the pose graph.

Pure and in-memory: a :class:`Dataset`, its :class:`Fingerprints` and an :class:`OptimizeConfig` in, an
:class:`OptimizeResult` out. Progress goes to ``progress(phase, info)`` callbacks (phases "pair_search",
"init", "build", "solve"); nothing is printed. The steps (docs/optimize.md):

1. the walk set (:mod:`.problem`) and the evidence sources (:mod:`.evidence`): Wi-Fi, anchors, compass;
2. placement (:mod:`.placement`): every walk's initial frame from the sources' evidence; anchors then put
   the placed components into the building frame;
3. the joint solve (:mod:`.solve`): odometry, gauge and the sources' factors, as the schedule says;
4. checks against the dead reckoning (:mod:`.checks`) and the report tables (:mod:`.report`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from rmbuild.config.optimize import OptimizeConfig
from rmbuild.errors import InputError
from rmbuild.floorplan import FloorPlan
from rmbuild.slam import report
from rmbuild.slam.checks import check_solution
from rmbuild.slam.evidence import default_sources
from rmbuild.slam.evidence.base import StaticFactors
from rmbuild.slam.evidence.wifi import CandidatesHook, WifiSource
from rmbuild.slam.gauge import gauge_factors, gauge_nodes
from rmbuild.slam.held import HeldMap, Holding, hold
from rmbuild.slam.held import reference as held_reference
from rmbuild.slam.placement import Placement, gather, heldcheck, place
from rmbuild.slam.placement.grow import window_lengths
from rmbuild.slam.placement.rfcheck import refute
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.result import OptimizeResult
from rmbuild.slam.solve import SolveOutcome
from rmbuild.slam.solve import run as run_solves
from rmbuild.types import Dataset, Fingerprints, OptimizeState

log = logging.getLogger(__name__)
Progress = Callable[[str, dict], None] | None


def optimize(
    dataset: Dataset,
    fingerprints: Fingerprints,
    cfg: OptimizeConfig,
    anchors: pd.DataFrame | None = None,
    progress: Progress = None,
    candidates_hook: CandidatesHook | None = None,
    floorplan: FloorPlan | None = None,
    held: HeldMap | None = None,
) -> OptimizeResult:
    """Align all walks of ``dataset`` into one frame and optimise the pose graph (module docstring).

    ``anchors``: walk_id, t_s, x_m, y_m (known building-frame positions). ``floorplan``: the floor's
    walkable space; the map is then built in the plan's frame. ``candidates_hook``: a function
    applied to the Wi-Fi candidate pairs before placement (tests and benchmarks inject false pairs with
    :func:`tests.slam_venue.false_pairs`). Raises :class:`InputError` for no poses, no fingerprints,
    NaN in poses, a single-step walk (with ``single_step_walks = "error"``), an unknown reference walk and
    anchors of unknown walks or outside their walk's time span. Walks with no verified link to the
    reference walk are reported (``walks.linked``, warnings). ``held``: the last optimize's map (an
    incremental run, :mod:`.held`): its linked walks are kept where they are and everything else is placed
    and solved against them by the same steps, each source restricted to what concerns the other walks.
    """
    timing: dict[str, float] = {}
    t_all = t0 = time.perf_counter()
    walks, warnings = WalkSet.from_dataset(dataset, fingerprints, cfg.single_step_walks, cfg.compass.default_sigma_rad)
    holding = None
    if held is not None:
        walks, holding = hold(walks, held)
    sources = default_sources(walks, cfg, anchors, progress, candidates_hook, floorplan, holding)
    wifi = sources[0]
    assert isinstance(wifi, WifiSource)
    timing["pair_search"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    ref = held_reference(walks, holding) if holding is not None else _reference_index(walks, cfg)
    placement = place(walks, sources, cfg.placement, ref, holding.fixed if holding is not None else None)
    if progress:
        progress("init", {"linked": int(placement.linked.sum()), "walks": walks.n_walks})
    for s in sources:  # each source sees the poses as the sources before it left them (a plan, then anchors)
        s.place(walks, placement, walks.apply_frames(placement.world_T_walk))
    if holding is not None:
        placement.frame = holding.state.frame
    init_xyt = walks.apply_frames(placement.world_T_walk)
    timing["init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    for s in sources:
        s.prepare(walks, placement, init_xyt)
    static = gauge_factors(walks, placement, init_xyt, any(s.fixes_rotation(placement) for s in sources))
    per_source = [s.static_factors(walks, placement, init_xyt) for s in sources]
    required = np.concatenate([gauge_nodes(walks)] + [s.required_nodes() for s in sources]).astype(np.int64)
    timing["build"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    factors = static.factors + [f for p in per_source for f in p.factors]
    outcome = run_solves(walks, placement, init_xyt, sources, factors, required, cfg, progress)
    timing["solve"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    checks = check_solution(walks, outcome.poses, outcome.raw_scaled, cfg)
    warnings += [w for s in sources for w in s.warnings] + checks.warnings
    final_xyt = init_xyt.copy() if checks.rejected else outcome.poses
    timing["checks"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if cfg.placement.method == "grow":  # the RF check (placement/rfcheck.py) on the solved poses
        sim = wifi.scan_locator()
        placement.refuted = refute(placement, walks, sim, final_xyt[sim.row_node, :2],
                                   holding.state.rf_typical_match_db if holding is not None else None)
    timing["rf_check"] = time.perf_counter() - t0
    pairs = wifi.pairs_table(final_xyt)
    walks_df = report.walk_table(walks, placement, pairs, checks, outcome, final_xyt, gather(sources, walks)[3])
    plan_used = any(s.name == "floorplan" and getattr(s, "used", False) for s in sources)
    lines = (report.unlinked_warning(walks, walks_df, placement.reference, plan_used),
             report.uncertain_placement_warning(walks_df[walks.keep]))
    warnings += [line for line in lines if line]
    if placement.refuted:
        warnings.append(f"{len(placement.refuted)} walk(s) left unplaced: where the Wi-Fi fit put them the radio "
                        "disagrees with the walks already there (RF check): "
                        + ", ".join(walks.walk_ids[w] for w in placement.refuted[:5])
                        + (" ..." if len(placement.refuted) > 5 else ""))
    if walks.n_walks > 1 and walks_df["linked"].sum() <= 1:
        warnings.append("all walks are disconnected: no verified cross-walk Wi-Fi links")
    for wmsg in warnings:
        log.warning(wmsg)
    t0 = time.perf_counter()
    agree = _held_check(walks, placement, sources, holding, cfg) if holding is not None else None
    timing["held_check"] = time.perf_counter() - t0
    timing["total"] = time.perf_counter() - t_all
    cand = wifi.candidates.assign(used=wifi.used_mask())
    in_map = (walks_df["linked"] | walks_df["anchored"]).to_numpy()[walks.walk_of]  # placed in the map's frame
    stats = _stats(walks, placement, outcome, checks, pairs, cand, [static] + per_source, timing, warnings, cfg)
    stats["vicinity"] = {**wifi.report(), "anisotropic_pairs": int(pairs["anisotropic"].sum())}
    stats["evidence"] = {s.name: s.report() for s in sources if s is not wifi}
    stats["placement_kinds"] = report.placement_summary(walks_df[walks.keep])
    if holding is not None and agree is not None:
        stats["incremental"] = {**report.incremental_summary(walks, holding, walks_df), **agree.report(walks)}
    return OptimizeResult(
        state=_state(walks, placement, walks_df, wifi),
        poses=walks.poses_frame(dataset.poses, final_xyt).assign(linked=in_map),
        initial_poses=walks.poses_frame(dataset.poses, init_xyt).assign(linked=in_map),
        pairs=pairs, candidates=cand, walks=walks_df, stats=stats, cost_history=outcome.cost_history,
        placement_log=pd.DataFrame(placement.log), solve_starts=outcome.solve_starts,
    )


def _held_check(walks: WalkSet, placement: Placement, sources: list, holding: Holding,
                cfg: OptimizeConfig) -> heldcheck.HeldCheck:
    """Whether the walks placed agree with the held map (:mod:`rmbuild.slam.placement.heldcheck`)."""
    links, rot, _, _ = gather(sources, walks)
    lk, lq = links.node_k, links.node_q
    if placement.links is not None:
        lk, lq = np.r_[lk, placement.links[0]], np.r_[lq, placement.links[1]]
    moves = heldcheck.held_move(walks, placement, lk, lq, rot, cfg.placement.gate_m,
                                window_lengths(walks, cfg.placement))
    pred = np.array([holding.state.predicted_error_m.get(w, np.nan) for w in walks.walk_ids])
    return heldcheck.check(walks, placement, moves, pred)


def _state(walks: WalkSet, placement: Placement, walks_df: pd.DataFrame, wifi: WifiSource) -> OptimizeState:
    """What later stages need from this run (:class:`rmbuild.types.OptimizeState`)."""
    in_map = walks_df["linked"] | walks_df["anchored"]
    rf = wifi.rf
    pred = walks_df.loc[walks_df["linked"], ["walk_id", "predicted_error_m"]]
    gauge = {"anchors": "anchors", "floorplan": "floorplan"}.get(placement.frame, "se2")
    return OptimizeState(
        tuple(walks.walk_ids), walks.n, tuple(walks_df.loc[in_map, "walk_id"].astype(str)),
        walks.walk_ids[placement.reference], placement.frame, gauge, dict(wifi.compared.offsets_db),
        float(wifi.compared.beta), (rf.near_mu, rf.near_sigma, rf.far_mu, rf.far_sigma),
        {str(w): float(e) for w, e in pred.itertuples(index=False) if np.isfinite(e)}, placement.rf_typical_match_db)


def _reference_index(walks: WalkSet, cfg: OptimizeConfig) -> int | None:
    if not cfg.reference_walk:
        return None
    if cfg.reference_walk not in walks.walk_ids:
        raise InputError(f"reference_walk {cfg.reference_walk!r} is not a walk of this dataset")
    return walks.walk_ids.index(cfg.reference_walk)


def _stats(walks: WalkSet, placement: Placement, outcome: SolveOutcome, checks, pairs: pd.DataFrame,
           cand: pd.DataFrame, statics: list[StaticFactors], timing: dict, warnings: list, cfg: OptimizeConfig) -> dict:
    counts: dict[str, int] = {"prior": 0, "anchor": 0, "heading": 0}
    for s in statics:
        for k, v in s.counts.items():
            counts[k] = counts.get(k, 0) + v
    keep = walks.keep
    n_cross = int((pairs["kind"] == "cross").sum())
    cross = walks.walk_of[cand["node_k"].to_numpy()] != walks.walk_of[cand["node_q"].to_numpy()]
    fitted = outcome.scale_fitted
    scale = outcome.scale
    return {
        "factors": {"odometry": int((walks.ends - walks.starts)[keep].clip(min=1).sum() - keep.sum()),
                    "odometry_in_solve": outcome.n_odometry, "vicinity": len(pairs),
                    "vicinity_within": len(pairs) - n_cross, "vicinity_cross": n_cross,
                    "vicinity_in_final_solve": len(pairs), **counts},
        "walks": walks.n_walks, "poses": walks.n, "poses_solved": int(len(outcome.keyframes)),
        "fingerprints": len(walks.fingerprints), "candidates": len(cand), "candidates_cross": int(cross.sum()),
        "walk_pairs_tested": placement.edge_fits[0], "walk_pairs_accepted": placement.edge_fits[1],
        "reference_walk": walks.walk_ids[placement.reference], "frame": placement.frame,
        "linked_walks": int((placement.linked & keep).sum()),
        "refuted_walks": [walks.walk_ids[w] for w in placement.refuted],
        "anchored_only_walks": int((placement.anchored & ~placement.linked).sum()),
        "components": int(placement.component.max() + 1) if walks.n_walks else 0,
        "initial_cost": outcome.initial_cost, "final_cost": outcome.final_cost,
        "first_solve_initial_cost": outcome.first_solve_initial_cost, "iterations": outcome.iterations,
        "solves": outcome.solves, "ordering": outcome.ordering, "cost_history": outcome.cost_history,
        "odometry_residual_rms_sigma": checks.odometry_rms_sigma,
        "median_extent_ratio": float(np.nanmedian(checks.extent_ratio)), "rejected": checks.rejected,
        "time_s": timing, "warnings": warnings,
        "scale": {"estimated": cfg.odometry.estimate_scale, "rounds": outcome.scale_rounds,
                  "fitted_walks": int(fitted.sum()),
                  "min": float(scale[fitted].min()) if fitted.any() else 1.0,
                  "max": float(scale[fitted].max()) if fitted.any() else 1.0},
    }
