"""UILoc pieces: RSS filter, least-squares multilateration and the fusion localizer, the self-building map."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.localize.base import Query, make_localizer
from rmbuild.localize.rss_filter import filter_query, kalman_1d, tukey_window_mean
from rmbuild.localize.uiloc import UilocLocalizer, ap_positions, fit_path_loss, multilaterate
from rmbuild.radiomap.reference import ReferenceSet
from rmbuild.radiomap.selfbuild import merge_fingerprints


def test_tukey_drops_an_outlier_and_kalman_converges():
    x = np.array([-60.0] * 9 + [-30.0])  # a spike at the newest sample: outside Q3 + 1.5 IQR (IQR = 0)
    assert tukey_window_mean(x)[-1] == pytest.approx(-60.0)
    x2 = np.c_[x, np.r_[np.nan, -70.0, np.nan, -72.0, -74.0, np.nan, -70.0, -70.0, -72.0, -70.0]]
    out = tukey_window_mean(x2)
    assert np.isnan(out[0, 1]) and out[3, 1] == pytest.approx(-71.0)  # mean of the readings so far
    rng = np.random.default_rng(0)
    z = -65.0 + rng.normal(0, 3.0, 400)
    k = kalman_1d(z)
    assert k[0] == z[0] and abs(k[-50:].mean() + 65.0) < 1.0 and k[-100:].std() < 0.5 * z[-100:].std()
    k2 = kalman_1d(np.r_[-60.0, np.nan, -60.0])
    assert np.isnan(k2[1]) and k2[2] == pytest.approx(-60.0)


def test_filter_query_per_walk_in_time_order():
    rss = np.array([[-50.0], [-80.0], [-50.0], [-80.0]], dtype=np.float32)
    q = Query(rss, np.array(["a"], dtype=object), np.array([0.0, 0.0, 1.0, 1.0]),
              np.array(["w1", "w2", "w1", "w2"], dtype=object), np.full(4, -1))
    f = filter_query(q)
    np.testing.assert_allclose(f.rss_dbm[:, 0], [-50, -80, -50, -80], atol=1e-4)  # walks never mixed


def test_multilaterate_exact_ranges_recover_the_point():
    rng = np.random.default_rng(1)
    anchors = rng.uniform(0, 40, (6, 2))
    p = np.array([12.0, 27.0])
    np.testing.assert_allclose(multilaterate(anchors, np.hypot(*(anchors - p).T)), p, atol=1e-8)
    assert np.isnan(multilaterate(np.array([[0, 0], [1, 0], [2, 0], [3, 0.0]]), np.ones(4))).all()


def _log_distance_map(ap_xy, p0=-35.0, eta=3.0, step=2.0, size=40.0):
    g = np.arange(0, size + 1e-9, step)
    xy = np.array([(x, y) for x in g for y in g])
    d = np.maximum(np.hypot(xy[:, None, 0] - ap_xy[None, :, 0], xy[:, None, 1] - ap_xy[None, :, 1]), 1.0)
    rss = (p0 - 10 * eta * np.log10(d)).astype(np.float32)
    return ReferenceSet(xy, rss, np.array([f"ap{i}" for i in range(len(ap_xy))], dtype=object))


def test_fit_recovers_ap_positions_and_path_loss_on_a_model_map():
    ap = np.array([[4.0, 6.0], [36.0, 8.0], [20.0, 34.0], [6.0, 30.0], [30.0, 24.0]])
    ref = _log_distance_map(ap)
    est = ap_positions(ref)
    assert np.hypot(*(est - ap).T).max() < 1.5
    p0, eta = fit_path_loss(ref, ap)
    assert p0 == pytest.approx(-35.0, abs=0.01) and eta == pytest.approx(3.0, abs=0.001)


def test_uiloc_fuses_towards_the_estimate_nearer_the_strongest_ap():
    ap = np.array([[4.0, 6.0], [36.0, 8.0], [20.0, 34.0], [6.0, 30.0], [30.0, 24.0]])
    ref = _log_distance_map(ap)
    loc = make_localizer("uiloc").fit(ref)
    assert isinstance(loc, UilocLocalizer)
    truth = np.array([[9.0, 11.0], [25.0, 21.0], [15.0, 31.0]])
    d = np.maximum(np.hypot(truth[:, None, 0] - ap[None, :, 0], truth[:, None, 1] - ap[None, :, 1]), 1.0)
    rss = (-35.0 - 30 * np.log10(d)).astype(np.float32)
    q = Query(rss, ref.bssids, np.arange(3.0), np.array(["w"] * 3, dtype=object), np.full(3, -1))
    p = loc.predict(q)
    knn = loc.knn.predict_rss(rss)
    b, o = loc.ls_estimates(rss)
    w = 1 / (1 + np.exp(np.hypot(*(knn - o).T) - np.hypot(*(b - o).T)))  # eq. 15-18
    np.testing.assert_allclose(p, w[:, None] * knn + (1 - w[:, None]) * b)
    assert np.hypot(*(p - truth).T).max() < 3.0 and loc.summary()["ls_share"] == 1.0
    # fewer than 4 heard APs: kNN alone
    rss2 = rss.copy()
    rss2[:, 2:] = np.nan
    q2 = Query(rss2, ref.bssids, np.arange(3.0), q.walk_id, q.node)
    np.testing.assert_allclose(loc.predict(q2), loc.knn.predict_rss(rss2))


def test_merge_within_one_metre_averages_else_inserts():
    b = np.array(["a", "b"], dtype=object)
    ref = merge_fingerprints(None, [[0.0, 0.0]], [[-50.0, np.nan]], b)
    ref = merge_fingerprints(ref, [[0.8, 0.0], [3.0, 0.0], [0.0, 0.5]],
                             [[-60.0, -70.0], [-40.0, -40.0], [-55.0, np.nan]], b)
    assert len(ref) == 2 and ref.kind == "nodes"
    np.testing.assert_allclose(ref.xy, [[0.8 / 3, 0.5 / 3], [3.0, 0.0]])
    np.testing.assert_allclose(ref.rss_dbm, [[-55.0, -70.0], [-40.0, -40.0]])
    np.testing.assert_array_equal(ref.count, [[3, 1], [1, 1]])
    # order does not matter for one cluster; beyond the radius nothing merges
    rev = merge_fingerprints(None, [[0.0, 0.5], [0.8, 0.0], [0.0, 0.0]],
                             [[-55.0, np.nan], [-60.0, -70.0], [-50.0, np.nan]], b)
    np.testing.assert_allclose(rev.rss_dbm, ref.rss_dbm[:1])
    far = merge_fingerprints(None, [[0.0, 0.0], [1.01, 0.0]], [[-50.0, -50.0]] * 2, b)
    assert len(far) == 2
    with pytest.raises(ValueError, match="columns"):
        merge_fingerprints(ref, [[0.0, 0.0]], [[-50.0]], b[:1])
