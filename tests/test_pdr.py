"""Phone PDR (rmbuild.pdr) on seeded synthetic IMU signals with known steps and headings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rmbuild.config.base import from_dict
from rmbuild.config.ingest import IngestConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.errors import ConfigError
from rmbuild.geometry import wrap as wrap_angle
from rmbuild.pdr import ImuSignals, ImuTimeError, integrate_increments, poses_from_increments, run_pdr, yaw_from_quat
from rmbuild.pdr.attitude import integrate_rates, quat_rotate
from rmbuild.pdr.heading import interval_mean, yaw_from_azimuth_deg
from rmbuild.pdr.length import step_lengths, step_swings
from rmbuild.pdr.synth import rotation_vector_samples, synthesize_phone_imu
from rmbuild.pdr.timebase import GRID_POINTS_PER_SAMPLE, main_block, uniform_grid

MODES = ("texting", "calling", "swinging", "pocket")


def synthetic_walk(seed: int, n_bouts: int = 3, steps: tuple[int, int] = (25, 45),
                   pause_s: tuple[float, float] = (3.0, 8.0)):
    """Bouts of walking (1.4-2.2 steps/s, slowly turning, some 22.5° corners) separated by pauses that end
    with a turn on the spot of up to 180°. Returns step times, headings and the generator."""
    rng = np.random.default_rng(seed)
    ts, hs, t, h = [], [], 0.0, rng.uniform(-np.pi, np.pi)
    f = rng.uniform(1.4, 2.2)
    for _ in range(n_bouts):
        for _ in range(int(rng.integers(*steps))):
            t += rng.uniform(0.95, 1.05) / f
            h += rng.normal(0, 0.03) + (rng.choice([-1, 1]) * np.pi / 8 if rng.random() < 0.03 else 0.0)
            ts.append(t)
            hs.append(h)
        t += rng.uniform(*pause_s)
        h += rng.uniform(-np.pi, np.pi)
    return np.array(ts), np.array(hs), rng


def heading_drift_deg_per_min(p, st: np.ndarray, hd: np.ndarray) -> float:
    """Drift (°/min) of the PDR heading: robust slope of its error at the true step times, over the steps on
    straight stretches (a stride-averaged heading lags at corners: an error, but not a drift)."""
    from scipy.stats import theilslopes

    err = np.unwrap(wrap_angle(np.interp(st, p.t_s, np.unwrap(p.heading_rad)) - (hd - hd[0])))
    steady = np.abs(np.r_[hd[2:], [hd[-1]] * 2] - np.r_[[hd[0]] * 2, hd[:-2]]) < np.deg2rad(5.0)
    return float(theilslopes(np.degrees(err[steady]), st[steady] / 60.0)[0])


@pytest.mark.parametrize("mode", MODES)
def test_carrying_modes_count_steps_and_hold_heading(mode):
    """Each way of carrying, at 50 and 200 Hz with jittery timestamps, gentle and brisk gaits, 5-20 s pauses
    ending in turns on the spot, a gyro bias of 0.3 °/s per axis: steps within 3 % and heading drift within
    2 °/min over the mode's 3-minute walks (3 °/min on either; bench_pdr measures more walks)."""
    drift = []
    for seed, (fs, bounce) in enumerate([(50.0, 0.6), (200.0, 1.4)]):
        st, hd, rng = synthetic_walk(100 + seed, n_bouts=4, steps=(30, 60), pause_s=(5.0, 20.0))
        bias = np.deg2rad(rng.normal(0.0, 0.3, 3))
        imu = synthesize_phone_imu(st, hd, rng, mode=mode, fs_hz=fs, bounce_scale=bounce, gyro_bias_radps=bias)
        res = run_pdr(imu, PdrConfig())
        n = len(res.poses) - 1
        assert abs(n - len(st)) <= 0.03 * len(st), (mode, fs, bounce, n, len(st))
        drift.append(abs(heading_drift_deg_per_min(res.poses, st, hd)))
        assert res.report.quality == "ok" and res.report.heading_source == "gyro"
    assert max(drift) <= 3.0 and np.mean(drift) <= 2.0, (mode, drift)


