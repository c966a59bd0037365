"""Phone PDR (rmbuild.pdr) on seeded synthetic IMU signals with known steps and headings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rmbuild.config.base import from_dict
from rmbuild.config.pdr import PdrConfig
from rmbuild.errors import ConfigError
from rmbuild.pdr import ImuSignals, integrate_increments, poses_from_increments, run_pdr, yaw_from_quat
from rmbuild.pdr.heading import interval_mean, wrap_angle, yaw_from_azimuth_deg
from rmbuild.pdr.length import step_frequency, step_lengths
from rmbuild.pdr.steps import detect_steps_pan_tompkins, pan_tompkins_signal, prepare_magnitude
from rmbuild.pdr.synth import rotation_vector_samples, synthesize_phone_imu


def synthetic_walk(seed: int, n_bouts: int = 3):
    """Bouts of walking (1.5-2.2 Hz, slowly turning) separated by 2-4 s stops."""
    rng = np.random.default_rng(seed)
    ts, t = [], 0.0
    for _ in range(n_bouts):
        per = rng.uniform(0.45, 0.65)
        for _ in range(int(rng.integers(15, 40))):
            t += per * rng.uniform(0.92, 1.08)
            ts.append(t)
        t += rng.uniform(2.0, 4.0)
    st = np.array(ts)
    hd = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0, 0.04, len(st)))
    return st, hd, rng


@pytest.mark.parametrize("detector", ["peak_valley", "pan_tompkins"])
def test_step_count_on_synthetic_signal(detector):
    cfg = replace(PdrConfig(), step_detector=detector)
    errors, total = [], 0
    for seed in range(12):
        st, hd, rng = synthetic_walk(seed)
        imu = synthesize_phone_imu(st, hd, rng, amp_mps2=rng.uniform(2.0, 3.5))
        poses = run_pdr(imu, cfg)
        errors.append(len(poses) - 1 - len(st))
        total += len(st)
    # within 2 % of the true count overall, no walk off by more than 2 steps
    assert abs(sum(errors)) <= 0.02 * total, errors
    assert max(abs(e) for e in errors) <= 2, errors


def test_no_steps_when_standing():
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.02)
    acc = np.c_[rng.normal(0, 0.05, len(t)), rng.normal(0, 0.05, len(t)), 9.81 + rng.normal(0, 0.05, len(t))]
    empty = np.zeros(0)
    imu = ImuSignals(t, acc, t, np.zeros(len(t)), np.full(len(t), 3), empty, np.zeros((0, 3)))
    poses = run_pdr(imu, replace(PdrConfig(), heading_source="rotation_vector"))
    assert len(poses) == 1 and poses.x_m[0] == 0 and poses.heading_rad[0] == 0


@pytest.mark.parametrize("source", ["rotation_vector", "gyro"])
def test_trajectory_shape_on_synthetic_signal(source):
    st, hd, rng = synthetic_walk(3, n_bouts=2)
    imu = synthesize_phone_imu(st, hd, rng, yaw_offset_rad=0.4, yaw_noise_rad=0.03)
    cfg = replace(PdrConfig(), heading_source=source, step_length_model="fixed", step_length_m=0.7)
    p = run_pdr(imu, cfg)
    assert len(p) - 1 == len(st)
    # the true walk in its own frame: start at the origin, heading relative to the first step's heading
    rel = hd - hd[0]
    tx = np.r_[0, np.cumsum(0.7 * np.cos(rel))]
    ty = np.r_[0, np.cumsum(0.7 * np.sin(rel))]
    # PDR heading is relative to the heading at the recording start (= first step's heading here)
    err = np.hypot(p.x_m - tx, p.y_m - ty)
    assert err.max() < 0.1 * 0.7 * len(st), err.max()
    assert np.max(np.abs(wrap_angle(p.heading_rad[1:] - rel))) < 0.25
    # the absolute yaw carries the magnetic offset, and is the same for either heading source
    dev = wrap_angle(p.yaw_abs_rad[1:] - (hd + 0.4))
    assert np.median(np.abs(dev)) < 0.1
    assert p.heading_rad[0] == 0 and p.x_m[0] == 0 and p.y_m[0] == 0
    assert np.all(np.diff(p.t_s) > 0)
    assert np.all(p.yaw_abs_sigma_rad == PdrConfig().yaw_sigma_by_accuracy_rad[3])


def test_yaw_from_quat_matches_synthetic_orientation():
    psi = np.linspace(-3, 3, 13)
    for pitch in (0.0, 0.5, 1.2, np.pi / 2):
        q = rotation_vector_samples(psi, pitch)
        np.testing.assert_allclose(wrap_angle(yaw_from_quat(q) - (psi + np.pi / 2)), 0, atol=1e-9)
    # compass azimuth (clockwise from north) -> ENU yaw
    np.testing.assert_allclose(yaw_from_azimuth_deg(np.array([0.0, 90.0, 180.0])), [np.pi / 2, 0, -np.pi / 2])


def test_pan_tompkins_signal_and_refractory():
    x = np.r_[np.zeros(10), np.arange(10.0), np.full(10, 9.0)]
    s = pan_tompkins_signal(x)
    assert np.all(s >= 0) and s[:10].max() == 0
    # eq. 6 on a unit ramp: [2n + (n - 1) - (n - 3) - 2(n - 4)] / 4 = 2.5 -> eq. 7: 3.5² - 1
    assert s[16] == pytest.approx(3.5**2 - 1)
    t = np.arange(len(x)) * 0.02
    cfg = replace(PdrConfig(), pt_threshold=0.1, pt_refractory_s=0.3)
    idx = detect_steps_pan_tompkins(t, np.tile(x, 1), cfg)
    assert np.all(np.diff(t[idx]) >= 0.3)


def test_prepare_magnitude_resamples_uniformly():
    t = np.sort(np.r_[0.0, np.random.default_rng(0).uniform(0, 5, 200), 5.0])
    acc = np.c_[np.zeros_like(t), np.zeros_like(t), np.full_like(t, 9.8)]
    tu, m = prepare_magnitude(t, acc, PdrConfig())
    assert np.allclose(np.diff(tu), 1 / PdrConfig().sample_hz)
    assert np.allclose(m, 9.8)


def test_step_length_models():
    t = np.array([1.0, 1.5, 2.0, 5.0])
    f = step_frequency(t, 0.0, 1.5)
    assert np.isnan(f[0]) and f[1] == pytest.approx(2.0) and np.isnan(f[3])
    cfg = replace(PdrConfig(), step_length_model="frequency", freq_alpha=0.3, freq_beta=0.1)
    s = step_lengths(t, f, None, None, cfg)
    assert s[1] == pytest.approx(0.7) and s[0] == pytest.approx(0.7)   # unknown -> walk median
    cfg = replace(PdrConfig(), step_length_model="weinberg", weinberg_k=0.5)
    tu = np.arange(0, 6, 0.02)
    mag = 9.8 + 2.0 * np.cos(2 * np.pi * 2 * tu)   # a_max - a_min = 4 -> 0.5 * 4^0.25
    s = step_lengths(np.array([2.0, 2.5]), np.array([2.0, 2.0]), tu, mag, cfg)
    np.testing.assert_allclose(s, 0.5 * 4**0.25, rtol=1e-3)
    cfg = replace(PdrConfig(), step_length_model="fixed", step_length_m=5.0)
    assert step_lengths(t, f, None, None, cfg).max() == cfg.max_step_m


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
    no_yaw = replace(imu, t_yaw_s=np.zeros(0), yaw_abs_rad=np.zeros(0), yaw_accuracy=np.zeros(0))
    with pytest.raises(ValueError, match="rotation-vector"):
        run_pdr(no_yaw, replace(PdrConfig(), heading_source="rotation_vector"))
    p = run_pdr(no_yaw, replace(PdrConfig(), heading_source="gyro"))
    assert np.isnan(p.yaw_abs_rad).all()
    with pytest.raises(ValueError, match="gyroscope"):
        run_pdr(replace(imu, t_gyro_s=np.zeros(0), gyro_radps=np.zeros((0, 3))),
                replace(PdrConfig(), heading_source="gyro"))
    with pytest.raises(ValueError, match="accelerometer"):
        run_pdr(replace(imu, t_acc_s=np.zeros(0), acc_mps2=np.zeros((0, 3))), PdrConfig())


def test_config_is_strict():
    cfg = from_dict(PdrConfig, {"step_detector": "pan_tompkins", "msft_ilc": {"max_wifi_age_s": 5}})
    assert cfg.msft_ilc.max_wifi_age_s == 5.0
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(PdrConfig, {"step_detektor": "x"})
    with pytest.raises(ConfigError, match="must be one of"):
        from_dict(PdrConfig, {"step_detector": "fft"})
    with pytest.raises(ConfigError, match="together"):
        from_dict(PdrConfig, {"ipin": {"origin_lat_deg": 10.0}})
    with pytest.raises(ConfigError, match="max_wifi_age_s"):
        from_dict(PdrConfig, {"msft_ilc": {"max_wifi_age_s": -1}})
    with pytest.raises(ConfigError, match="lowpass"):
        from_dict(PdrConfig, {"lowpass_hz": 30.0})
