"""kNN / weighted kNN against scikit-learn and brute force; the localizer protocol, registry and Query."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rmbuild.config.evaluate import EvaluateConfig, KnnConfig
from rmbuild.errors import InputError
from rmbuild.localize import LOCALIZERS, Localizer, Query, ReferenceSet, make_localizer
from rmbuild.localize.knn import KnnLocalizer, WeightedKnnLocalizer


def _random_ref(n_rp=300, n_q=80, n_ap=40, p_seen=0.35, seed=0):
    rng = np.random.default_rng(seed)
    rss = rng.uniform(-95, -35, (n_rp, n_ap)).astype(np.float32)
    rss[rng.random((n_rp, n_ap)) > p_seen] = np.nan
    q = rng.uniform(-95, -35, (n_q, n_ap)).astype(np.float32)
    q[rng.random((n_q, n_ap)) > p_seen] = np.nan
    xy = rng.uniform(0, 100, (n_rp, 2))
    bssids = np.array([f"ap{j:02d}" for j in range(n_ap)], dtype=object)
    return ReferenceSet(xy, rss, bssids), q


def _filled(a, fill=-110.0):
    return np.where(np.isnan(a), fill, a).astype(np.float64)


@pytest.mark.parametrize("k", [1, 5, 15])
def test_knn_equals_sklearn(k):
    from sklearn.neighbors import KNeighborsRegressor

    ref, q = _random_ref()
    loc = KnnLocalizer(KnnConfig(k=k)).fit(ref)
    dist, idx = loc.kneighbors(q)
    sk = KNeighborsRegressor(n_neighbors=k, algorithm="brute").fit(_filled(ref.rss_dbm), ref.xy)
    sd, si = sk.kneighbors(_filled(q))
    np.testing.assert_array_equal(idx, si)
    np.testing.assert_allclose(dist, sd, rtol=1e-9, atol=1e-7)
    np.testing.assert_allclose(loc.predict_rss(q), sk.predict(_filled(q)), atol=1e-9)


def test_weighted_knn_equals_sklearn_distance_weights():
    from sklearn.neighbors import KNeighborsRegressor

    ref, q = _random_ref(seed=1)
    q[3] = ref.rss_dbm[7]  # an exact match: sklearn then uses only the zero-distance neighbours
    loc = WeightedKnnLocalizer(KnnConfig(k=7)).fit(ref)
    sk = KNeighborsRegressor(n_neighbors=7, algorithm="brute", weights="distance")
    sk.fit(_filled(ref.rss_dbm), ref.xy)
    np.testing.assert_allclose(loc.predict_rss(q), sk.predict(_filled(q)), atol=1e-9)
    np.testing.assert_allclose(loc.predict_rss(q)[3], ref.xy[7])


def test_weighted_by_hand():
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [50.0, 50.0]])
    rss = np.array([[-50.0], [-60.0], [-90.0]], dtype=np.float32)
    ref = ReferenceSet(xy, rss, np.array(["a"], dtype=object))
    loc = WeightedKnnLocalizer(KnnConfig(k=2)).fit(ref)
    p = loc.predict_rss(np.array([[-52.0]], dtype=np.float32))
    w = np.array([1 / 2.0, 1 / 8.0])
    np.testing.assert_allclose(p[0], (w[:, None] * xy[:2]).sum(0) / w.sum())
    plain = KnnLocalizer(KnnConfig(k=2)).fit(ref).predict_rss(np.array([[-52.0]], dtype=np.float32))
    np.testing.assert_allclose(plain[0], [5.0, 0.0])


def _brute(ref, q, missing, metric, fill=-110.0, min_shared=1):
    d = np.empty((len(q), len(ref)))
    for i, a in enumerate(q.astype(np.float64)):
        for j, b in enumerate(ref.rss_dbm.astype(np.float64)):
            ba, bb = ~np.isnan(a), ~np.isnan(b)
            if missing == "fill":
                s = ((np.where(ba, a, fill) - np.where(bb, b, fill)) ** 2).sum()
                d[i, j] = np.sqrt(s / max((ba | bb).sum(), 1) if metric == "rms" else s)
            else:
                sh = ba & bb
                d[i, j] = np.sqrt(((a[sh] - b[sh]) ** 2).sum() / sh.sum()) if sh.sum() >= min_shared else np.inf
    return d


@pytest.mark.parametrize("missing,metric", [("fill", "rms"), ("exclude", "euclidean"), ("fill", "euclidean")])
def test_distance_modes_match_brute_force(missing, metric):
    ref, q = _random_ref(n_rp=60, n_q=15, n_ap=12, seed=2)
    cfg = KnnConfig(k=4, missing=missing, metric=metric, min_shared_aps=2)
    dist, idx = KnnLocalizer(cfg).fit(ref).kneighbors(q)
    d = _brute(ref, q, missing, metric, min_shared=2)
    want = np.sort(d, axis=1)[:, :4]
    np.testing.assert_allclose(dist, want, rtol=1e-9, atol=1e-6)
    got = np.take_along_axis(d, np.maximum(idx, 0), axis=1)
    np.testing.assert_allclose(np.where(idx >= 0, got, np.inf), want, rtol=1e-9, atol=1e-6)


def test_exclude_with_no_shared_ap_gives_nan():
    xy = np.array([[0.0, 0.0], [1.0, 1.0]])
    rss = np.array([[-50.0, np.nan], [-60.0, np.nan]], dtype=np.float32)
    ref = ReferenceSet(xy, rss, np.array(["a", "b"], dtype=object))
    loc = KnnLocalizer(KnnConfig(k=2, missing="exclude")).fit(ref)
    p = loc.predict_rss(np.array([[np.nan, -40.0], [-55.0, np.nan]], dtype=np.float32))
    assert np.isnan(p[0]).all()
    np.testing.assert_allclose(p[1], [0.5, 0.5])


def test_k_larger_than_reference_and_blocks():
    ref, q = _random_ref(n_rp=5, n_q=3, n_ap=6)
    p = KnnLocalizer(KnnConfig(k=15)).fit(ref).predict_rss(q)
    np.testing.assert_allclose(p, np.repeat(ref.xy.mean(0)[None], 3, axis=0))


def test_registry_protocol_and_query_alignment():
    assert {"knn", "wknn"} <= set(LOCALIZERS)
    cfg = EvaluateConfig(knn=KnnConfig(k=2))
    loc = make_localizer("wknn", cfg)
    assert isinstance(loc, Localizer) and loc.name == "wknn" and loc.cfg.k == 2
    with pytest.raises(InputError, match="unknown localizer"):
        make_localizer("nope", cfg)
    ref, qr = _random_ref(n_rp=30, n_q=4, n_ap=5)
    # a query with the columns in another order and an AP the map does not know
    perm = np.array([4, 2, 0, 1, 3])
    extra = np.full((4, 1), -40.0, dtype=np.float32)
    query = Query(np.hstack([qr[:, perm], extra]), np.r_[ref.bssids[perm], ["zz"]].astype(object),
                  np.arange(4.0), np.array(["w"] * 4, dtype=object), np.full(4, -1))
    loc = make_localizer("knn", cfg).fit(ref)
    np.testing.assert_allclose(loc.predict(query), loc.predict_rss(qr))


def test_query_from_dataset_scans_steps_and_walk_order():
    from rmbuild.types import Dataset

    poses = pd.DataFrame({
        "walk_id": ["b"] * 3 + ["a"] * 3, "step": [0, 1, 2] * 2, "t_s": [0.0, 1.0, 2.0] * 2,
        "x_m": [0, 1, 2, 0, 0, 0.0], "y_m": [0, 0, 0, 0, 2, 4.0], "heading_rad": [0, 0, 0, 1.57, 1.57, 1.57],
        "step_freq_hz": [1.5] * 6,
    })
    wifi = pd.DataFrame({
        "walk_id": ["b", "b", "b", "a", "a"], "t_s": [1.1, 1.1, 0.1, 2.1, 0.1],
        "bssid": ["x", "y", "x", "y", "y"], "rssi_dbm": [-50.0, -60, -55, -70, -65],
        "node": [1, 1, 0, 5, 3],
    })
    walks = pd.DataFrame({"walk_id": ["b", "a"], "role": ["", ""]})
    ds = Dataset(walks, poses, wifi, pd.DataFrame(columns=["walk_id", "t_s", "x_m", "y_m", "label"]))
    q = Query.from_dataset(ds, ["b", "a"], np.array(["x", "y"], dtype=object))
    assert list(q.walk_id) == ["b", "b", "a", "a"]
    np.testing.assert_allclose(q.t_s, [0.1, 1.1, 0.1, 2.1])
    assert q.node.tolist() == [0, 1, 3, 5]
    np.testing.assert_allclose(q.rss_dbm, [[-55, np.nan], [-50, -60], [np.nan, -65], [np.nan, -70]])
    assert [w for w, _ in q.walks()] == ["b", "a"]
    st = q.steps["a"]
    assert list(st.columns) == ["t_s", "step_length_m", "heading_rad", "step_freq_hz"]
    np.testing.assert_allclose(st.step_length_m, [2.0, 2.0])
