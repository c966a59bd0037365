"""SLAC (He et al. 2015): its kernels against brute force, calibration on the synthetic venue, bad input."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pandas as pd
import pytest

from rmbuild.baselines.calibration import calibrate_query, fit_device_model, to_map_units
from rmbuild.baselines.config import SlacConfig
from rmbuild.baselines.slac import SlacLocalizer, berhu, greedy_capped, project_capped_simplex
from rmbuild.errors import ConfigError, InputError
from rmbuild.localize.base import Query, ReferenceSet


def _ref(n_rp=60, n_ap=12, seed=0, std=True):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 50, (n_rp, 2))
    aps = rng.uniform(0, 50, (n_ap, 2))
    d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1))
    rss = (-40 - 25 * np.log10(np.maximum(d, 1))).astype(np.float32)
    rss[rss < -85] = np.nan
    sd = np.where(np.isnan(rss), np.nan, 2.0).astype(np.float32) if std else None
    return ReferenceSet(xy, rss, np.array([f"ap{j}" for j in range(n_ap)], dtype=object), sd), aps


def test_berhu():
    z = np.array([-3.0, -1.0, 0.0, 0.5, 2.0, 4.0])
    np.testing.assert_allclose(berhu(z, 2.0), [(9 + 4) / 4, 1.0, 0.0, 0.5, 2.0, (16 + 4) / 4])


def test_capped_simplex_projection_is_exact():
    from scipy.optimize import minimize

    rng = np.random.default_rng(1)
    for _ in range(20):
        n = 6
        y = rng.normal(0, 1, n)
        valid = rng.random(n) > 0.2
        valid[:3] = True
        cap = max(rng.uniform(0.2, 0.6), 1.0 / valid.sum())
        w = project_capped_simplex(y[None], np.array([cap]), valid[None])[0]
        assert abs(w.sum() - 1) < 1e-9 and (w >= -1e-12).all() and (w <= cap + 1e-9).all()
        assert (w[~valid] == 0).all()
        bounds = [(0, cap if v else 0) for v in valid]
        r = minimize(lambda x, y=y: ((x - y) ** 2).sum(), valid / valid.sum(),
                     method="SLSQP", bounds=bounds, constraints=[{"type": "eq", "fun": lambda x: x.sum() - 1}])
        assert ((w - y) ** 2).sum() <= r.fun + 1e-7


def test_greedy_is_least_cost():
    g = np.array([[1.0, 2.0, 3.0, 10.0]])
    w = greedy_capped(g, np.array([0.4]), np.ones_like(g, dtype=bool))
    np.testing.assert_allclose(w, [[0.4, 0.4, 0.2, 0.0]])


def test_gamma_matches_equation_9_10():
    ref, _ = _ref()
    loc = SlacLocalizer().fit(ref)
    rng = np.random.default_rng(2)
    scan = ref.rss_dbm[5:8].copy()
    scan[rng.random(scan.shape) < 0.3] = np.nan
    kk, bb = to_map_units(np.array([1.2, 0.8]), np.array([-3.0, -7.0]), "device")
    gam, shared = loc._gamma(loc._scan_terms(scan), kk, bb)
    for p in range(2):
        for m in range(3):
            for q in range(len(ref)):
                s = ~np.isnan(scan[m]) & ~np.isnan(ref.rss_dbm[q])
                if not s.any():
                    assert np.isinf(gam[p, m, q])
                    continue
                u = kk[p] * scan[m, s] + bb[p]
                want = ((u - ref.rss_dbm[q, s]) ** 2 + ref.std_db[q, s] ** 2).mean()
                assert gam[p, m, q] == pytest.approx(want, rel=1e-6)


def test_device_fit_and_calibration():
    rng = np.random.default_rng(3)
    psi = rng.uniform(-90, -40, 500)
    phi = 1.25 * psi - 6 + rng.normal(0, 0.5, 500)
    fit = fit_device_model(psi, phi)
    assert fit.k == pytest.approx(1.25, abs=0.02) and fit.b == pytest.approx(-6, abs=1.0) and fit.n_pairs == 500
    q = Query(phi[None].astype(np.float32), np.array(["a"] * 500, dtype=object), np.zeros(1),
              np.array(["w"], dtype=object), np.zeros(1, dtype=np.int64))
    back = calibrate_query(q, 1.25, -6.0).rss_dbm[0]
    assert np.abs(back - psi).max() < 3
    with pytest.raises(InputError):
        fit_device_model(np.array([np.nan, -50.0]), np.array([-60.0, np.nan]))


def _walk_query(ref, aps, n_scans=20, speed=1.2, dt=2.0, device=(1.0, 0.0), seed=4, steps=True):
    """A straight walk through the reference area, scans every dt s, steps at 1.8 Hz of 0.67 m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_scans) * dt
    xy = np.c_[5 + speed * t, 20 + 0.2 * speed * t]
    d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1))
    truth = -40 - 25 * np.log10(np.maximum(d, 1)) + rng.normal(0, 1.0, d.shape)
    rss = (device[0] * truth + device[1]).astype(np.float32)
    rss[truth < -85] = np.nan
    f = 1.8
    ts = np.arange(0, t[-1] + 1e-9, 1 / f)[1:]
    st = pd.DataFrame({"t_s": ts, "step_length_m": np.full(len(ts), speed / f), "heading_rad": 0.2,
                       "step_freq_hz": np.full(len(ts), f)}) if steps else pd.DataFrame(
        {"t_s": [], "step_length_m": [], "heading_rad": [], "step_freq_hz": []})
    q = Query(rss, ref.bssids, t, np.array(["w0"] * n_scans, dtype=object), np.full(n_scans, -1, np.int64),
              {"w0": st})
    return q, xy