@pytest.mark.parametrize("mode", MODES)
def test_absolute_yaw_only_while_the_phone_is_held_in_front(mode):
    """The absolute yaw is the phone's forward axis: within its noise of the walking direction when the
    phone is held in front; at the ear, swinging or in a pocket it is 55-168° off, so it is dropped."""
    st, hd, rng = synthetic_walk(7, n_bouts=2)
    imu = synthesize_phone_imu(st, hd, rng, mode=mode, fs_hz=100.0, magnetic_error_rad=0.0)
    res = run_pdr(imu, PdrConfig())
    ya = res.poses.yaw_abs_rad[1:]
    if mode == "texting":
        ok = np.isfinite(ya)
        assert ok.mean() > 0.95 and res.report.yaw_abs_not_in_front <= 0.05 * len(ya)
        err = wrap_angle(ya[ok] - np.interp(res.poses.t_s[1:][ok], st, hd))
        assert np.degrees(np.median(np.abs(err))) < 10.0
    else:
        assert np.isnan(ya).all() and res.report.yaw_abs_not_in_front >= 0.95 * len(ya)


def test_no_steps_when_standing():
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.02)
    acc = np.c_[rng.normal(0, 0.05, len(t)), rng.normal(0, 0.05, len(t)), 9.81 + rng.normal(0, 0.05, len(t))]
    empty = np.zeros(0)
    imu = ImuSignals(t, acc, t, np.zeros(len(t)), np.full(len(t), 3), empty, np.zeros((0, 3)))
    res = run_pdr(imu, PdrConfig())
    p = res.poses
    assert len(p) == 1 and p.x_m[0] == 0 and p.heading_rad[0] == 0
    assert res.report.quality == "poor" and "no steps" in res.report.warnings[0]
    assert res.report.heading_source == "rotation_vector"


@pytest.mark.parametrize("source", ["rotation_vector", "gyro"])
def test_trajectory_shape_on_synthetic_signal(source):
    st, hd, rng = synthetic_walk(3, n_bouts=2)
    imu = synthesize_phone_imu(st, hd, rng, yaw_offset_rad=0.4, yaw_noise_rad=0.03, magnetic_error_rad=0.02)
    p = run_pdr(imu, replace(PdrConfig(), heading_source=source)).poses
    assert len(p) - 1 == len(st)
    # headings relative to the first step's (the walk starts with a step, not a turn on the spot), up to the
    # yaw of the recording's first instant
    rel = hd - hd[0]
    off = float(np.median(wrap_angle(p.heading_rad[1:] - rel)))
    assert abs(off) < 0.1
    rel = rel + off
    # the shape: the true walk with the PDR's own step lengths
    true_xy = np.c_[np.r_[0, np.cumsum(p.step_length_m[1:] * np.cos(rel))],
                    np.r_[0, np.cumsum(p.step_length_m[1:] * np.sin(rel))]]
    err = np.hypot(p.x_m - true_xy[:, 0], p.y_m - true_xy[:, 1])
    assert err.max() < 0.05 * p.step_length_m.sum(), err.max()
    # the absolute yaw carries the magnetic offset, and is the same for either heading source
    dev = wrap_angle(p.yaw_abs_rad[1:] - (hd + 0.4))
    assert np.median(np.abs(dev)) < 0.1
    assert p.heading_rad[0] == 0 and p.x_m[0] == 0 and p.y_m[0] == 0
    assert np.all(np.diff(p.t_s) > 0)
    assert np.all(p.yaw_abs_sigma_rad == PdrConfig().yaw_sigma_by_accuracy_rad[3])


