"""GTSAM keys, Values conversion and the factors of the rmbuild pose graph.

Key scheme: pose node i (row i of ``Dataset.poses``) is ``X(i) = gtsam.symbol('x', i)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import OdometryConfig, WifiConfig


def X(i: int) -> int:
    """Key of pose node i."""
    return gtsam.symbol("x", int(i))


def poses_to_values(xyt: np.ndarray, key=X, nodes: np.ndarray | None = None) -> gtsam.Values:
    """Values with Pose2 ``key(i)`` = (x, y, theta) of row i of ``xyt`` (n, 3) [m, m, rad]; with ``nodes``
    (n,) the keys are ``key(nodes[i])`` instead."""
    v = gtsam.Values()
    ids = range(len(xyt)) if nodes is None else np.asarray(nodes).tolist()
    for i, (x, y, t) in zip(ids, np.asarray(xyt, dtype=float).tolist()):
        v.insert(key(i), gtsam.Pose2(x, y, t))
    return v


def values_to_poses(values: gtsam.Values, n: int | None = None, key=X, nodes: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) array [m, m, rad] of Pose2 ``key(0..n-1)``, or of ``key(nodes[i])`` (theta wrapped to
    (-pi, pi])."""
    ids = list(range(n or 0)) if nodes is None else np.asarray(nodes).tolist()
    out = np.empty((len(ids), 3))
    for j, i in enumerate(ids):
        p = values.atPose2(key(i))
        out[j] = (p.x(), p.y(), p.theta())
    return out


def odometry_noise(ocfg: OdometryConfig) -> gtsam.noiseModel.Base:
    """Ω_IMU = diag(1/σx², 1/σy², μ) (Gu et al., eq. 8)."""
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([ocfg.sigma_x_m, ocfg.sigma_y_m, 1 / np.sqrt(ocfg.mu)]))


def add_odometry(graph: gtsam.NonlinearFactorGraph, raw: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                 ocfg: OdometryConfig) -> int:
    """BetweenFactorPose2 between consecutive nodes of each walk [starts[w], ends[w]); never across walks."""
    noise = odometry_noise(ocfg)
    n = 0
    for s, e in zip(starts, ends):
        u = geometry.increments(raw[s:e])
        for k in range(e - s - 1):
            graph.add(gtsam.BetweenFactorPose2(X(s + k), X(s + k + 1), gtsam.Pose2(*u[k]), noise))
            n += 1
    return n


# eq. 10's e_max, the plateau of the fuzzy error. Only e_max²·Ω_WiFi enters the cost, so the config
# carries the weight in Ω alone and e_max stays at the paper's 1.
E_MAX = 1.0


def fuzzy_error(d: np.ndarray, cfg: WifiConfig) -> np.ndarray:
    """Gu et al., eq. 10: e(d) = 0 below d_min, e_max beyond d_max, linear in between (d in metres)."""
    d = np.asarray(d, dtype=float)
    return E_MAX * np.clip((d - cfg.d_min) / (cfg.d_max - cfg.d_min), 0.0, 1.0)


def fuzzy_cost(d: np.ndarray, cfg: WifiConfig) -> np.ndarray:
    """GTSAM-convention factor error 0.5·Ω_WiFi·e(d)² of one vicinity factor."""
    return 0.5 * cfg.omega * fuzzy_error(d, cfg) ** 2


def _ramp_sigma(cfg: WifiConfig) -> float:
    """Sigma (m) that makes the whitened range residual r = (d - d_min)/sigma equal sqrt(Ω)·e(d)."""
    return (cfg.d_max - cfg.d_min) / (E_MAX * np.sqrt(cfg.omega))


def vicinity_noise(cfg: WifiConfig) -> gtsam.noiseModel.Base:
    """The robust noise model of eq. 10 as a range factor: the ramp's sigma, truncated (gtsam's
    TruncatedLeastSquares) at the whitened residual sqrt(Ω)·e_max, where eq. 10 turns flat. Exact for
    d >= d_min; below d_min it adds a tiny push-apart (about 0.5 % of the plateau)."""
    base = gtsam.noiseModel.Isotropic.Sigma(1, _ramp_sigma(cfg))
    est = gtsam.noiseModel.mEstimator.TruncatedLeastSquares(E_MAX * np.sqrt(cfg.omega))
    return gtsam.noiseModel.Robust.Create(est, base)


def vicinity_factor(k: int, q: int, cfg: WifiConfig, noise=None) -> gtsam.NonlinearFactor:
    """One fuzzy vicinity factor between pose nodes k and q (eq. 10): RangeFactorPose2 measuring d_min.

    ``noise``: a shared noise model from :func:`vicinity_noise` (built once for many factors).
    """
    return gtsam.RangeFactorPose2(X(k), X(q), cfg.d_min, noise if noise is not None else vicinity_noise(cfg))


# the rotation part of an anisotropic pair factor carries no information (its sigma, rad)
_FREE_ROT_SIGMA = 1e3


def anisotropic_noise(cfg: WifiConfig, across_ratio: float) -> gtsam.noiseModel.Base:
    """Robust noise of an anisotropic pair factor (:func:`anisotropic_factor`): eq. 10's ramp sigma along
    the walking direction, across_ratio times it across, a free rotation; truncated at the Mahalanobis
    radius e_max·sqrt(Ω), where eq. 10 turns flat (with d_min = 0)."""
    sigma = _ramp_sigma(cfg)
    base = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, across_ratio * sigma, _FREE_ROT_SIGMA]))
    est = gtsam.noiseModel.mEstimator.TruncatedLeastSquares(E_MAX * np.sqrt(cfg.omega))
    return gtsam.noiseModel.Robust.Create(est, base)


def anisotropic_factor(k: int, q: int, rel_theta: float, noise) -> gtsam.NonlinearFactor:
    """A pair factor between nodes k and q whose error is q's offset from k in q's heading frame.

    BetweenFactorPose2 with measured (0, 0, rel_theta): the translation of its error is
    R(-θk - rel_theta)·(t_q - t_k), the offset in q's frame when rel_theta is the current θq - θk; the
    rotation error then stays near 0, where the Pose2 log map leaves the translation as it is."""
    return gtsam.BetweenFactorPose2(X(k), X(q), gtsam.Pose2(0.0, 0.0, float(rel_theta)), noise)
