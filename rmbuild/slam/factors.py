"""GTSAM keys, Values conversion and the factors of the rmbuild pose graph.

Key scheme: pose node i (row i of ``Dataset.poses``) is ``X(i) = gtsam.symbol('x', i)``; walk-level
frames in the initialisation graph are ``W(w) = gtsam.symbol('w', w)`` (w = walk index).
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild.config.optimize import OdometryConfig, VicinityConfig


def X(i: int) -> int:
    """Key of pose node i."""
    return gtsam.symbol("x", int(i))


def W(w: int) -> int:
    """Key of walk w's frame (world_T_walk) in the walk-level graph."""
    return gtsam.symbol("w", int(w))


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
    ids = list(range(n)) if nodes is None else np.asarray(nodes).tolist()
    out = np.empty((len(ids), 3))
    for j, i in enumerate(ids):
        p = values.atPose2(key(i))
        out[j] = (p.x(), p.y(), p.theta())
    return out


def between_se2(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """p⁻¹ · q for pose arrays p, q (m, 3) [m, m, rad]: q in p's body frame."""
    d = q[:, :2] - p[:, :2]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], np.angle(np.exp(1j * (q[:, 2] - p[:, 2])))]


def compose_many(p: np.ndarray, u: np.ndarray) -> np.ndarray:
    """p · u for pose arrays p, u (m, 3) [m, m, rad]."""
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.c_[p[:, 0] + c * u[:, 0] - s * u[:, 1], p[:, 1] + s * u[:, 0] + c * u[:, 1],
                 np.angle(np.exp(1j * (p[:, 2] + u[:, 2])))]


def compose_se2(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """T (3,) = (x, y, theta) applied to poses p (n, 3): world poses of walk-frame poses."""
    p = np.asarray(p, dtype=float)
    return compose_many(np.broadcast_to(np.asarray(T, dtype=float), p.shape), p)


def relative_se2(p: np.ndarray) -> np.ndarray:
    """Body-frame increments (n-1, 3) between consecutive poses p (n, 3) (seed 001 eq. 6)."""
    return between_se2(p[:-1], p[1:])


def odometry_noise(ocfg: OdometryConfig) -> gtsam.noiseModel.Base:
    """Ω_IMU = diag(1/σx², 1/σy², μ) (seed 001 eq. 8)."""
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([ocfg.sigma_x_m, ocfg.sigma_y_m, 1 / np.sqrt(ocfg.mu)]))


def add_odometry(graph: gtsam.NonlinearFactorGraph, raw: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                 ocfg: OdometryConfig) -> int:
    """BetweenFactorPose2 between consecutive nodes of each walk [starts[w], ends[w]); never across walks."""
    noise = odometry_noise(ocfg)
    n = 0
    for s, e in zip(starts, ends):
        u = relative_se2(raw[s:e])
        for k in range(e - s - 1):
            graph.add(gtsam.BetweenFactorPose2(X(s + k), X(s + k + 1), gtsam.Pose2(*u[k]), noise))
            n += 1
    return n


def fuzzy_error(d: np.ndarray, vcfg: VicinityConfig) -> np.ndarray:
    """Seed 001 eq. 10: e(d) = 0 below d_min, e_max beyond d_max, linear in between (d in metres)."""
    d = np.asarray(d, dtype=float)
    return vcfg.e_max * np.clip((d - vcfg.d_min) / (vcfg.d_max - vcfg.d_min), 0.0, 1.0)


def fuzzy_cost(d: np.ndarray, vcfg: VicinityConfig) -> np.ndarray:
    """GTSAM-convention factor error 0.5·Ω_WiFi·e(d)² of one vicinity factor."""
    return 0.5 * vcfg.omega_wifi * fuzzy_error(d, vcfg) ** 2


def _ramp_sigma(vcfg: VicinityConfig) -> float:
    """Sigma (m) that makes the whitened range residual r = (d - d_min)/sigma equal sqrt(Ω)·e(d)."""
    return (vcfg.d_max - vcfg.d_min) / (vcfg.e_max * np.sqrt(vcfg.omega_wifi))


