"""The joint solve: the pose graph assembled from odometry, the gauge and the sources, solved by
Levenberg-Marquardt (gtsam) as often as :class:`rmbuild.slam.schedule.SolveSchedule` says.

The graph has one node per keyframe (:mod:`rmbuild.slam.chains`): every node some factor other than
odometry touches, each walk's ends, and one every KEYFRAME_MAX_GAP steps; the steps between are put back
after each solve. Odometry is rebuilt from each walk's scaled dead reckoning whenever a scale round moves
a step-length scale (:mod:`rmbuild.slam.scale`), and the solve after it starts from the poses stretched
about each walk's centroid.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np

from rmbuild.config.optimize import OptimizeConfig
from rmbuild.slam import schedule
from rmbuild.slam.chains import add_chain_odometry, fill_chains, keyframe_mask
from rmbuild.slam.evidence.base import EvidenceSource, SolveState
from rmbuild.slam.factors import X, poses_to_values, values_to_poses
from rmbuild.slam.scale import scaled_raw, update_scales
from rmbuild.slam.schedule import SolveSchedule

log = logging.getLogger(__name__)
Progress = Callable[[str, dict], None] | None

# m and rad; 1-sigma of the prior that keeps a held node (an incremental run's map) where it is
HOLD_SIGMA = 1e-3
# steps; the chain reduction keeps at least one node every this many steps (long chains linearise badly)
KEYFRAME_MAX_GAP = 20
# poses; below this COLAMD orders the elimination (METIS pays off on big graphs, ~3x at 50k poses); gtsam
# 4.3's METIS also corrupts memory on graphs with isolated variables (a pinned one-pose walk)
METIS_MIN_POSES = 5000
# Levenberg-Marquardt stops and damping (gtsam's LevenbergMarquardtParams; Nielsen's lambda update)
LM_RELATIVE_TOL = 1e-3
LM_ABSOLUTE_TOL = 1e-6
LM_LAMBDA_INITIAL = 1e-5
LM_LAMBDA_FACTOR = 10.0
# keyframes; from this graph size on (a venue-month of walks, docs/notes/performance.md) a solve that the schedule
# follows with another stops after INTERMEDIATE_MAX_ITERATIONS: its poses only re-select pairs and re-fit
# scales, and the next solve starts from them (each iteration eliminates the whole graph, seconds at this size)
LARGE_SOLVE_KEYFRAMES = 20_000
INTERMEDIATE_MAX_ITERATIONS = 2
# keyframes; from this graph size on (a venue-month) each LM step is solved by conjugate gradients with the
# walks as the preconditioner's subdomains (:mod:`rmbuild.slam.walkpcg`) instead of eliminating the graph:
# a venue walked that densely makes every separator of the elimination cut hundreds of walks
ITERATIVE_MIN_KEYFRAMES = 25_000


@dataclass
class SolveOutcome:
    """The solved poses (n, 3), the scaled dead reckoning they were solved against, per-walk scales and
    which walks were fitted, solver counts and the cost history (initial cost, then one per iteration)."""

    poses: np.ndarray
    raw_scaled: np.ndarray
    scale: np.ndarray
    scale_fitted: np.ndarray
    settling_used: np.ndarray
    keyframes: np.ndarray
    iterations: int = 0
    solves: int = 0
    scale_rounds: int = 0
    n_odometry: int = 0
    cost_history: list[float] = field(default_factory=list)
    # index into cost_history of each solve's first entry (a new solve's graph has other factors: its
    # cost jumps, which is not divergence)
    solve_starts: list[int] = field(default_factory=list)
    final_cost: float = 0.0
    initial_cost: float = 0.0
    first_solve_initial_cost: float | None = None
    ordering: str = "METIS"


class _Graph:
    """Odometry over the keyframes of the solved walks (``solved``: kept, not held), from the current scaled
    dead reckoning, plus the static factors; held nodes (``base``: the poses they keep) get a tight prior
    where a factor touches them, and a factor that touches held nodes only is left out (it cannot move
    anything)."""

    def __init__(self, walks, kf: np.ndarray, static: list, cfg: OptimizeConfig, fixed: np.ndarray, base: np.ndarray):
        self.walks, self.kf, self.cfg, self.base = walks, kf, cfg, base
        self.solved = walks.keep & ~fixed
        self.kf_idx = np.flatnonzero(kf)
        held = self.kf_idx[fixed[walks.walk_of[self.kf_idx]]]
        self.held_keys = {X(int(i)) for i in held.tolist()}
        self.static = gtsam.NonlinearFactorGraph()
        hold = gtsam.noiseModel.Isotropic.Sigma(3, HOLD_SIGMA)
        for i in held.tolist():
            self.static.add(gtsam.PriorFactorPose2(X(i), gtsam.Pose2(*base[i]), hold))
        for f in self.free(static):
            self.static.add(f)
        self.set_scale(walks.raw)

    def free(self, factors: list) -> list:
        """The factors that touch a node not held."""
        if not self.held_keys:
            return factors
        return [f for f in factors if any(k not in self.held_keys for k in f.keys())]

    def set_scale(self, raw_s: np.ndarray) -> None:
        w = self.walks
        self.raw_s = raw_s
        self.odo = gtsam.NonlinearFactorGraph()
        self.n_odo = add_chain_odometry(self.odo, raw_s, w.starts[self.solved], w.ends[self.solved], self.kf,
                                        self.cfg.odometry)

    def build(self, factors: list) -> gtsam.NonlinearFactorGraph:
        g = gtsam.NonlinearFactorGraph(self.odo)
        g.push_back(self.static)
        for f in self.free(factors):
            g.add(f)
        return g

    def to_values(self, xyt: np.ndarray) -> gtsam.Values:
        return poses_to_values(xyt[self.kf_idx], nodes=self.kf_idx)

    def from_values(self, v: gtsam.Values) -> np.ndarray:
        w = self.walks
        full = self.base.copy()
        # the solve's values hold exactly the keyframes' Pose2s, in key order X(kf_idx[0]) < X(kf_idx[1]) < ...
        full[self.kf_idx] = gtsam.utilities.extractPose2(v) if v.size() == len(self.kf_idx) else \
            values_to_poses(v, nodes=self.kf_idx)
        return fill_chains(full, self.raw_s, w.starts[self.solved], w.ends[self.solved], self.kf)


def keyframes(walks, required: np.ndarray, chain_reduction: bool, fixed: np.ndarray) -> np.ndarray:
    """bool (n,): the nodes the solve keeps: the solved walks' keyframes and the ``required`` nodes of the
    ``fixed`` (held) walks."""
    solved = walks.keep & ~fixed
    if not chain_reduction:
        return solved[walks.walk_of] | required
    return keyframe_mask(walks.n, walks.starts[solved], walks.ends[solved], required, KEYFRAME_MAX_GAP)


def levenberg_marquardt(graph, values, cfg: OptimizeConfig, history: list, progress: Progress, outer: int,
                        ordering: str, max_iterations: int | None = None, walk: np.ndarray | None = None):
    """gtsam's LM on ``graph`` from ``values``; with ``walk`` (the walk of each value, keys ascending) the
    same damping and stops with each step solved by :func:`rmbuild.slam.walkpcg.levenberg_marquardt`."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations or cfg.solve.max_iterations)
    params.setRelativeErrorTol(LM_RELATIVE_TOL)
    params.setAbsoluteErrorTol(LM_ABSOLUTE_TOL)
    params.setOrderingType(ordering)
    params.setlambdaInitial(LM_LAMBDA_INITIAL)
    params.setlambdaFactor(LM_LAMBDA_FACTOR)
    params.setUseFixedLambdaFactor(False)  # Nielsen's update, not gtsam's default fixed factor
    params.setDiagonalDamping(False)

    def hook(it, before, after):
        history.append(float(after))
        if progress:
            progress("solve", {"outer": outer, "iteration": int(it), "cost_before": float(before),
                               "cost_after": float(after), "max_iterations": cfg.solve.max_iterations})

    if walk is not None:
        from rmbuild.slam import walkpcg  # scipy: not imported on the incremental path (~0.3 s)

        return walkpcg.levenberg_marquardt(graph, values, walk, int(walk.max(initial=-1)) + 1,
                                           max_iterations or cfg.solve.max_iterations, LM_LAMBDA_INITIAL,
                                           LM_LAMBDA_FACTOR, LM_RELATIVE_TOL, LM_ABSOLUTE_TOL, hook)
    params.iterationHook = hook
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    return result, int(opt.iterations())


