"""Chain reduction (slam/chains.py): keyframes, composed odometry and its covariance, putting steps back."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from rmbuild.config.optimize import OdometryConfig  # noqa: E402
from rmbuild.geometry import compose as compose_se2  # noqa: E402
from rmbuild.slam.chains import (  # noqa: E402
    add_chain_odometry,
    chain_covariances,
    fill_chains,
    keyframe_mask,
)
from rmbuild.slam.factors import X, add_odometry, poses_to_values, values_to_poses  # noqa: E402

OC = OdometryConfig()


def _walk(n: int, seed: int, start=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A PDR-like walk of n poses: ~0.7 m steps, turning now and then."""
    rng = np.random.default_rng(seed)
    p = [gtsam.Pose2(*start)]
    for k in range(n - 1):
        turn = rng.normal(0, 0.05) + (np.pi / 2 if k % 23 == 22 else 0.0)
        p.append(p[-1].compose(gtsam.Pose2(0.7 + rng.normal(0, 0.03), rng.normal(0, 0.02), turn)))
    return np.array([[q.x(), q.y(), q.theta()] for q in p])


def test_keyframe_mask_keeps_required_ends_and_max_gap():
    starts, ends = np.array([0, 50]), np.array([50, 120])
    req = np.zeros(120, bool)
    req[[7, 8, 90]] = True
    kf = keyframe_mask(120, starts, ends, req, max_gap=10)
    assert kf[[0, 7, 8, 49, 50, 90, 119]].all()
    for s, e in zip(starts, ends):
        idx = s + np.flatnonzero(kf[s:e])
        assert np.diff(idx).max() <= 10
    assert kf.sum() < 40  # ~one node in ten, not every step
    assert keyframe_mask(120, starts, ends, req, max_gap=1).all()


def test_chain_covariance_is_the_marginal_of_the_step_chain():
    raw = _walk(30, 1)
    g = gtsam.NonlinearFactorGraph()
    add_odometry(g, raw, np.array([0]), np.array([30]), OC)
    g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*raw[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    marg = gtsam.Marginals(g, poses_to_values(raw)).marginalCovariance(X(29))
    cov = chain_covariances(raw, np.array([0]), np.array([29]), OC)[0]
    np.testing.assert_allclose(cov, marg, rtol=1e-4, atol=1e-9)
    # the chain's own spread after 29 steps (the heading noise's lever arm), not the 5 cm of one step
    assert 0.3 < np.sqrt(cov[0, 0]) < 3.0


def test_reduced_solve_matches_the_full_graph():
    """Two walks tied by range factors and heading priors: the keyframe solve plus fill_chains gives the
    poses of the per-step solve to millimetres, with a fraction of the variables."""
    a = _walk(80, 2)
    b = compose_se2(np.array([3.0, -2.0, 0.4]), _walk(70, 3))
    raw = np.vstack([a, b])
    starts, ends = np.array([0, 80]), np.array([80, 150])
    rng = np.random.default_rng(4)
    # the solve starts from b turned and shifted away from where its pairs put it
    init = raw.copy()
    init[80:] = compose_se2(np.array([1.5, 1.0, 0.08]), b)
    pairs = list(zip(rng.choice(80, 12, replace=False).tolist(), (80 + rng.choice(70, 12, replace=False)).tolist()))
    heading = list(range(0, 150, 10))

    def solve(kf):
        g = gtsam.NonlinearFactorGraph()
        add_chain_odometry(g, raw, starts, ends, kf, OC)
        g.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*raw[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
        for i, j in pairs:  # range to the true distance, so the solution is the truth up to noise
            d = float(np.hypot(*(raw[i, :2] - raw[j, :2])))
            g.add(gtsam.RangeFactorPose2(X(i), X(j), d, gtsam.noiseModel.Isotropic.Sigma(1, 0.3)))
        hnoise = gtsam.noiseModel.Isotropic.Sigma(1, 0.1)
        for i in heading:
            g.add(gtsam.PoseRotationPrior2D(X(i), gtsam.Pose2(0, 0, raw[i, 2]), hnoise))
        idx = np.flatnonzero(kf)
        v = gtsam.LevenbergMarquardtOptimizer(g, poses_to_values(init[idx], nodes=idx)).optimize()
        full = np.zeros_like(raw)
        full[idx] = values_to_poses(v, nodes=idx)
        return fill_chains(full, raw, starts, ends, kf), len(idx)

    req = np.zeros(150, bool)
    req[[i for p in pairs for i in p] + heading] = True
    full, n_full = solve(np.ones(150, bool))
    red, n_red = solve(keyframe_mask(150, starts, ends, req, max_gap=20))
    assert n_red < 0.5 * n_full
    assert np.abs(full[80:, :2] - init[80:, :2]).max() > 1.0  # the solve did move walk b
    np.testing.assert_allclose(red[:, :2], full[:, :2], atol=5e-3)
    np.testing.assert_allclose(np.angle(np.exp(1j * (red[:, 2] - full[:, 2]))), 0, atol=1e-3)


def test_fill_chains_puts_rigidly_moved_steps_back_exactly():
    raw = _walk(60, 5)
    kf = np.zeros(60, bool)
    kf[[0, 17, 40, 59]] = True
    moved = compose_se2(np.array([10.0, -4.0, 1.1]), raw)
    only_kf = np.where(kf[:, None], moved, np.nan)
    out = fill_chains(only_kf, raw, np.array([0]), np.array([60]), kf)
    np.testing.assert_allclose(out, moved, atol=1e-9)
