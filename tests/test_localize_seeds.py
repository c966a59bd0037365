"""MLL, SSR, SmartLocator's fusion and the offline device fit: formulas against brute force, invariances,
and seeded synthetic walks with tolerances."""

from __future__ import annotations

import itertools

import click
import numpy as np
import pandas as pd
import pytest

from rmbuild.baselines.bayes import NaiveBayesLocalizer
from rmbuild.baselines.calibration import colocated_pairs, deming, fit_device_model
from rmbuild.baselines.config import MllConfig, SmartLocatorConfig, SsrConfig
from rmbuild.baselines.mll import MllLocalizer, walked_between
from rmbuild.baselines.smartloc import SmartLocator, StaticSmartLocator
from rmbuild.baselines.ssd import SsrLocalizer
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, ReferenceSet


def _grid_ref(seed=0, n_ap=12, spacing=2.0, size=40.0, noise=1.0):
    """RPs on a grid with log-distance RSS from random APs (and each AP's positions)."""
    rng = np.random.default_rng(seed)
    g = np.arange(spacing / 2, size, spacing)
    xy = np.array([(x, y) for x in g for y in g])
    aps = rng.uniform(0, size, (n_ap, 2))
    rss = _field(xy, aps) + rng.normal(0, noise, (len(xy), n_ap))
    rss[rss < -88] = np.nan
    std = np.where(np.isnan(rss), np.nan, 2.0)
    return ReferenceSet(xy, rss.astype(np.float32), np.array([f"ap{j}" for j in range(n_ap)], dtype=object),
                        std.astype(np.float32)), aps


def _field(xy, aps):
    d = np.hypot(*(xy[:, None, :] - aps[None]).transpose(2, 0, 1))
    return -35.0 - 28.0 * np.log10(np.maximum(d, 1.0))


