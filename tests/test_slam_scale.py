"""Per-walk step-length scale (odometry.estimate_scale): a walk whose PDR is 20 % too long gets s_w ~ 1/1.2."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("gtsam")

from slam_venue import make_venue  # noqa: E402

from rmbuild.config.optimize import OdometryConfig, OptimizeConfig  # noqa: E402
from rmbuild.slam import (  # noqa: E402
    optimize,  # noqa: E402
    scale,
    schedule,
)
from rmbuild.slam.scale import fit_stretch, increment_scale, scaled_raw  # noqa: E402


def _stretched_venue(factor: float, walk: str = "w002"):
    ds, fp = make_venue(n_walks=5, steps_per_walk=260, seed=3, pdr_scale_sigma=0.0)
    poses = ds.poses.copy()
    m = poses["walk_id"] == walk
    for c in ("x_m", "y_m"):
        v = poses.loc[m, c].to_numpy()
        poses.loc[m, c] = v[0] + factor * (v - v[0])
    return dataclasses.replace(ds, poses=poses), fp


def test_scaled_walk_recovered():
    ds, fp = _stretched_venue(1.2)
    cfg = OptimizeConfig(odometry=OdometryConfig(estimate_scale=True))
    r = optimize(ds, fp, cfg)
    w = r.walks.set_index("walk_id")
    assert w.loc["w002", "scale_fitted"]
    assert w.loc["w002", "scale"] == pytest.approx(1 / 1.2, rel=0.05)
    others = w.drop(index="w002")
    # a walk sharing most of its path with the stretched one absorbs some of it (measured: 0.93)
    assert np.all(np.abs(others.loc[others["scale_fitted"], "scale"] - 1) < 0.1)
    assert r.stats["scale"]["estimated"]


def test_scale_off_reports_ones():
    ds, fp = make_venue(n_walks=3, steps_per_walk=120, seed=1)
    r = optimize(ds, fp, OptimizeConfig(odometry=OdometryConfig(estimate_scale=False)))
    assert np.all(r.walks["scale"] == 1.0)
    assert not r.walks["scale_fitted"].any()
    assert not r.stats["scale"]["estimated"]


def test_short_span_is_not_fitted(monkeypatch):
    """Pairs spread over less than SCALE_MIN_SPAN_M leave s_w at 1 (a few metres of pair spread would
    swamp a few per cent of stretch)."""
    rng = np.random.default_rng(1)
    a = rng.uniform(-10, 10, (60, 2))
    f = fit_stretch(a, 1.1 * a, 1.0)
    assert not f.ok and f.ratio == 1.0
    monkeypatch.setattr(scale, "SCALE_MIN_SPAN_M", 20.0)
    assert fit_stretch(a, 1.1 * a, 1.0).ok


def test_closed_form_helpers(monkeypatch):
    rng = np.random.default_rng(0)
    th = np.cumsum(rng.normal(0, 0.1, 50))
    xy = np.cumsum(np.c_[0.7 * np.cos(th), 0.7 * np.sin(th)], axis=0)
    raw = np.c_[xy, th]
    out = scaled_raw(raw, np.array([0]), np.array([50]), np.array([0.8]))
    assert increment_scale(raw, out) == pytest.approx(0.8, rel=1e-9)
    a = rng.uniform(-20, 20, (60, 2))
    b = 3.0 + 1.1 * a + rng.normal(0, 1.0, a.shape)
    monkeypatch.setattr(scale, "SCALE_PRIOR_SIGMA", 10.0)
    monkeypatch.setattr(scale, "SCALE_MIN_SPAN_M", 15.0)
    f = fit_stretch(a, b, 1.0)
    assert f.ok and f.ratio == pytest.approx(1.1, abs=0.02)


def test_rounds_extend_while_the_scale_still_moves(monkeypatch):
    """Rounds beyond the first two run while the last one moved some s_w by more than SCALE_EXTEND_MOVE,
    and bring a 20 % stretch closer to its truth than the fixed two rounds."""
    ds, fp = _stretched_venue(1.2)
    monkeypatch.setattr(schedule, "SCALE_ROUNDS_MAX", 2)
    fixed = optimize(ds, fp, OptimizeConfig())
    monkeypatch.setattr(schedule, "SCALE_ROUNDS_MAX", 8)
    monkeypatch.setattr(schedule, "SCALE_EXTEND_MOVE", 0.005)
    extended = optimize(ds, fp, OptimizeConfig())
    assert fixed.stats["scale"]["rounds"] == 2
    assert 2 < extended.stats["scale"]["rounds"] <= 8
    err = {name: abs(r.walks.set_index("walk_id").loc["w002", "scale"] - 1 / 1.2)
           for name, r in (("fixed", fixed), ("extended", extended))}
    assert err["extended"] < 0.6 * err["fixed"]
