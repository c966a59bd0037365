"""Compass evidence: the phone's absolute heading (magnetometer-referenced yaw, poses column yaw_abs_rad).

- Placement: each walk frame's rotation in the compass world — the circular mean over its steps of
  yaw_abs − heading — with a 1-sigma that shrinks with the number of independent samples (the indoor
  magnetic disturbance is correlated over ABS_HEADING_CORR_STEPS steps) down to ABS_HEADING_SIGMA_RAD.
  A walk with a rotation is fitted by translation only; the placement may distrust a walk's compass
  (``placement.heading_used``) when its fit disagrees.
- Solve: a robust (Cauchy) rotation prior on every n-th step of the walks whose compass is trusted,
  expressed in the map's frame, once the reference walk has a compass (it then fixes the map's rotation).
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import CompassConfig
from rmbuild.slam.evidence.base import EvidenceSource, RotationPriors, StaticFactors
from rmbuild.slam.factors import X
from rmbuild.slam.held import Holding
from rmbuild.slam.problem import WalkSet

# steps; correlation length of the indoor magnetic disturbance (samples this far apart count as independent)
ABS_HEADING_CORR_STEPS = 10
# rad; floor of a walk frame's rotation sigma (the disturbance's common part does not average out)
ABS_HEADING_SIGMA_RAD = 0.02
# Cauchy kernel width (sigmas) of each heading prior: a local disturbance (steel, escalators) far beyond
# the reported sigma bends the walk less (docs/notes/optimize.md: six synthetic seeds 1.64 -> 1.38 m)
HEADING_PRIOR_CAUCHY_K = 1.0
# steps; a heading prior on every n-th step of a walk with a compass in the joint solve
HEADING_PRIOR_EVERY_N = 10


class CompassSource(EvidenceSource):
    """Walk rotations for placement and heading priors for the solve (module docstring)."""

    name = "compass"

    def __init__(self, walks: WalkSet, cfg: CompassConfig, holding: Holding | None = None):
        """``holding``: a held map (:mod:`rmbuild.slam.held`): its walks share one rotation, the map frame's
        in the compass world (the circular mean over them), and get no heading priors (they do not move)."""
        self.warnings: list[str] = []
        self.cfg = cfg
        self.walks = walks
        theta, known, sigma = walk_rotations(walks)
        self.fixed = holding.fixed if holding is not None else np.zeros(walks.n_walks, bool)
        if (self.fixed & known).any():
            theta = np.where(self.fixed, geometry.circular_mean(theta[self.fixed & known]), theta)
        self.priors = RotationPriors(theta, known & walks.keep & cfg.use, sigma)
        self.nodes = np.zeros(0, np.int64)

    def rotation_priors(self) -> RotationPriors:
        return self.priors

    def fixes_rotation(self, placement) -> bool:
        """Whether the heading priors fix the map's rotation (the reference walk has a trusted compass)."""
        return self.cfg.use and bool(placement.heading_known[placement.reference])

    def static_factors(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> StaticFactors:
        """Per-step rotation priors (yaw_abs minus the map frame's compass rotation)."""
        out = StaticFactors(counts={"heading": 0})
        if not self.fixes_rotation(placement):
            return out
        world_rot = self.priors.theta[placement.reference] - placement.frame_rotation
        nodes = []
        for w in np.flatnonzero(placement.heading_known & ~self.fixed):
            idx = np.arange(walks.starts[w], walks.ends[w], HEADING_PRIOR_EVERY_N)
            idx = idx[np.isfinite(walks.yaw_abs[idx])]
            nodes.append(idx)
            for i in idx.tolist():
                noise = gtsam.noiseModel.Robust.Create(
                    gtsam.noiseModel.mEstimator.Cauchy.Create(HEADING_PRIOR_CAUCHY_K),
                    gtsam.noiseModel.Isotropic.Sigma(1, float(walks.yaw_sigma[i])))
                out.factors.append(gtsam.PoseRotationPrior2D(X(i), gtsam.Pose2(0, 0, walks.yaw_abs[i] - world_rot),
                                                             noise))
        self.nodes = np.concatenate(nodes) if nodes else np.zeros(0, np.int64)
        out.counts["heading"] = len(out.factors)
        return out

    def required_nodes(self) -> np.ndarray:
        return self.nodes


def walk_rotations(walks: WalkSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta, known, sigma), each (n_walks,): each walk frame's rotation (rad) in the compass world,
    whether the walk has yaw_abs, and the rotation's 1-sigma (rad, see the module docstring)."""
    n_w = walks.n_walks
    th = np.zeros(n_w)
    sig = np.full(n_w, np.inf)
    known = np.zeros(n_w, bool)
    for w, (s, e) in enumerate(zip(walks.starts, walks.ends)):
        d = walks.yaw_abs[s:e] - walks.raw[s:e, 2]
        ok = np.isfinite(d)
        if ok.any():
            th[w] = geometry.circular_mean(d[ok])
            known[w] = True
            n_ind = max(1.0, ok.sum() / ABS_HEADING_CORR_STEPS)
            sig[w] = max(ABS_HEADING_SIGMA_RAD, float(np.median(walks.yaw_sigma[s:e][ok])) / np.sqrt(n_ind))
    return th, known, sig


def component_compass_offset(T: np.ndarray, walks: np.ndarray, rot: RotationPriors, ref: int) -> float:
    """Rotation (rad) that takes a component's frame to the reference's by the compass: the circular mean
    over ``walks`` (bool, trusted compass) of theta[w] - theta[ref] - T[w, 2]."""
    return float(geometry.circular_mean(rot.theta[walks] - rot.theta[ref] - T[walks, 2]))