def run(walks, placement, init_xyt: np.ndarray, sources: list[EvidenceSource], static: list,
        required: np.ndarray, cfg: OptimizeConfig, progress: Progress = None) -> SolveOutcome:
    """Solve the pose graph from ``init_xyt`` as the schedule says (module docstring)."""
    req = np.zeros(walks.n, bool)
    req[required] = True
    fixed = placement.fixed if placement.fixed is not None else np.zeros(walks.n_walks, bool)
    kf = keyframes(walks, req, cfg.solve.chain_reduction, fixed)
    graph = _Graph(walks, kf, static, cfg, fixed, init_xyt)
    ocfg = cfg.odometry
    iterative = len(graph.kf_idx) >= ITERATIVE_MIN_KEYFRAMES
    sched = SolveSchedule(cfg.solve.outer_iterations, ocfg.estimate_scale, schedule.SCALE_ROUNDS_MAX)
    ordering = "COLAMD" if (~walks.keep).any() or len(graph.kf_idx) < METIS_MIN_POSES else "METIS"
    scale = np.ones(walks.n_walks)
    out = SolveOutcome(init_xyt, walks.raw, scale, np.zeros(walks.n_walks, bool), np.zeros(walks.n_walks, bool),
                       graph.kf_idx, ordering=ordering)
    settling = np.zeros(walks.n_walks, bool)
    large = len(graph.kf_idx) >= LARGE_SOLVE_KEYFRAMES
    walk_of_kf = walks.walk_of[graph.kf_idx] if iterative else None
    out.ordering = "walk-PCG" if walk_of_kf is not None else ordering
    values = graph.to_values(init_xyt)
    current = init_xyt
    while True:
        state = SolveState(current, settling.copy(), placement, graph.kf_idx)
        out.settling_used = state.settling
        g = graph.build([f for s in sources for f in s.factors(state)])
        out.solve_starts.append(len(out.cost_history))
        if out.first_solve_initial_cost is None:
            out.first_solve_initial_cost = float(g.error(values))
            out.cost_history.append(out.first_solve_initial_cost)
        cap = INTERMEDIATE_MAX_ITERATIONS if large and sched.solves + 1 < sched.budget else None
        values, it = levenberg_marquardt(g, values, cfg, out.cost_history, progress, sched.solves, ordering, cap,
                                         walk_of_kf)
        sched.solved()
        out.iterations += it
        current = graph.from_values(values)
        done = SolveState(current, settling, placement, graph.kf_idx)
        updates = [s.update(done) for s in sources]
        if sched.scale_round_due():
            restart, settling = _scale_round(walks, placement, sources, graph, sched, out, current, scale)
            scale = out.scale
            values = restart if restart is not None else values
        if not sched.settling():
            settling = np.zeros(walks.n_walks, bool)
        if not sched.next_solve(any(u.changed for u in updates), any(u.first_switch for u in updates)):
            break
    out.poses, out.raw_scaled, out.solves, out.scale_rounds = current, graph.raw_s, sched.solves, sched.rounds
    out.n_odometry = graph.n_odo
    final_state = SolveState(current, out.settling_used, placement, graph.kf_idx)
    final = graph.build([f for s in sources for f in s.final_factors(final_state)])
    out.final_cost = float(final.error(values))
    out.initial_cost = float(final.error(graph.to_values(init_xyt)))
    return out


