"""UILoc pieces: least-squares multilateration and the fusion localizer, the self-building map."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.baselines.selfbuild import merge_fingerprints
from rmbuild.baselines.uiloc import UilocLocalizer, ap_positions, fit_path_loss, multilaterate
from rmbuild.localize.base import Query, make_localizer
from rmbuild.radiomap.reference import ReferenceSet


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
