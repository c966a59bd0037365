"""Pair search: the blocked eq. 9 / median-window search equals a brute-force double loop."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.slam.pairs import RowMeta, SearchParams, median_window_pairs, run_matched_candidates, window_median
from rmbuild.slam.rss import RssMatrix, rss_distance_reference
from rmbuild.types import Fingerprints


def _random(n=90, m=25, n_walks=3, seed=0):
    rng = np.random.default_rng(seed)
    rss = rng.uniform(-95, -40, (n, m)).astype(np.float32)
    rss[rng.random((n, m)) < 0.6] = np.nan
    fp = Fingerprints(np.arange(n), np.array([f"a{i}" for i in range(m)], dtype=object), rss,
                      (~np.isnan(rss)).astype(np.int32))
    walk = np.repeat(np.arange(n_walks), n // n_walks)
    step = np.concatenate([np.arange(n // n_walks)] * n_walks)
    meta = RowMeta(np.arange(n), walk, step, step * 0.6 + walk * 1000.0, step * 0.7)
    return fp, meta


def test_rss_distance_matches_eq9():
    fp, _ = _random()
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    d, _ = rm.block(np.arange(10), np.arange(20))
    for i in range(10):
        for j in range(20):
            # float32 GEMM identity: ~0.02 dB cancellation error at d ~ 0 (ranking only)
            assert abs(d[i, j] - rss_distance_reference(fp.rss_dbm[i], fp.rss_dbm[j], -110.0)) < 0.05
    i, j = np.arange(10), np.arange(10, 20)
    dp, _ = rm.pairs(i, j)
    np.testing.assert_allclose(dp, d[i, j], atol=0.05)


def test_median_window_pairs_equal_brute_force():
    fp, meta = _random()
    cfg = SearchParams(window_steps=6, within_min_dt_s=5.0, within_min_path_m=4.0, max_pairs_per_node=3,
                     min_common_aps=2, block_rows=16)
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    got, thr = median_window_pairs(rm, meta, cfg)
    n = len(fp)
    D = np.array([[rss_distance_reference(fp.rss_dbm[i], fp.rss_dbm[j]) for j in range(n)] for i in range(n)])
    det = ~np.isnan(fp.rss_dbm)
    C = det.astype(int) @ det.T.astype(int)
    want = set()
    for k in range(n):
        win = [q for q in range(n) if q != k and meta.walk[q] == meta.walk[k]
               and abs(meta.step[q] - meta.step[k]) <= 3]
        med = np.median(D[k, win])
        assert abs(med - thr[k]) < 1e-3
        cands = []
        for q in range(n):
            if q == k or C[k, q] < 2 or not D[k, q] < med:
                continue
            if meta.walk[q] == meta.walk[k] and (abs(meta.t_s[q] - meta.t_s[k]) < 5.0
                                                  or abs(meta.path_m[q] - meta.path_m[k]) < 4.0):
                continue
            cands.append((D[k, q], q))
        for _, q in sorted(cands)[:3]:
            want.add((min(k, q), max(k, q)))
    assert set(zip(got["row_k"].tolist(), got["row_q"].tolist())) == want


def test_window_median_ignores_other_walks():
    fp, meta = _random()
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    thr = window_median(rm, meta, 4)
    assert np.isfinite(thr).all()


def test_run_matched_candidates_find_true_neighbours():
    # two walks along the same line with a smooth field: candidates must pair nearby positions
    rng = np.random.default_rng(3)
    aps = rng.uniform(0, 100, (30, 2))
    xa = np.linspace(0, 60, 80)
    xb = np.linspace(60, 0, 80)  # opposite direction
    def scan(x):
        d = np.hypot(x[:, None] - aps[None, :, 0], 5 - aps[None, :, 1])
        r = -30 - 30 * np.log10(np.maximum(d, 1)) + rng.normal(0, 1, d.shape)
        r[r < -90] = np.nan
        return r.astype(np.float32)
    rss = np.r_[scan(xa), scan(xb)]
    fp = Fingerprints(np.arange(160), np.array([f"a{i}" for i in range(30)], dtype=object), rss,
                      (~np.isnan(rss)).astype(np.int32))
    walk = np.repeat([0, 1], 80)
    step = np.r_[np.arange(80), np.arange(80)]
    meta = RowMeta(np.arange(160), walk, step, step + walk * 500.0, np.r_[xa, 60 - xb])
    cfg = SearchParams(segment_scans=2, top_k=3, run_half_scans=2, within_walk=False)
    df = run_matched_candidates(RssMatrix.from_fingerprints(fp, -110.0), meta, cfg)
    x = np.r_[xa, xb]
    err = np.abs(x[df["row_k"]] - x[df["row_q"]])
    assert len(df) > 20 and np.median(err) < 4.0  # a smooth path-loss-only field: metres of ambiguity
    assert isinstance(df, pd.DataFrame) and set(df["kind"]) == {"cross"}


def test_segment_neighbours_equal_full_ranking():
    """The bounded symmetric sweep finds each row's k nearest searchable rows, as ranking whole rows does."""
    from rmbuild.slam.pairs import _allowed, segment_neighbours

    fp, meta = _random(n=300, m=30, n_walks=6, seed=3)
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    cfg = SearchParams(within_min_dt_s=20.0, within_min_path_m=10.0, block_rows=64)
    si, sj = segment_neighbours(rm, meta, cfg, 5)
    rows = np.arange(len(rm))
    d, common = rm.block(rows)
    d[(common < cfg.min_common_aps) | ~_allowed(meta, rows, slice(None), cfg, within=True)] = np.inf
    for i in rows:
        want = np.argsort(d[i], kind="stable")[:5]
        want = set(want[np.isfinite(d[i, want])].tolist())
        assert set(sj[si == i].tolist()) == want