def _scale_round(walks, placement, sources, graph: _Graph, sched: SolveSchedule, out: SolveOutcome,
                 current: np.ndarray, scale: np.ndarray):
    """Re-estimate each linked walk's step-length scale from the pairs near each other; rebuild the
    odometry and restart from the poses stretched about each walk's centroid when a scale moved.
    Returns (values to start from, walks still settling)."""
    cfg = graph.cfg
    pairs = [s.pairs_near(current) for s in sources]
    pk = np.concatenate([p[0] for p in pairs])
    pq = np.concatenate([p[1] for p in pairs])
    eligible = graph.solved & placement.linked
    new_scale, fitted = update_scales(current, walks.raw, walks.starts, walks.ends, scale, eligible, pk, pq,
                                      walks.walk_of, cfg.odometry,
                                      normalize=placement.n_anchors == 0 and placement.fixed is None)
    out.scale_fitted |= fitted
    moved = sched.scale_done(float(np.max(np.abs(new_scale - scale), initial=0.0)))
    settling = np.abs(new_scale - scale) > schedule.SCALE_EXTEND_MOVE
    log.debug("scale round %d: %s", sched.rounds, np.round(new_scale, 3).tolist())
    values = None
    if moved:
        stretched = current.copy()
        for w in np.flatnonzero(new_scale != scale):
            a, b = walks.starts[w], walks.ends[w]
            c = current[a:b, :2].mean(axis=0)
            stretched[a:b, :2] = c + (new_scale[w] / scale[w]) * (current[a:b, :2] - c)
        graph.set_scale(scaled_raw(walks.raw, walks.starts, walks.ends, new_scale))
        values = graph.to_values(stretched)
    out.scale = new_scale if moved else scale
    return values, settling
