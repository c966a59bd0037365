"""The powed RSS representation and its exponent chosen on the data (rmbuild/slam/powed.py)."""

from __future__ import annotations

import numpy as np
from slam_venue import walk_set

from rmbuild.slam.powed import auc, choose, powed
from rmbuild.types import Fingerprints


def test_auc_counts_ties_half():
    assert auc(np.array([1.0, 2.0]), np.array([3.0, 4.0])) == 1.0
    assert auc(np.array([3.0, 4.0]), np.array([1.0, 2.0])) == 0.0
    assert auc(np.array([1.0, 3.0]), np.array([2.0, 3.0])) == 0.625  # 1<2, 1<3, 3>2, 3=3 (half): 2.5 / 4


def test_powed_maps_back_onto_the_dbm_scale():
    fp = Fingerprints(np.arange(1), np.array(["a", "b", "c", "d"]), np.array([[-110, -70, -30, np.nan]], np.float32),
                      np.ones((1, 4), np.int32))
    assert powed(fp, 1.0, -110.0) is fp
    out = powed(fp, 2.0, -110.0).rss_dbm[0]
    assert np.allclose(out[:3], [-110.0, -90.0, -30.0]) and np.isnan(out[3])


def _line_walks(noisy_weak: bool):
    """Four walks to and fro along a 120 m corridor with 12 APs along it, one scan per 1 m step. Strong
    readings follow path loss closely; weak ones (below -75 dBm) are ``noisy_weak`` (σ 10 dB) or not."""
    rng = np.random.default_rng(5)
    x = np.r_[np.arange(0, 120.0), np.arange(119.0, -1, -1)]
    raw = np.tile(np.c_[x, np.zeros_like(x), np.zeros_like(x)], (4, 1))
    walk_of = np.repeat(np.arange(4), len(x))
    ws = walk_set(raw, walk_of)
    aps = np.linspace(0, 120, 12)
    rss = -35 - 30 * np.log10(np.maximum(np.abs(raw[:, :1] - aps[None]), 1.0))
    weak = rss < -75
    rss += rng.normal(0, np.where(weak & noisy_weak, 10.0, 2.0))
    rss[rss < -100] = np.nan
    ws.fingerprints = Fingerprints(np.arange(len(raw)), np.array([f"ap{i}" for i in range(12)]),
                                   rss.astype(np.float32), np.ones(rss.shape, np.int32))
    return ws


def test_choice_follows_where_the_information_is():
    ws = _line_walks(noisy_weak=True)
    beta, scores = choose(ws.fingerprints, ws, -110.0, 3)
    assert set(scores) == {1.0, 1.25, 1.5, 2.0, 2.5} and scores[beta] == max(scores.values())
    assert beta > 1.0 and scores[beta] > scores[1.0] + 0.01  # weak readings are noise: weigh strong ones
    ws2 = _line_walks(noisy_weak=False)
    beta2, scores2 = choose(ws2.fingerprints, ws2, -110.0, 3)
    assert beta2 < beta and scores2[beta2] > 0.9


def test_too_few_pairs_keep_the_readings_as_read():
    ws = _line_walks(noisy_weak=True)
    few = ws.fingerprints.subset(ws.walk_of[ws.fingerprints.node] == 0)
    few = few.subset(np.arange(len(few)) < 15)  # 15 s of one walk: no pairs >= 10 s apart and 15 m away
    assert choose(few, ws, -110.0, 3) == (1.0, {})


def test_a_small_gain_keeps_the_readings_as_read(monkeypatch):
    import rmbuild.slam.powed as pw

    ws = _line_walks(noisy_weak=True)
    _, scores = choose(ws.fingerprints, ws, -110.0, 3)
    monkeypatch.setattr(pw, "MIN_AUC_GAIN", max(scores.values()) - scores[1.0] + 1e-6)
    assert choose(ws.fingerprints, ws, -110.0, 3) == (1.0, scores)