def test_slac_localizes_a_hand_made_walk():
    ref, aps = _ref(n_rp=400, seed=5)
    q, xy = _walk_query(ref, aps)
    cfg = SlacConfig(k_range=(1.0, 1.0), b_range_db=(0.0, 0.0), n_particles=1)
    loc = SlacLocalizer(cfg).fit(ref)
    p = loc.predict(q)
    assert np.isfinite(p).all()
    assert np.hypot(*(p - xy).T).mean() < 6.0
    r = loc.diagnostics["w0"]
    assert r.fallbacks == [] and np.isfinite(r.alpha) and np.isfinite(r.beta)


def test_bad_input_and_fallbacks():
    ref, aps = _ref(seed=6)
    q, _ = _walk_query(ref, aps, steps=False)
    with pytest.raises(InputError, match="no step events"):
        SlacLocalizer().fit(ref).predict(q)
    loc = SlacLocalizer(SlacConfig(no_steps="fingerprint_only", n_particles=5)).fit(ref)
    p = loc.predict(q)
    assert np.isfinite(p).all() and "steps:none" in loc.summary()["fallbacks"]
    # a window longer than the walk: the window is the whole walk, and the result says so
    q3, _ = _walk_query(ref, aps, n_scans=3)
    loc = SlacLocalizer(SlacConfig(n_particles=5)).fit(ref)
    assert np.isfinite(loc.predict(q3)).all()
    assert "window:short" in loc.diagnostics["w0"].fallbacks
    # a map without std
    nostd = dataclasses.replace(ref, std_db=None)
    with pytest.raises(InputError, match="no RSSI std"):
        SlacLocalizer(SlacConfig(missing_std="error")).fit(nostd)
    loc = SlacLocalizer(SlacConfig(n_particles=5)).fit(nostd)
    assert "std:zero" in loc.map_fallbacks
    # no step frequencies: PDR step lengths, named
    q4, _ = _walk_query(ref, aps)
    q4.steps["w0"]["step_freq_hz"] = np.nan
    loc = SlacLocalizer(SlacConfig(n_particles=5)).fit(ref)
    loc.predict(q4)
    assert "steps:pdr" in loc.diagnostics["w0"].fallbacks and np.isnan(loc.diagnostics["w0"].alpha)


def test_config_validation():
    from rmbuild.config.base import from_dict

    with pytest.raises(ConfigError):
        from_dict(SlacConfig, {"window_scans": 1})
    with pytest.raises(ConfigError):
        from_dict(SlacConfig, {"k_range": [2.0, 1.0]})
    with pytest.raises(ConfigError):
        from_dict(SlacConfig, {"windw_scans": 7})
    c = from_dict(SlacConfig, {"k_range": [0.5, 2.0], "b_range_db": [-8, 0]})
    assert c.k_range == (0.5, 2.0) and c.n_particles == 60 and c.window_scans == 7


@functools.lru_cache(maxsize=2)
def _synthetic(device):
    """(surveyed radio map, the two long test walks' scans, their true xy) of the `default` preset, seed 7,
    test walks on ``device`` (cached: several test modules use it; nobody modifies it)."""
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.evaluate.localization import reference_positions, split_walks
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.radiomap import build_radio_map
    from rmbuild.synthetic import simulate

    c = preset_config("default", 7)
    c = dataclasses.replace(c, walkers=dataclasses.replace(c.walkers, n_test_walks=4),
                            devices=dataclasses.replace(c.devices, test_device=device))
    sd = simulate(c)
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    maps, test, _ = split_walks(ds, EvaluateConfig())
    ref, _ = reference_positions(ds)
    wifi = ds.wifi[ds.wifi["walk_id"].astype(str).isin(maps)]
    bssids = np.asarray(fp.bssids, dtype=object)
    rm = build_radio_map(wifi, ref, ds.poses["walk_id"].astype(str).to_numpy(), bssids=bssids)
    # the two long test walks only (keeps the test short)
    q = Query.from_dataset(ds, [w for w in test if w in ("w007", "w009")], bssids)
    tp = ds.truth_poses
    qxy = np.full((len(q), 2), np.nan)
    for wid, rows in q.walks():
        g = tp[tp["walk_id"].astype(str) == wid]
        qxy[rows] = np.c_[np.interp(q.t_s[rows], g["t_s"], g["x_m"]), np.interp(q.t_s[rows], g["t_s"], g["y_m"])]
    return rm, q, qxy


def test_slac_calibrates_the_synthetic_test_device():
    from rmbuild.localize.knn import KnnLocalizer

    rm, q, qxy = _synthetic((1.25, -6.0))
    loc = SlacLocalizer().fit(rm)
    e = np.hypot(*(loc.predict(q) - qxy).T)
    s = loc.summary()
    assert s["k"] == pytest.approx(1.25, rel=0.10)
    assert s["b"] == pytest.approx(-6.0, abs=2.0)
    e_knn = np.hypot(*(KnnLocalizer().fit(rm).predict(q) - qxy).T)
    e_true = np.hypot(*(KnnLocalizer().fit(rm).predict(calibrate_query(q, 1.25, -6.0)) - qxy).T)
    assert np.nanmean(e) <= 0.75 * np.nanmean(e_knn)
    assert np.nanmean(e) <= 1.15 * np.nanmean(e_true)