def test_segment_neighbours_do_not_depend_on_the_worker_threads(monkeypatch):
    from rmbuild import blas
    from rmbuild.slam.pairs import segment_neighbours

    fp, meta = _random(n=300, m=30, n_walks=6, seed=4)
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    cfg = SearchParams(block_rows=64)
    monkeypatch.setattr(blas, "WORKERS", 1)
    one = segment_neighbours(rm, meta, cfg, 5)
    monkeypatch.setattr(blas, "WORKERS", 3)
    three = segment_neighbours(rm, meta, cfg, 5)
    assert all(np.array_equal(a, b) for a, b in zip(one, three))


def test_leaf_search_finds_nearly_every_exact_neighbour(monkeypatch):
    """From LEAF_MIN_SEGMENTS on each segment is searched among its nearest leaves: on fingerprints of a smooth
    field along six walks it finds most of the exact sweep's neighbours, and only searchable ones."""
    from rmbuild.slam import pairs
    from rmbuild.slam.pairs import segment_neighbours

    rng = np.random.default_rng(5)
    n, m = 1200, 40
    pos = rng.uniform(0, 100, n)
    ap = rng.uniform(0, 100, m)
    rss = (-40 - 30 * np.log10(1 + np.abs(pos[:, None] - ap[None, :])) + rng.normal(0, 2, (n, m))).astype(np.float32)
    rss[rss < -85] = np.nan
    fp = Fingerprints(np.arange(n), np.array([f"a{i}" for i in range(m)], dtype=object), rss,
                      (~np.isnan(rss)).astype(np.int32))
    walk = np.repeat(np.arange(6), n // 6)
    step = np.tile(np.arange(n // 6), 6)
    meta = RowMeta(np.arange(n), walk, step, step * 0.6 + walk * 1000.0, step * 0.7)
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    cfg = SearchParams(within_walk=False)
    exact = segment_neighbours(rm, meta, cfg, 5)
    monkeypatch.setattr(pairs, "LEAF_MIN_SEGMENTS", 100)
    monkeypatch.setattr(pairs, "LEAF_SEGMENTS", 40)
    monkeypatch.setattr(pairs, "LEAF_PROBES", 8)
    leaf = segment_neighbours(rm, meta, cfg, 5)
    want, got = set(zip(*(a.tolist() for a in exact))), set(zip(*(a.tolist() for a in leaf)))
    assert len(want & got) >= 0.9 * len(want) and len(got) <= len(want)
    si, sj = leaf
    assert (meta.walk[si] != meta.walk[sj]).all() and (np.bincount(si) <= 5).all()


def test_a_search_restricted_to_new_walks_finds_every_full_search_pair_of_theirs():
    """An incremental run searches only the new walks' scans: every pair the full search finds with a new
    scan is found (the mutual rule's bound for an old scan is an upper bound: a few more may be)."""
    fp, meta = _random(n=240, m=30, n_walks=8, seed=4)
    rm = RssMatrix.from_fingerprints(fp, -110.0)
    cfg = SearchParams(segment_scans=2, top_k=4, run_half_scans=1, within_walk=True)
    full = run_matched_candidates(rm, meta, cfg)
    new = meta.walk >= 6
    part = run_matched_candidates(rm, meta, cfg, rows=new)
    k, q = part["row_k"].to_numpy(), part["row_q"].to_numpy()
    assert (new[k] | new[q]).all()  # nothing between two old scans
    fk, fq = full["row_k"].to_numpy(), full["row_q"].to_numpy()
    touch = new[fk] | new[fq]
    assert touch.sum() > 10
    assert set(zip(fk[touch].tolist(), fq[touch].tolist())) <= set(zip(k.tolist(), q.tolist()))
