"""Trajectory metrics: SE(2) alignment, ATE, landmark and heading alignment errors."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from rmbuild.evaluate.trajectory import (
    align_se2,
    ate,
    heading_alignment_error_deg,
    landmark_error_unlinked_at_raw,
    trajectory_metrics,
)


def _rot(t):
    return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])


def test_align_se2_recovers_transform():
    rng = np.random.default_rng(0)
    src = rng.normal(0, 10, (50, 2))
    R, t = _rot(0.7), np.array([3.0, -2.0])
    r, tt = align_se2(src, src @ R.T + t)
    np.testing.assert_allclose(r, R, atol=1e-10)
    np.testing.assert_allclose(tt, t, atol=1e-10)


def test_ate_aligned_is_zero_for_rigid_copy():
    rng = np.random.default_rng(1)
    xy = rng.normal(0, 10, (30, 2))
    m = ate(xy @ _rot(1.0).T + 5, xy, align=True)
    assert m["rmse"] < 1e-9 and set(m) == {"rmse", "mean", "median", "max"}
    assert abs(ate(xy + 1.0, xy, align=False)["mean"] - math.sqrt(2)) < 1e-12


def _two_walks(turn_deg: float):
    t = np.arange(20.0)
    tru = pd.DataFrame({"walk_id": ["a"] * 20 + ["b"] * 20, "step": np.r_[t, t], "t_s": np.r_[t, t + 100],
                        "x_m": np.r_[t, t], "y_m": np.r_[np.zeros(20), t], "heading_rad": 0.0})
    est = tru.copy()
    b = est["walk_id"] == "b"
    xy = est.loc[b, ["x_m", "y_m"]].to_numpy() @ _rot(math.radians(turn_deg)).T
    est.loc[b, "x_m"], est.loc[b, "y_m"] = xy[:, 0], xy[:, 1]
    return est, tru


def test_heading_alignment_error():
    est, tru = _two_walks(0.0)
    assert heading_alignment_error_deg(est, tru)["mean"] < 1e-9
    est, tru = _two_walks(4.0)
    h = heading_alignment_error_deg(est, tru, np.eye(2))
    assert abs(h["mean"] - 2.0) < 1e-6  # walk a: 0 deg, walk b: 4 deg


def test_trajectory_metrics_shape_and_nulls():
    est, tru = _two_walks(0.0)
    fixes = pd.DataFrame({"walk_id": ["a", "b"], "t_s": [5.5, 110.0], "x_m": [5.5, 10.0], "y_m": [0.0, 10.0],
                          "label": ["l1", "l2"]})
    ds = SimpleNamespace(truth_poses=tru, fixes=fixes)
    m = trajectory_metrics(est, ds)
    assert set(m) == {"ate_m", "landmark_error_m", "heading_alignment_error_deg"}
    assert m["landmark_error_m"]["n"] == 2 and m["landmark_error_m"]["mean"] < 1e-9
    m = trajectory_metrics(est, SimpleNamespace(truth_poses=None, fixes=fixes.iloc[:0]))
    assert m == {"ate_m": None, "landmark_error_m": None, "heading_alignment_error_deg": None}


def test_alignment_fitted_on_the_named_walks_only():
    """A walk the optimiser could not place sits in an arbitrary frame: fitted on the other walks, the
    alignment leaves their figures exact and that walk's error counts in full; fitted on all walks, it
    spreads that walk's offset over everyone."""
    est, tru = _two_walks(0.0)
    est = est.copy()
    b = est["walk_id"] == "b"
    est.loc[b, "x_m"] += 40.0  # walk b dropped 40 m away
    fixes = pd.DataFrame({"walk_id": ["a", "b"], "t_s": [5.5, 110.0], "x_m": [5.5, 10.0], "y_m": [0.0, 10.0]})
    ds = SimpleNamespace(truth_poses=tru, fixes=fixes)
    fit_a = trajectory_metrics(est, ds, fit_walks=["a"])
    fit_all = trajectory_metrics(est, ds)
    err_a = np.linalg.norm(est.loc[~b, ["x_m", "y_m"]].to_numpy() - tru.loc[~b, ["x_m", "y_m"]].to_numpy(), axis=1)
    assert err_a.max() < 1e-9
    assert fit_a["landmark_error_m"]["mean"] == pytest.approx(20.0, abs=1e-6)  # (0 + 40) / 2
    # the named walks' own landmark error, reported beside: walk a alone is exact
    assert fit_a["landmark_error_fitted_walks_m"]["n"] == 1 and fit_a["landmark_error_fitted_walks_m"]["mean"] < 1e-6
    assert "landmark_error_fitted_walks_m" not in fit_all
    assert fit_a["ate_m"]["max"] == pytest.approx(40.0, abs=1e-6)
    assert fit_a["heading_alignment_error_deg"]["mean"] < 1e-6
    # fitted on all walks, walk a is moved too: its landmark is no longer exact
    assert fit_all["ate_m"]["median"] > 5.0


