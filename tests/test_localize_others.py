"""Naive Bayes, SSD, PFL and the Kalman post-filter: formulas against brute force, invariances, tracks."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rmbuild.baselines.bayes import NaiveBayesLocalizer
from rmbuild.baselines.config import BayesConfig, PflConfig, SmoothingConfig, SsdConfig
from rmbuild.baselines.pfl import PflLocalizer
from rmbuild.baselines.smoothing import KalmanSmoothed, kalman_smooth, pdr_positions
from rmbuild.baselines.ssd import SsdLocalizer
from rmbuild.errors import ConfigError, InputError
from rmbuild.localize.base import Query, ReferenceSet


def _ref(n_rp=200, n_ap=15, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 60, (n_rp, 2))
    aps = rng.uniform(0, 60, (n_ap, 2))
    d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1))
    rss = (-40 - 25 * np.log10(np.maximum(d, 1)) + rng.normal(0, 1, d.shape)).astype(np.float32)
    rss[rss < -85] = np.nan
    std = np.where(np.isnan(rss), np.nan, rng.uniform(1, 4, rss.shape)).astype(np.float32)
    return ReferenceSet(xy, rss, np.array([f"ap{j}" for j in range(n_ap)], dtype=object), std), aps


def _query(rss, t=None, steps=None):
    n = len(rss)
    t = np.arange(n, dtype=float) if t is None else t
    return Query(rss.astype(np.float32), np.array([f"ap{j}" for j in range(rss.shape[1])], dtype=object), t,
                 np.array(["w"] * n, dtype=object), np.full(n, -1, np.int64), None if steps is None else {"w": steps})


def test_naive_bayes_matches_brute_force():
    ref, _ = _ref()
    cfg = BayesConfig(k=3)
    loc = NaiveBayesLocalizer(cfg).fit(ref)
    q = ref.rss_dbm[[3, 50, 120]] + np.float32(1.5)
    ll = loc.log_likelihood(q)
    for i, x in enumerate(q):
        xf = np.where(np.isnan(x), cfg.fill_dbm, x).astype(float)
        for r in (0, 7, 99):
            y = np.where(np.isnan(ref.rss_dbm[r]), cfg.fill_dbm, ref.rss_dbm[r]).astype(float)
            v = cfg.kernel_sigma_db ** 2 + np.nan_to_num(ref.std_db[r].astype(float)) ** 2
            want = np.sum(np.log(np.exp(-(xf - y) ** 2 / (2 * v)) / np.sqrt(2 * np.pi * v)))
            assert ll[i, r] == pytest.approx(want, rel=1e-9)
    p = loc.predict(_query(q))
    assert np.hypot(*(p - ref.xy[[3, 50, 120]]).T).max() < 10


def test_ssd_is_offset_invariant_and_matches_pairwise_definition():
    ref, _ = _ref(seed=1)
    loc = SsdLocalizer(SsdConfig(k=5)).fit(ref)
    q = ref.rss_dbm[[10, 20, 30]]
    d = loc.distances(q)
    x = q[0].astype(float)
    for r in (10, 11, 60):
        s = ~np.isnan(x) & ~np.isnan(ref.rss_dbm[r])
        a, b = x[s], ref.rss_dbm[r, s].astype(float)
        want = (((a[:, None] - a[None]) - (b[:, None] - b[None])) ** 2).mean()
        assert d[0, r] == pytest.approx(want, rel=1e-6, abs=1e-6)
    p0 = loc.predict(_query(q))
    p1 = loc.predict(_query(q - np.float32(8.0)))
    np.testing.assert_allclose(p0, p1, atol=1e-9)
    assert np.isnan(loc.predict(_query(np.full((1, q.shape[1]), np.nan)))).all()


def _walk(ref, aps, n=40, seed=2):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 2.0
    xy = np.c_[8 + 1.2 * t * np.cos(0.3), 8 + 1.2 * t * np.sin(0.3)]
    d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1))
    rss = -40 - 25 * np.log10(np.maximum(d, 1)) + rng.normal(0, 3, d.shape)
    rss[rss < -85] = np.nan
    ts = np.arange(0.5, t[-1] + 1e-9, 0.5)
    # the walk's own frame is rotated by -1 rad from the map frame
    steps = pd.DataFrame({"t_s": ts, "step_length_m": 0.6, "heading_rad": 0.3 - 1.0, "step_freq_hz": 2.0})
    return rss, t, steps, xy


def test_pfl_tracks_a_walk_with_unknown_frame_rotation():
    ref, aps = _ref(n_rp=600, seed=3)
    rss, t, steps, xy = _walk(ref, aps)
    from rmbuild.localize.knn import KnnLocalizer

    q = _query(rss, t, steps)
    e_knn = np.hypot(*(KnnLocalizer().fit(ref).predict(q) - xy).T)
    e = np.hypot(*(PflLocalizer(PflConfig(n_particles=800)).fit(ref).predict(q) - xy).T)
    assert np.nanmean(e[15:]) < np.nanmean(e_knn[15:])


def test_kalman_smoothing_reduces_noise_and_estimates_rotation():
    rng = np.random.default_rng(4)
    n = 60
    t = np.arange(n) * 2.0
    truth = np.c_[1.2 * t * np.cos(0.3), 1.2 * t * np.sin(0.3)]
    z = truth + rng.normal(0, 4, truth.shape)
    steps = pd.DataFrame({"t_s": np.arange(0.5, t[-1] + 1e-9, 0.5), "step_length_m": 0.6,
                          "heading_rad": 0.3 - 1.0, "step_freq_hz": 2.0})
    pdr = pdr_positions(t, steps)
    for mode in ("filter", "rts"):
        s = kalman_smooth(z, pdr, SmoothingConfig(mode=mode))
        assert np.hypot(*(s - truth).T)[10:].mean() < 0.7 * np.hypot(*(z - truth).T)[10:].mean()


def test_wrappers_registry_names_and_fallbacks():
    ref, aps = _ref(seed=5)
    rss, t, steps, xy = _walk(ref, aps, n=10)
    from rmbuild.localize.knn import KnnLocalizer

    k = KalmanSmoothed(KnnLocalizer()).fit(ref)
    assert np.isfinite(k.predict(_query(rss, t, steps))).all()
    p = k.predict(_query(rss, t, None))  # no steps: left unsmoothed, named
    assert "steps:none" in k.summary()["fallbacks"] and np.isfinite(p).all()
    pf = PflLocalizer().fit(ref)
    pf.predict(_query(rss, t, None))
    assert pf.summary()["fallbacks"] == ["steps:none"]


def test_configs_validate():
    from rmbuild.config.base import from_dict

    for cls, bad in ((BayesConfig, {"k": 0}), (SsdConfig, {"min_shared_aps": 1}), (PflConfig, {"n_particles": 0}),
                     (SmoothingConfig, {"process_sd_m": 0.0, "process_sd_per_m": 0.0})):
        with pytest.raises(ConfigError):
            from_dict(cls, bad)
    with pytest.raises(InputError):
        NaiveBayesLocalizer(BayesConfig(kernel_sigma_db=-1.0))


def test_unknown_localizer_name():
    from rmbuild.localize import make_localizer

    with pytest.raises(InputError, match="unknown localizer"):
        make_localizer("slacc")