def _walk(aps, n=60, dt=2.0, speed=1.0, rot=0.7, noise=6.0, seed=3):
    """A walk round a 12 m square, twice: scans every dt s (noisy), steps every 0.5 s in a frame rotated by
    -rot from the map. Returns (query, true xy)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    ts = np.arange(0.5, t[-1] + 1e-9, 0.5)
    legs = (ts // (12.0 / speed)).astype(int)
    heading = 0.1 + (legs % 4) * np.pi / 2  # map-frame heading per step
    step = speed * 0.5
    pos = np.array([12.0, 12.0]) + np.r_[[[0.0, 0.0]], np.cumsum(np.c_[step * np.cos(heading),
                                                                       step * np.sin(heading)], axis=0)]
    tt = np.r_[0.0, ts]
    xy = np.c_[np.interp(t, tt, pos[:, 0]), np.interp(t, tt, pos[:, 1])]
    rss = _field(xy, aps) + rng.normal(0, noise, (n, len(aps)))
    rss[rss < -88] = np.nan
    steps = pd.DataFrame({"t_s": ts, "step_length_m": step, "heading_rad": heading - rot, "step_freq_hz": 2.0})
    q = Query(rss.astype(np.float32), np.array([f"ap{j}" for j in range(len(aps))], dtype=object), t,
              np.array(["w"] * n, dtype=object), np.full(n, -1, np.int64), {"w": steps})
    return q, xy


def _err(p, xy):
    return float(np.nanmean(np.hypot(*(p - xy).T)))


# ------------------------------------------------------------------------------------------------- SSR
def test_ssr_matches_pairwise_log_ratios_and_is_gain_invariant():
    ref, aps = _grid_ref(seed=1)
    loc = SsrLocalizer(SsrConfig(k=5)).fit(ref)
    q = ref.rss_dbm[[10, 200, 333]]
    d = loc.distances(q)
    x = q[0].astype(float)
    for r in (10, 11, 150):
        s = ~np.isnan(x) & ~np.isnan(ref.rss_dbm[r])
        a, b = np.log(x[s][:, None] / x[s][None]), np.log(ref.rss_dbm[r, s][:, None] / ref.rss_dbm[r, s][None])
        assert d[0, r] == pytest.approx(((a - b) ** 2).mean(), rel=1e-6, abs=1e-9)
    qq = Query(q, ref.bssids, np.zeros(3), np.array(["w"] * 3, dtype=object), np.full(3, -1))
    p0 = loc.predict(qq)
    p1 = loc.predict(Query(q * np.float32(1.3), ref.bssids, np.zeros(3), qq.walk_id, qq.node))
    np.testing.assert_allclose(p0, p1, atol=1e-6)
    assert _err(p0, ref.xy[[10, 200, 333]]) < 6.0


# ------------------------------------------------------------------------------------------------- MLL
def test_walked_between():
    steps = pd.DataFrame({"t_s": [0.5, 1.0, 1.5, 2.5], "step_length_m": [0.5, 0.6, 0.7, 0.8]})
    np.testing.assert_allclose(walked_between(np.array([0.2, 1.2, 3.0]), steps), [0.0, 1.1, 1.5])
    assert walked_between(np.array([1.0, 2.0]), None).tolist() == [0.0, 0.0]


def test_mll_track_is_the_exact_window_maximum():
    ref, aps = _grid_ref(seed=2, spacing=8.0)
    loc = MllLocalizer(MllConfig(window_scans=3, n_candidates=4)).fit(ref)
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(ref), (5, 4))
    ll = rng.normal(0, 3, (5, 4))
    walked = rng.uniform(0, 10, 5)
    out = loc.track(idx, ll, walked)
    for i in range(5):  # brute force over every sequence of candidates in the window
        lo = max(0, i - 2)
        best, arg = -np.inf, None
        for seq in itertools.product(range(4), repeat=i - lo + 1):
            v = sum(ll[lo + j, c] for j, c in enumerate(seq))
            for j in range(1, len(seq)):
                dd = np.hypot(*(ref.xy[idx[lo + j, seq[j]]] - ref.xy[idx[lo + j - 1, seq[j - 1]]]))
                v -= (dd - walked[lo + j]) ** 2 / (2 * 2.0 ** 2)
            if v > best:
                best, arg = v, seq[-1]
        np.testing.assert_allclose(out[i], ref.xy[idx[i, arg]])


def test_mll_beats_single_scans_on_a_noisy_walk_and_falls_back_without_steps():
    ref, aps = _grid_ref(seed=3)
    q, xy = _walk(aps, noise=7.0)
    mll = MllLocalizer().fit(ref)
    e_mll = _err(mll.predict(q), xy)
    nb_top1 = NaiveBayesLocalizer().fit(ref)
    idx, ll = nb_top1.top(q.rss_dbm, 1)
    e_nb1 = _err(ref.xy[idx[:, 0]], xy)
    assert e_mll < 0.8 * e_nb1 and e_mll < 4.0
    q_none = Query(q.rss_dbm, q.bssids, q.t_s, q.walk_id, q.node, None)
    np.testing.assert_allclose(mll.predict(q_none), ref.xy[idx[:, 0]])
    assert mll.summary()["fallbacks"] == ["steps:none"]


# ------------------------------------------------------------------------------------------ SmartLocator
def test_smartlocator_weights():
    s = SmartLocator(SmartLocatorConfig())
    assert s.weight(0.3, 2.0) == pytest.approx(0.38)
    assert s.weight(0.3, 60.0) == pytest.approx(0.7)  # α_t stops at 0.4
    assert s.weight(0.9, 60.0) == 1.0  # clamped (the paper's eq. 8 prints max)
    assert StaticSmartLocator().weight(0.0, 100.0) == 0.5
    ref, _ = _grid_ref()
    s.fit(ref)
    rss = np.full((3, len(ref.bssids)), np.nan, dtype=np.float32)
    rss[1, :3] = -60
    rss[2, :6] = -60
    np.testing.assert_allclose(s.accuracy(rss), [0.0, 0.1, 0.3])  # Fig. 6: 0 at 2 APs, 0.3 at 5


def test_smartlocator_fuses_pdr_and_fixes():
    ref, aps = _grid_ref(seed=4)
    q, xy = _walk(aps, noise=7.0, seed=5)
    fixes = NaiveBayesLocalizer().fit(ref).predict(q)
    for cls in (SmartLocator, StaticSmartLocator):
        loc = cls().fit(ref)
        e = _err(loc.predict(q), xy)
        assert e < 0.8 * _err(fixes, xy), cls.name
    # the first estimate is the first fix; without steps the fixes come out unchanged
    np.testing.assert_allclose(loc.predict(q)[0], fixes[0])
    q_none = Query(q.rss_dbm, q.bssids, q.t_s, q.walk_id, q.node, None)
    np.testing.assert_allclose(loc.predict(q_none), fixes)
    assert loc.summary()["fallbacks"] == ["steps:none"]


# ----------------------------------------------------------------------------------------- device fit
def _colocated(k=1.25, b=-6.0, n_spots=240, seed=0, offset_sd=3.0, floor=-100.0):
    """Per-(spot, AP) means of two devices: a common field, a per-(spot, AP, device) session offset, 20
    noisy readings each of which only those at or above the floor are reported (the device reads k·x + b)."""
    rng = np.random.default_rng(seed)
    field = rng.uniform(-95, -40, (n_spots, 30))
    out = []
    for kk, bb in ((1.0, 0.0), (k, b)):
        base = kk * (field + rng.normal(0, offset_sd, field.shape)) + bb
        r = base[..., None] + kk * rng.normal(0, 4.0, field.shape + (20,))
        r = np.where(r >= floor, r, np.nan)
        n = (~np.isnan(r)).sum(axis=2)
        out.append(np.where(n > 0, np.nansum(r, axis=2) / np.maximum(n, 1), np.nan))
    return out


def test_device_fit_corrects_dilution_and_truncation():
    x, y = _colocated()
    ok = np.isfinite(x) & np.isfinite(y)
    k_ols, _ = np.polyfit(x[ok], y[ok], 1)
    assert k_ols < 1.1  # the naive fit: diluted by the map side's offsets, flattened by the floor
    fit = fit_device_model(x, y, floors_dbm=(-100.0, -100.0))
    assert fit.method == "deming_trimmed" and fit.n_used < fit.n_pairs
    assert fit.k == pytest.approx(1.25, abs=0.06) and fit.b == pytest.approx(-6.0, abs=4.0)
    # noise-free line: exact
    xs = np.linspace(-90, -40, 50)
    f2 = fit_device_model(xs, 1.25 * xs - 6)
    assert f2.k == pytest.approx(1.25, abs=1e-6) and f2.b == pytest.approx(-6, abs=1e-4)
    assert deming(xs, 0.5 * xs + 1, 0.25) == pytest.approx((0.5, 1.0), abs=1e-9)
    with pytest.raises(InputError):
        fit_device_model(np.array([np.nan, -50.0]), np.array([-60.0, np.nan]))


def test_colocated_pairs():
    bss = np.array(["a", "b", "c"], dtype=object)
    m = ReferenceSet(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([[-50, -60, np.nan], [-55, np.nan, -70]],
                                                                   dtype=np.float32), bss)
    d = ReferenceSet(np.array([[2.0, 0.0], [9.0, 9.0]]), np.array([[-57, -80], [-1, -1]], dtype=np.float32),
                     np.array(["a", "c"], dtype=object))
    pm, pd_ = colocated_pairs(m, d)
    np.testing.assert_allclose(pm, [[-55, np.nan, -70]])
    np.testing.assert_allclose(pd_, [[-57, np.nan, -80]])


def test_registry_classes_and_cli_choices():
    from rmbuild.cli.evaluate import evaluate
    from rmbuild.localize.base import localizer_class, make_localizer
    from rmbuild.localize.registry import REGISTRY, localizer_names

    for name in REGISTRY:
        assert localizer_class(name).name == name
        assert make_localizer(name) is not None
    opt = next(p for p in evaluate.params if p.name == "localizers")
    # the choices come from the registry: every registered name is accepted (comma-separated too), others not
    assert opt.callback(None, opt, (",".join(localizer_names()),)) == tuple(localizer_names())
    with pytest.raises(click.BadParameter):
        opt.callback(None, opt, ("knn,not_a_localizer",))
    assert all(n in opt.help for n in REGISTRY)