def test_unlinked_walks_count_at_their_raw_placement():
    """'Never worse than raw' is judged with the unlinked walks where dead reckoning alone puts them: the
    optimiser's arbitrary frame for walk c (40 m off) must not count, its raw placement (exact here) does."""
    t = np.arange(20.0)
    raw = pd.DataFrame({"walk_id": np.repeat(["a", "b", "c"], 20), "step": np.tile(t, 3),
                        "t_s": np.r_[t, t + 100, t + 200], "x_m": np.tile(t, 3),
                        "y_m": np.r_[np.zeros(20), np.full(20, 10.0), np.full(20, 20.0)], "heading_rad": 0.0})
    opt = raw.copy()
    opt.loc[opt["walk_id"] == "c", "x_m"] += 40.0
    fixes = pd.DataFrame({"walk_id": ["a", "a", "b", "b", "c", "c"], "t_s": [2.0, 15.0, 102.0, 115.0, 202.0, 215.0],
                          "x_m": [2.0, 15.0, 2.0, 15.0, 2.0, 15.0], "y_m": [0.0, 0.0, 10.0, 10.0, 20.0, 20.0]})
    ds = SimpleNamespace(truth_poses=None, fixes=fixes)
    m = landmark_error_unlinked_at_raw(raw, opt, ds, ["a", "b"])
    assert m["n"] == 6 and m["mean"] < 1e-9
    assert trajectory_metrics(opt, ds, fit_walks=["a", "b"])["landmark_error_m"]["mean"] == pytest.approx(40 / 3)
    # a linked walk placed badly counts as optimised: walk b 3 m off, the fit on a and b shares it out
    opt.loc[opt["walk_id"] == "b", "y_m"] += 3.0
    m = landmark_error_unlinked_at_raw(raw, opt, ds, ["a", "b"])
    assert m["mean"] == pytest.approx(1.5 * 4 / 6, abs=1e-6)
    assert landmark_error_unlinked_at_raw(raw, opt, ds, ["a", "b", "c"]) is None  # all linked: nothing to add
    assert landmark_error_unlinked_at_raw(raw, opt, SimpleNamespace(fixes=fixes.iloc[:0]), ["a"]) is None


def test_walk_grouping_keeps_each_walks_rows_in_order():
    from rmbuild.evaluate.trajectory import named, walk_rows

    ids = pd.Series(["b", "a", "b", "c", "a", "b"])
    rows = walk_rows(ids)
    assert list(rows) == ["b", "a", "c"]  # first appearance
    assert [r.tolist() for r in rows.values()] == [[0, 2, 5], [1, 4], [3]]
    assert named(ids, ["a", "c"]).tolist() == [False, True, False, True, True, False]


def test_metrics_do_not_depend_on_walks_being_contiguous():
    est, tru = _two_walks(4.0)
    order = np.r_[np.arange(0, 40, 2), np.arange(1, 40, 2)]  # the two walks' rows interleaved
    a = heading_alignment_error_deg(est, tru, np.eye(2))
    b = heading_alignment_error_deg(est.iloc[order].reset_index(drop=True), tru.iloc[order].reset_index(drop=True),
                                    np.eye(2))
    assert a == pytest.approx(b, abs=1e-12)
