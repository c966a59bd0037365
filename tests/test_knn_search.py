"""The sparse kNN shortlist: the same neighbour sets as scikit-learn's float64 brute force (exact ties aside)
on random and on path-loss-like data, batch and one query at a time; the selection's keys; the float32
values used without a re-rank only where they are exact."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.config.evaluate import KnnConfig
from rmbuild.localize import ReferenceSet, knn_search
from rmbuild.localize.knn import KnnLocalizer
from rmbuild.localize.knn_search import key_values, morton_order, sort_keys

FILL = -110.0


def _field(n_rp=1500, n_q=150, n_ap=80, seed=0, integer=True):
    """RPs on a 240 x 120 m floor, log-distance path loss from random APs, detection above -90 dBm (a scan
    sees ~1/5 of the APs); one RP in four repeats its neighbour's scan (consecutive map nodes between two scans
    do), which with integer dBm makes exact distance ties common."""
    rng = np.random.default_rng(seed)
    aps = rng.uniform([0, 0], [240, 120], (n_ap, 2))

    def scans(xy):
        d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1)) + 1.0
        rss = -30.0 - 35.0 * np.log10(d) + rng.normal(0, 4, d.shape)
        rss = np.round(rss) if integer else rss
        return np.where(rss > -90.0, rss, np.nan)

    xy = rng.uniform([0, 0], [240, 120], (n_rp, 2))
    qxy = rng.uniform([0, 0], [240, 120], (n_q, 2))
    bssids = np.array([f"ap{j:03d}" for j in range(n_ap)], dtype=object)
    rss = scans(xy)
    if integer:
        rss[1::4] = rss[0::4][: len(rss[1::4])]
    return ReferenceSet(xy, rss, bssids), scans(qxy)


def _random(n_rp=1200, n_q=120, n_ap=60, seed=1):
    rng = np.random.default_rng(seed)
    rss = rng.uniform(-95, -35, (n_rp, n_ap))
    rss[rng.random(rss.shape) > 0.15] = np.nan
    q = rng.uniform(-95, -35, (n_q, n_ap))
    q[rng.random(q.shape) > 0.15] = np.nan
    xy = rng.uniform(0, 100, (n_rp, 2))
    xy[:5] = np.nan  # RPs without a finite position still take part
    return ReferenceSet(xy, rss, np.array([f"a{j}" for j in range(n_ap)], dtype=object)), q


def _brute_d2(ref, q):
    a = np.where(np.isnan(ref.rss_dbm), FILL, ref.rss_dbm)
    b = np.where(np.isnan(q), FILL, q)
    return ((b[:, None, :] - a[None]) ** 2).sum(axis=2)


def _check_sets(ref, q, k, one_at_a_time=False):
    """Neighbour sets equal the brute force's, except where the K-th and (K+1)-th distances tie exactly."""
    loc = KnnLocalizer(KnnConfig(k=k)).fit(ref)
    if one_at_a_time:
        idx = np.vstack([loc.kneighbors(q[i:i + 1])[1] for i in range(len(q))])
    else:
        idx = loc.kneighbors(q)[1]
    d2 = _brute_d2(ref, q)
    srt = np.sort(d2, axis=1)
    n_tied = 0
    for i in range(len(q)):
        want = set(np.argsort(d2[i], kind="stable")[:k].tolist())
        if srt[i, k - 1] == srt[i, k]:  # a tie at the boundary: any choice among the tied RPs is right
            n_tied += 1
            assert np.all(d2[i, idx[i]] <= srt[i, k - 1])
        else:
            assert set(idx[i].tolist()) == want, i
    return n_tied


@pytest.mark.parametrize("k", [1, 15])
def test_random_sets_equal_brute_force_batch_and_single(k):
    ref, q = _random()
    assert _check_sets(ref, q, k) == 0
    assert _check_sets(ref, q[:20], k, one_at_a_time=True) == 0


def test_path_loss_sets_equal_brute_force_with_ties(monkeypatch):
    ref, q = _field()
    monkeypatch.setattr(knn_search, "CHUNK_ELEMS", 40 * 1504)  # several chunks of 40 queries, two threads
    n_tied = _check_sets(ref, q, 15)
    assert 0 < n_tied < len(q)
    _check_sets(ref, q[:10], 15, one_at_a_time=True)
    ref, q = _field(integer=False, seed=3)
    assert _check_sets(ref, q, 15) == 0


