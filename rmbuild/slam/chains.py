"""Chain reduction of the pose graph: odometry between keyframes instead of between every step.

Most steps of a walk carry nothing but their two odometry factors: no vicinity pair, no heading prior, no
anchor. Between two nodes that do carry something (the *keyframes*), the steps form a chain, and a chain
can be eliminated before the solve: the composed PDR increment between consecutive keyframes, with the
per-step noise propagated along the chain, is the between factor that the chain's steps amount to (exact
for a linear-Gaussian chain; to first order for SE(2)). The solve then has one node per keyframe, and the
steps in between are put back afterwards by spreading the keyframes' correction along the chain.

Noise propagation (gtsam's BetweenFactor<Pose2> puts the noise on the right: hx = measured · Exp(ξ),
ξ ~ N(0, Q)): composing u_1 Exp(ξ_1) · u_2 Exp(ξ_2) ··· gives M · Exp(η) with, step by step,
Σ_k = Ad(u_k⁻¹) Σ_{k-1} Ad(u_k⁻¹)ᵀ + Q, Σ_0 = 0.
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import OdometryConfig
from rmbuild.slam.factors import X


def keyframe_mask(n: int, starts: np.ndarray, ends: np.ndarray, required: np.ndarray, max_gap: int) -> np.ndarray:
    """bool (n,): the nodes the reduced graph keeps.

    ``required`` (n,) bool marks nodes with factors other than odometry; each walk [starts[w], ends[w])
    also keeps its first and last node and at least one node every ``max_gap`` steps (so that no chain is
    long enough for its composed increment to linearise badly). Nodes outside every walk stay as they are
    in ``required``.
    """
    kf = np.asarray(required, bool).copy()
    for s, e in zip(starts, ends):
        if e <= s:
            continue
        kf[s] = kf[e - 1] = True
        idx = np.flatnonzero(kf[s:e])
        # walk the gaps longer than max_gap and add evenly spaced nodes inside each
        gaps = np.diff(idx)
        for g0, g in zip(idx[:-1][gaps > max_gap], gaps[gaps > max_gap]):
            k = int(np.ceil(g / max_gap))
            kf[s + g0 + np.round(np.arange(1, k) * g / k).astype(int)] = True
    return kf


def _segments(starts: np.ndarray, ends: np.ndarray, kf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive keyframe pairs (a, b) inside each walk."""
    a_all, b_all = [], []
    for s, e in zip(starts, ends):
        idx = s + np.flatnonzero(kf[s:e])
        a_all.append(idx[:-1])
        b_all.append(idx[1:])
    if not a_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(a_all).astype(np.int64), np.concatenate(b_all).astype(np.int64)


def chain_covariances(raw: np.ndarray, a: np.ndarray, b: np.ndarray, ocfg: OdometryConfig) -> np.ndarray:
    """(m, 3, 3) covariance of the composed increment raw[a]⁻¹ raw[b] of each chain a → b (see module)."""
    q = np.diag([ocfg.sigma_x_m ** 2, ocfg.sigma_y_m ** 2, 1.0 / ocfg.mu])
    cov = np.zeros((len(a), 3, 3))
    length = b - a
    for j in range(1, int(length.max(initial=0)) + 1):
        m = length >= j
        k = a[m] + j  # the increment from node k-1 to node k
        u = geometry.between(raw[k - 1], raw[k])
        # Ad(u⁻¹): u⁻¹ = (R(-θ), -R(-θ) t); Ad(x, y, θ) = [[c, -s, y], [s, c, -x], [0, 0, 1]]
        c, s = np.cos(u[:, 2]), np.sin(u[:, 2])
        xi, yi = -(c * u[:, 0] + s * u[:, 1]), s * u[:, 0] - c * u[:, 1]
        ad = np.zeros((len(k), 3, 3))
        ad[:, 0, 0], ad[:, 0, 1], ad[:, 0, 2] = c, s, yi
        ad[:, 1, 0], ad[:, 1, 1], ad[:, 1, 2] = -s, c, -xi
        ad[:, 2, 2] = 1.0
        cov[m] = np.einsum("kij,kjl,kml->kim", ad, cov[m], ad) + q
    return cov


def add_chain_odometry(graph: gtsam.NonlinearFactorGraph, raw: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                       kf: np.ndarray, ocfg: OdometryConfig) -> int:
    """BetweenFactorPose2 between consecutive keyframes of each walk (the composed PDR increment and its
    propagated covariance); with every node a keyframe these are exactly the per-step odometry factors."""
    a, b = _segments(starts, ends, kf)
    if not len(a):
        return 0
    u = geometry.between(raw[a], raw[b])
    cov = chain_covariances(raw, a, b, ocfg)
    single = gtsam.noiseModel.Diagonal.Sigmas(np.array([ocfg.sigma_x_m, ocfg.sigma_y_m, 1 / np.sqrt(ocfg.mu)]))
    for i in range(len(a)):
        noise = single if b[i] - a[i] == 1 else gtsam.noiseModel.Gaussian.Covariance(cov[i])
        graph.add(gtsam.BetweenFactorPose2(X(a[i]), X(b[i]), gtsam.Pose2(*u[i]), noise))
    return len(a)


def fill_chains(xyt: np.ndarray, raw: np.ndarray, starts: np.ndarray, ends: np.ndarray, kf: np.ndarray) -> np.ndarray:
    """Full (n, 3) poses from solved keyframe rows of ``xyt`` (other rows ignored).

    A step i between keyframes a < i < b is propagated forward from a and backward from b along its PDR
    increments, and the two are blended with weight (i − a) / (b − a) on the backward one: the chain's
    correction spread evenly over its steps (each step has the same odometry noise).
    """
    out = np.array(xyt, dtype=float, copy=True)
    for s, e in zip(starts, ends):
        if e - s < 3:
            continue
        idx = s + np.flatnonzero(kf[s:e])
        nodes = np.arange(s, e)
        pos = np.searchsorted(idx, nodes, side="right") - 1
        a = idx[np.clip(pos, 0, len(idx) - 1)]
        b = idx[np.clip(pos + 1, 0, len(idx) - 1)]
        inner = (nodes != a) & (b > nodes)
        if not inner.any():
            continue
        i, a, b = nodes[inner], a[inner], b[inner]
        fwd = geometry.compose(out[a], geometry.between(raw[a], raw[i]))
        bwd = geometry.compose(out[b], geometry.between(raw[b], raw[i]))
        w = (i - a) / (b - a)
        out[i, :2] = (1 - w)[:, None] * fwd[:, :2] + w[:, None] * bwd[:, :2]
        dth = geometry.wrap(bwd[:, 2] - fwd[:, 2])
        out[i, 2] = geometry.wrap(fwd[:, 2] + w * dth)
    return out