@pytest.mark.parametrize("how", ["rotation_vector", "still", "yaw_drift"])
def test_gyro_bias_is_found_and_removed(how):
    """A 4 °/s bias (as on some IPIN 2023 Samsung walks): found from the orientation, from still stretches or
    from the absolute yaw's drift alone; the heading then holds."""
    st, hd, rng = synthetic_walk(11, n_bouts=4, steps=(30, 60), pause_s=(5.0, 20.0))
    bias = np.deg2rad([2.0, -1.5, 3.0])
    imu = synthesize_phone_imu(st, hd, rng, mode="texting", gyro_bias_radps=bias, magnetic_error_rad=0.03)
    if how == "yaw_drift":
        imu = replace(imu, quat_xyzw=np.zeros((0, 4)))
    if how != "still":   # a hand that never rests: no still stretch
        imu = replace(imu, gyro_radps=imu.gyro_radps + rng.normal(0, 0.06, imu.gyro_radps.shape))
    res = run_pdr(imu, PdrConfig())
    assert res.report.bias_source == how
    assert abs(heading_drift_deg_per_min(res.poses, st, hd)) <= 3.0   # without its removal: 180-240 °/min
    assert res.report.gyro_bias_dps > 1.0   # (for "yaw_drift" only the part about gravity is known)


def test_turning_on_the_spot_keeps_the_heading():
    """Pauses ending with a turn of up to 180° on the spot: the heading after each is right to 10°."""
    st, hd, rng = synthetic_walk(5, n_bouts=4)
    p = run_pdr(synthesize_phone_imu(st, hd, rng, mode="swinging", fs_hz=100.0), PdrConfig()).poses
    after = np.flatnonzero(np.diff(st) > 2.0) + 1
    got = np.interp(st[after + 3], p.t_s, np.unwrap(p.heading_rad))
    assert np.degrees(np.abs(wrap_angle(got - (hd[after + 3] - hd[0])))).max() < 10.0


def test_yaw_from_quat_matches_synthetic_orientation():
    psi = np.linspace(-3, 3, 13)
    for pitch in (0.0, 0.5, 1.2, np.pi / 2):
        q = rotation_vector_samples(psi, pitch)
        np.testing.assert_allclose(wrap_angle(yaw_from_quat(q) - (psi + np.pi / 2)), 0, atol=1e-9)
    # compass azimuth (clockwise from north) -> ENU yaw
    np.testing.assert_allclose(yaw_from_azimuth_deg(np.array([0.0, 90.0, 180.0])), [np.pi / 2, 0, -np.pi / 2])


def test_rate_integration_matches_a_known_rotation():
    t = np.linspace(0, 10, 2001)
    w = np.c_[np.full_like(t, 0.3), 0.2 * np.sin(t), np.full_like(t, -0.1)]   # rad/s, body frame
    q = integrate_rates(t, w)
    # against a fine sequential integration
    r = np.eye(3)
    for k in range(1, len(t)):
        a = 0.5 * (w[k] + w[k - 1]) * (t[k] - t[k - 1])
        th = np.linalg.norm(a)
        kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / th
        r = r @ (np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx)
    np.testing.assert_allclose(quat_rotate(q[-1:], np.eye(3)), r.T, atol=1e-9)


def test_clock_strays_jumps_and_grid_bounds():
    t = np.r_[1.0, np.arange(1e5, 1e5 + 60, 0.02), 1e9]   # a stray at each end
    keep, issues = main_block(t, 30.0)
    assert keep.sum() == len(t) - 2 and not keep[0] and not keep[-1]
    assert [i.index for i in issues] == [0, len(t) - 1]
    with pytest.raises(ImuTimeError, match="time jumps by 2.592e\\+06 s") as e:
        main_block(np.r_[np.arange(0, 60, 0.02), 2592060 + np.arange(0, 60, 0.02)], 30.0)
    assert e.value.index == 3000
    # the grid follows the samples, never the clock: 0.4-s gaps at a 200-Hz median rate are refused
    t = np.cumsum(np.tile([0.005] * 3 + [0.4], 500))
    with pytest.raises(ImuTimeError, match="too irregular"):
        uniform_grid(t)
    g = uniform_grid(np.cumsum(np.tile([0.02, 0.02, 0.6], 400)))   # 400 dropouts: 401 runs
    assert len(g.t_s) <= GRID_POINTS_PER_SAMPLE * 1200 and len(g.runs()) == 401