def test_distances_match_sklearn():
    from sklearn.neighbors import NearestNeighbors

    ref, q = _field(integer=False, seed=4)
    dist, idx = KnnLocalizer(KnnConfig(k=15)).fit(ref).kneighbors(q)
    sd, si = NearestNeighbors(n_neighbors=15).fit(np.where(np.isnan(ref.rss_dbm), FILL, ref.rss_dbm)).kneighbors(
        np.where(np.isnan(q), FILL, q))
    np.testing.assert_array_equal(idx, si)
    np.testing.assert_allclose(dist, sd, rtol=1e-9)


def test_sort_keys_order_like_values_then_index_and_decode():
    rng = np.random.default_rng(5)
    x = rng.integers(-4, 5, (200, 40)).astype(np.float32) * np.float32(0.75)  # ties at every rank, signs
    x[:, :3] = [np.inf, -0.0, 0.0]  # (-0 orders before +0)
    x[:, 3] = rng.normal(0, 1e30, 200)
    keys = sort_keys(x, np.arange(40))
    np.testing.assert_array_equal(key_values(keys), x)
    np.testing.assert_array_equal(keys & 0xFFFFFFFF, np.broadcast_to(np.arange(40), x.shape))
    o = np.argsort(keys, axis=1)
    np.testing.assert_array_equal(o, np.lexsort((np.broadcast_to(np.arange(40), x.shape), x + 0.0), axis=1))


def test_float32_shortlist_used_only_where_exact():
    """Integer dBm: the shortlist's float32 values are exact, so the batch returns the float64 brute force's
    distances to the last bit without a re-rank; entries of RPs with a non-integer value (a mean) are
    re-ranked in float64."""
    ref, q = _field(seed=8)
    loc = KnnLocalizer(KnnConfig(k=15)).fit(ref)
    sl = loc._shortlist
    a, _ = loc._prep_query(q)
    cand, _ = sl.select(a, 23)
    assert sl.exact(a, cand).all()
    dist, idx = loc.kneighbors(q)
    d2 = _brute_d2(ref, q)
    np.testing.assert_array_equal(dist, np.sqrt(np.sort(d2, axis=1)[:, :15]))
    np.testing.assert_array_equal(dist, np.sqrt(np.take_along_axis(d2, idx, axis=1)))
    rss = ref.rss_dbm.copy()
    rss[::7] += 0.25  # every 7th RP a non-integer fingerprint: its entries re-ranked in float64
    mixed = ReferenceSet(ref.xy, rss, ref.bssids)
    loc = KnnLocalizer(KnnConfig(k=15)).fit(mixed)
    cand, _ = loc._shortlist.select(a, 23)
    ok = loc._shortlist.exact(a, cand)
    assert 0 < ok.sum() < ok.size and ok.all(axis=1).any()
    _check_sets(mixed, q, 15)
    qf = q + 0.5  # non-integer queries: none exact
    assert not loc._shortlist.exact(loc._prep_query(qf)[0], cand).any()
    _check_sets(mixed, qf, 15)


def test_morton_order_is_a_permutation_and_local():
    rng = np.random.default_rng(6)
    xy = rng.uniform(0, 100, (4096, 2))
    xy[7] = np.nan
    p = morton_order(xy)
    assert sorted(p.tolist()) == list(range(4096)) and p[-1] == 7
    step = np.hypot(*np.diff(xy[p[:-1]], axis=0).T)
    assert np.median(step) < 3.0  # neighbours along the curve are near in space (random order: ~50 m)


def test_a_few_queries_at_once_equal_the_batch():
    ref, q = _random(seed=7)
    loc = KnnLocalizer(KnnConfig(k=15)).fit(ref)
    batch = loc.kneighbors(q)[1]
    for n in (1, 2, 5, knn_search.FEW_QUERIES, knn_search.FEW_QUERIES + 1):
        np.testing.assert_array_equal(loc.kneighbors(q[:n])[1], batch[:n])


def test_one_at_a_time_with_fewer_rps_than_candidates():
    """K + margin at least the RPs: every RP a candidate, one query at a time and in a batch."""
    ref, q = _field(n_rp=20, n_q=12, seed=9)
    for k in (12, 19):  # K + 8 >= 20 RPs
        _check_sets(ref, q, k, one_at_a_time=True)
        _check_sets(ref, q, k)