def vicinity_noise(vcfg: VicinityConfig) -> gtsam.noiseModel.Base:
    """The robust noise model of a range-based fuzzy factor (kernel range_tls or range_custom)."""
    sigma = _ramp_sigma(vcfg)
    base = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
    if vcfg.kernel == "range_tls":
        est = gtsam.noiseModel.mEstimator.TruncatedLeastSquares(vcfg.e_max * np.sqrt(vcfg.omega_wifi))
    else:
        a, b = vcfg.d_min / sigma, vcfg.d_max / sigma

        def loss(r: float) -> float:
            r = abs(r)
            return 0.0 if r < a else 0.5 * (min(r, b) - a) ** 2

        def weight(r: float) -> float:
            r = abs(r)
            return 0.0 if (r <= a or r >= b) else (r - a) / r

        est = gtsam.noiseModel.mEstimator.Custom(weight, loss)
    return gtsam.noiseModel.Robust.Create(est, base)


def _custom_error_fn(vcfg: VicinityConfig):
    sigma = _ramp_sigma(vcfg)

    def err(this: gtsam.CustomFactor, v: gtsam.Values, H):
        k1, k2 = this.keys()
        p, q = v.atPose2(k1), v.atPose2(k2)
        dx, dy = q.x() - p.x(), q.y() - p.y()
        d = max(np.hypot(dx, dy), 1e-9)
        inside = vcfg.d_min < d < vcfg.d_max
        e = (min(max(d, vcfg.d_min), vcfg.d_max) - vcfg.d_min) / sigma
        if H is not None:
            g = (1.0 / sigma) if inside else 0.0
            # derivative w.r.t. body-frame increments (Pose2 retract: x ⊕ ξ moves by R(θ)ξ_xy)
            cp, sp = np.cos(p.theta()), np.sin(p.theta())
            cq, sq = np.cos(q.theta()), np.sin(q.theta())
            ux, uy = dx / d, dy / d
            H[0] = np.array([[-g * (ux * cp + uy * sp), -g * (-ux * sp + uy * cp), 0.0]])
            H[1] = np.array([[g * (ux * cq + uy * sq), g * (-ux * sq + uy * cq), 0.0]])
        return np.array([e])

    return err


def vicinity_factor(k: int, q: int, vcfg: VicinityConfig, noise=None) -> gtsam.NonlinearFactor:
    """One fuzzy vicinity factor between pose nodes k and q (eq. 10, in the configured kernel).

    ``noise``: a shared noise model from :func:`vicinity_noise` (built once for many factors).
    """
    if vcfg.kernel == "custom_factor":
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [X(k), X(q)], _custom_error_fn(vcfg))
    noise = noise if noise is not None else vicinity_noise(vcfg)
    measured = vcfg.d_min if vcfg.kernel == "range_tls" else 0.0
    return gtsam.RangeFactorPose2(X(k), X(q), measured, noise)


# the rotation part of an anisotropic pair factor carries no information (its sigma, rad)
_FREE_ROT_SIGMA = 1e3


def pair_offsets(xyt: np.ndarray, k: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, across, θq - θk) of pairs (k, q) at poses xyt (n, 3): q's offset from k in q's heading frame
    (m) and the relative heading (rad, wrapped)."""
    d = xyt[q, :2] - xyt[k, :2]
    c, s = np.cos(xyt[q, 2]), np.sin(xyt[q, 2])
    rel = np.angle(np.exp(1j * (xyt[q, 2] - xyt[k, 2])))
    return c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], rel


def anisotropic_noise(vcfg: VicinityConfig, across_ratio: float) -> gtsam.noiseModel.Base:
    """Robust noise of an anisotropic pair factor (:func:`anisotropic_factor`): eq. 10's ramp sigma along
    the walking direction, across_ratio times it across, a free rotation; truncated at the Mahalanobis
    radius e_max·sqrt(Ω), where eq. 10 turns flat (kernel range_tls, d_min = 0)."""
    sigma = _ramp_sigma(vcfg)
    base = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, across_ratio * sigma, _FREE_ROT_SIGMA]))
    est = gtsam.noiseModel.mEstimator.TruncatedLeastSquares(vcfg.e_max * np.sqrt(vcfg.omega_wifi))
    return gtsam.noiseModel.Robust.Create(est, base)


def anisotropic_factor(k: int, q: int, rel_theta: float, noise) -> gtsam.NonlinearFactor:
    """A pair factor between nodes k and q whose error is q's offset from k in q's heading frame.

    BetweenFactorPose2 with measured (0, 0, rel_theta): the translation of its error is
    R(-θk - rel_theta)·(t_q - t_k), the offset in q's frame when rel_theta is the current θq - θk; the
    rotation error then stays near 0, where the Pose2 log map leaves the translation as it is."""
    return gtsam.BetweenFactorPose2(X(k), X(q), gtsam.Pose2(0.0, 0.0, float(rel_theta)), noise)