def test_clock_problems_through_run_pdr():
    st, hd, rng = synthetic_walk(2, n_bouts=1)
    imu = synthesize_phone_imu(st, hd, rng)
    t = imu.t_acc_s.copy()
    t[5] = -1e9
    res = run_pdr(replace(imu, t_acc_s=np.sort(t)), PdrConfig())
    assert [(i.stream, i.index) for i in res.report.time_issues] == [("acc", 0)]
    assert abs(len(res.poses) - 1 - len(st)) <= 1
    gap = imu.t_acc_s + np.where(imu.t_acc_s > imu.t_acc_s[len(t) // 2], 5.0, 0.0)   # a 5-s dropout
    res = run_pdr(replace(imu, t_acc_s=gap), PdrConfig())
    assert any("no samples for 5" in i.message for i in res.report.time_issues)


def test_step_length_model():
    cfg = PdrConfig()
    tu = np.arange(0, 10, 0.02)
    s = 2.0 * np.cos(2 * np.pi * 2 * tu)   # a 4 m/s² swing over each step
    t = np.arange(1.0, 9.0, 0.5)
    np.testing.assert_allclose(step_swings(t, np.full(len(t), 0.5), tu, s), 4.0, rtol=0.01)
    # at the reference swing every step is step_length_m long; a twice larger swing all along: 2^0.1 longer
    np.testing.assert_allclose(step_lengths(np.full(20, 4.0), np.zeros(20), cfg), cfg.step_length_m)
    np.testing.assert_allclose(step_lengths(np.full(20, 8.0), np.zeros(20), cfg), cfg.step_length_m * 2**0.1)
    # one weak step among normal ones is shorter by (swing ratio)^0.4
    a = np.full(21, 4.0)
    a[10] = 1.0
    assert step_lengths(a, np.zeros(21), cfg)[10] == pytest.approx(cfg.step_length_m * 0.25**0.4)
    # pivot steps on the spot keep a quarter of their length; gentle curves all of it
    turn = np.deg2rad([10.0, 30.0, 60.0, 90.0, 170.0])
    np.testing.assert_allclose(step_lengths(np.full(5, 4.0), turn, cfg) / cfg.step_length_m,
                               [1.0, 1.0, 0.625, 0.25, 0.25])
    assert step_lengths(np.full(3, 4.0), np.zeros(3), replace(cfg, step_length_m=2.0)).max() == cfg.max_step_m


def test_integrate_increments_square():
    # four 1 m steps, turning left 90° after each: back at the start
    t, x, y, th = integrate_increments(0.0, np.arange(1.0, 5.0), np.ones(4), np.zeros(4),
                                       np.full(4, np.pi / 2))
    np.testing.assert_allclose([x[-1], y[-1]], [0, 0], atol=1e-12)
    np.testing.assert_allclose([x[1], y[1], x[2], y[2]], [1, 0, 1, 1], atol=1e-12)
    p = poses_from_increments(0.0, np.arange(1.0, 5.0), np.ones(4), np.zeros(4), np.zeros(4))
    assert np.isnan(p.yaw_abs_rad).all() and p.x_m[-1] == 4


def test_interval_mean_of_linear_signal():
    t = np.linspace(0, 10, 101)
    v = 2 * t
    np.testing.assert_allclose(interval_mean(t, v, np.array([1.0, 4.0]), np.array([3.0, 4.0])), [4.0, 8.0])


def test_missing_signals_raise_value_error():
    st, hd, rng = synthetic_walk(0, n_bouts=1)
    imu = synthesize_phone_imu(st, hd, rng)
    no_yaw = replace(imu, t_yaw_s=np.zeros(0), yaw_abs_rad=np.zeros(0), yaw_accuracy=np.zeros(0),
                     quat_xyzw=np.zeros((0, 4)))
    with pytest.raises(ValueError, match="rotation-vector"):
        run_pdr(no_yaw, replace(PdrConfig(), heading_source="rotation_vector"))
    res = run_pdr(no_yaw, PdrConfig())
    assert np.isnan(res.poses.yaw_abs_rad).all() and res.report.heading_source == "gyro"
    no_gyro = replace(imu, t_gyro_s=np.zeros(0), gyro_radps=np.zeros((0, 3)))
    with pytest.raises(ValueError, match="gyroscope"):
        run_pdr(no_gyro, replace(PdrConfig(), heading_source="gyro"))
    assert run_pdr(no_gyro, PdrConfig()).report.heading_source == "rotation_vector"
    with pytest.raises(ValueError, match="no gyroscope and no rotation-vector"):
        run_pdr(replace(no_gyro, t_yaw_s=np.zeros(0), yaw_abs_rad=np.zeros(0), yaw_accuracy=np.zeros(0),
                        quat_xyzw=np.zeros((0, 4))), PdrConfig())
    with pytest.raises(ValueError, match="accelerometer"):
        run_pdr(replace(imu, t_acc_s=np.zeros(0), acc_mps2=np.zeros((0, 3))), PdrConfig())


def test_config_is_strict():
    cfg = from_dict(PdrConfig, {"heading_source": "gyro"})
    assert cfg.heading_source == "gyro"
    ing = from_dict(IngestConfig, {"msft_ilc": {"max_wifi_age_s": 5}})
    assert ing.msft_ilc.max_wifi_age_s == 5.0
    with pytest.raises(ConfigError, match="unknown key 'msft_ilc'"):
        from_dict(PdrConfig, {"msft_ilc": {"max_wifi_age_s": 5}})
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(PdrConfig, {"step_detector": "peak_valley"})
    with pytest.raises(ConfigError, match="must be one of"):
        from_dict(PdrConfig, {"heading_source": "compass"})
    with pytest.raises(ConfigError, match="together"):
        from_dict(IngestConfig, {"ipin": {"origin_lat_deg": 10.0}})
    with pytest.raises(ConfigError, match="max_wifi_age_s"):
        from_dict(IngestConfig, {"msft_ilc": {"max_wifi_age_s": -1}})
    with pytest.raises(ConfigError, match="max_gap_s"):
        from_dict(PdrConfig, {"max_gap_s": 1e9})


def test_phone_waved_not_walked_counts_no_steps():
    """20 s of waving the phone (as when calibrating the compass: periodic, but turning at 6 rad/s) before
    a walk: no steps and no absolute yaw there, the time reported as handling."""
    st, hd, rng = synthetic_walk(4, n_bouts=1)
    walk = synthesize_phone_imu(st + 21.0, hd, rng, t_start_s=20.0)
    t = np.arange(0.0, 20.0, 0.02)
    wave = np.sin(2 * np.pi * 1.5 * t)
    acc = np.c_[3.0 * wave, np.zeros_like(t), 9.81 + 3.0 * np.cos(2 * np.pi * 1.5 * t)]
    gyro = np.c_[8.0 * wave, 6.0 * np.cos(2 * np.pi * 1.5 * t), np.zeros_like(t)]
    q = np.tile(walk.quat_xyzw[:1], (len(t), 1))
    imu = ImuSignals(np.r_[t, walk.t_acc_s], np.r_[acc, walk.acc_mps2], np.r_[t, walk.t_yaw_s],
                     np.r_[np.zeros(len(t)), walk.yaw_abs_rad], np.r_[np.full(len(t), 3), walk.yaw_accuracy],
                     np.r_[t, walk.t_gyro_s], np.r_[gyro, walk.gyro_radps], np.r_[q, walk.quat_xyzw])
    res = run_pdr(imu, PdrConfig())
    assert abs(len(res.poses) - 1 - len(st)) <= 1 and res.poses.t_s[1] > 20.0
    assert res.report.handling_s >= 15.0 and np.isnan(res.poses.yaw_abs_rad[0])
    assert np.isfinite(res.poses.yaw_abs_rad[5:]).all()


def test_one_angle_wrap_matches_the_modulo_it_replaced() -> None:
    """geometry.wrap (now the PDR's and the simulator's wrap too) equals the (a + pi) % 2pi - pi the PDR
    and the walkers used, to rounding (+-pi itself may keep either sign); NaN stays NaN."""
    a = np.random.default_rng(4).uniform(-60, 60, 10_000)
    old = (a + np.pi) % (2 * np.pi) - np.pi
    new = wrap_angle(a)
    assert np.all((new > -np.pi) & (new <= np.pi))
    assert np.abs(new - old).max() < 1e-13
    np.testing.assert_allclose(np.abs(wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi]))), np.pi, rtol=0, atol=1e-15)
    assert np.isnan(wrap_angle(np.array([np.nan]))[0])
