"""Keys/Values round trip and the fuzzy vicinity factor (eq. 10) as a truncated range factor."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from rmbuild import geometry  # noqa: E402
from rmbuild.config.optimize import WifiConfig  # noqa: E402
from rmbuild.slam.factors import (  # noqa: E402
    X,
    fuzzy_cost,
    fuzzy_error,
    poses_to_values,
    values_to_poses,
    vicinity_factor,
)


def test_values_round_trip():
    rng = np.random.default_rng(0)
    p = np.c_[rng.normal(0, 50, (200, 2)), rng.uniform(-np.pi, np.pi, 200)]
    back = values_to_poses(poses_to_values(p), len(p))
    np.testing.assert_allclose(back[:, :2], p[:, :2], atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back[:, 2] - p[:, 2]))), 0, atol=1e-12)
    assert poses_to_values(p).exists(X(199)) and not poses_to_values(p).exists(X(200))


def test_increments_match_gtsam_between():
    rng = np.random.default_rng(1)
    p = np.c_[rng.normal(0, 5, (20, 2)), rng.uniform(-3, 3, 20)]
    u = geometry.increments(p)
    for k in range(19):
        b = gtsam.Pose2(*p[k]).between(gtsam.Pose2(*p[k + 1]))
        np.testing.assert_allclose(u[k], [b.x(), b.y(), b.theta()], atol=1e-9)


def test_fuzzy_error_is_eq10():
    vc = WifiConfig(d_min=2.0, d_max=30.0)
    d = np.array([0.0, 1.99, 2.0, 16.0, 30.0, 45.0])
    np.testing.assert_allclose(fuzzy_error(d, vc), [0, 0, 0, 14 / 28, 1, 1])


def test_factor_error_matches_eq10():
    vc = WifiConfig(d_min=2.0, d_max=30.0, omega=3.0)
    for d in [0.0, 1.0, 2.0, 2.5, 10.0, 29.9, 30.0, 31.0, 100.0]:
        v = gtsam.Values()
        v.insert(X(0), gtsam.Pose2(1.0, 2.0, 0.3))
        v.insert(X(1), gtsam.Pose2(1.0 + d * np.cos(0.7), 2.0 + d * np.sin(0.7), -1.0))
        err = vicinity_factor(0, 1, vc).error(v)
        want = float(fuzzy_cost(np.array([d]), vc)[0])
        if d >= vc.d_min:
            assert err == pytest.approx(want, abs=1e-9), d
        else:  # a tiny push-apart below d_min (documented)
            assert err <= 0.01 * 0.5 * vc.omega + 1e-12
