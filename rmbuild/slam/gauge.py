"""The gauge: priors that fix what no evidence fixes — each component's frame, and the walks left out.

Each component's root (the reference walk, or a further component's first walk) gets a tight prior on its
first pose, unless anchors place the component (a component placed by one anchor keeps a rotation prior).
When the compass fixes the map's rotation, the reference component's roots with a trusted compass get a
position prior only. A walk that takes no part (fewer than 2 poses) is pinned where it is.
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild.slam.evidence.base import StaticFactors
from rmbuild.slam.factors import X
from rmbuild.slam.problem import WalkSet

# m / rad; 1-sigma of a gauge prior (tight: it only removes the free frame)
GAUGE_SIGMA_M = 1e-3
GAUGE_SIGMA_RAD = 1e-4
# m and rad; 1-sigma of the prior pinning a walk that takes no part
PIN_SIGMA = 1e-3


def gauge_factors(walks: WalkSet, placement, init_xyt: np.ndarray, compass_fixes_rotation: bool) -> StaticFactors:
    """Gauge and pinning priors (module docstring); counted as "prior"."""
    out: list = []
    full_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([GAUGE_SIGMA_M, GAUGE_SIGMA_M, GAUGE_SIGMA_RAD]))
    for r in placement.gauge_full:
        s = int(walks.starts[r])
        if compass_fixes_rotation and placement.component[r] == 0 and placement.heading_known[r]:
            out.append(gtsam.PoseTranslationPrior2D(X(s), gtsam.Pose2(*init_xyt[s]),
                                                    gtsam.noiseModel.Isotropic.Sigma(2, GAUGE_SIGMA_M)))
        else:
            out.append(gtsam.PriorFactorPose2(X(s), gtsam.Pose2(*init_xyt[s]), full_noise))
    for r in placement.gauge_rotation_only:
        s = int(walks.starts[r])
        out.append(gtsam.PoseRotationPrior2D(X(s), gtsam.Pose2(*init_xyt[s]),
                                             gtsam.noiseModel.Isotropic.Sigma(1, GAUGE_SIGMA_RAD)))
    pin = gtsam.noiseModel.Isotropic.Sigma(3, PIN_SIGMA)
    for w in np.flatnonzero(~walks.keep):
        for i in range(walks.starts[w], walks.ends[w]):
            out.append(gtsam.PriorFactorPose2(X(i), gtsam.Pose2(*init_xyt[i]), pin))
    return StaticFactors(out, {"prior": len(out)})


def gauge_nodes(walks: WalkSet) -> np.ndarray:
    """Nodes the gauge and pinning priors may sit on: every kept walk's first pose, every skipped walk's poses."""
    skipped = [np.arange(walks.starts[w], walks.ends[w]) for w in np.flatnonzero(~walks.keep)]
    return np.concatenate([walks.starts[walks.keep]] + skipped).astype(np.int64)
