"""The seeded synthetic venue (rmbuild.synthetic): determinism, frames, truth consistency, radio sanity,
presets and config validation. Tiny preset only, so the whole file runs in a few seconds."""

from __future__ import annotations

import dataclasses
import re
import tomllib

import numpy as np
import pandas as pd
import pytest
from synthetic_difficulty import pair_rule_stats, raw_walk_errors, rss_distance

from rmbuild.config.base import from_dict, to_toml
from rmbuild.config.simulate import MAX_SIMULATED_STEPS, SimulateConfig, preset_config
from rmbuild.errors import ConfigError
from rmbuild.synthetic import radio_field, simulate
from rmbuild.synthetic.geometry import segments_cross, wall_loss_from_point

TABLES = ("walks", "poses", "wifi", "fixes", "truth_poses", "truth_aps", "truth_devices", "truth_users",
          "truth_walks", "truth_landmarks")


@pytest.fixture(scope="module")
def tiny():
    return simulate(preset_config("tiny", 3))


@pytest.fixture(scope="module")
def variant():
    """tiny seed 3 without IMU errors, without magnetometers, with a test device."""
    cfg = preset_config("tiny", 3)
    r = dataclasses.replace
    return simulate(r(
        cfg,
        imu=r(cfg.imu, step_scale_sd=0.0, step_noise_m=0.0, heading_bias_sd_dps=0.0, heading_bias_rw_dps=0.0,
              heading_step_noise_deg=0.0),
        magnetometer=r(cfg.magnetometer, missing_fraction=1.0),
        devices=r(cfg.devices, test_device=(0.8, -6.0)),
    ))


def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, float_format="%.17g")


def _placed(data) -> np.ndarray:
    """Own-frame poses moved by each walk's true start pose (world_T_walk), (n, 2)."""
    start = data.truth_walks.set_index("walk_id").loc[data.poses["walk_id"]]
    c, s = np.cos(start["heading0_rad"].to_numpy()), np.sin(start["heading0_rad"].to_numpy())
    x, y = data.poses["x_m"].to_numpy(), data.poses["y_m"].to_numpy()
    return np.c_[start["x0_m"].to_numpy() + c * x - s * y, start["y0_m"].to_numpy() + s * x + c * y]


def test_deterministic(tiny):
    again = simulate(preset_config("tiny", 3))
    for name in TABLES:
        assert _csv(getattr(tiny, name)) == _csv(getattr(again, name)), name
    assert tiny.venue == again.venue
    other = simulate(preset_config("tiny", 4))
    assert _csv(other.poses) != _csv(tiny.poses)
    assert _csv(other.wifi) != _csv(tiny.wifi)


def test_schemas(tiny):
    assert list(tiny.walks.columns) == ["walk_id", "device_id", "user_id", "role"]
    assert list(tiny.poses.columns) == ["walk_id", "t_s", "x_m", "y_m", "heading_rad", "yaw_abs_rad",
                                        "yaw_abs_sigma_rad", "step_freq_hz"]
    assert list(tiny.wifi.columns) == ["walk_id", "t_s", "bssid", "rssi_dbm", "freq_mhz", "ssid"]
    assert list(tiny.fixes.columns) == ["walk_id", "t_s", "x_m", "y_m", "label"]
    assert list(tiny.truth_poses.columns) == ["walk_id", "t_s", "x_m", "y_m", "heading_rad"]
    assert list(tiny.truth_aps.columns) == ["bssid", "x_m", "y_m", "tx_power_dbm", "path_loss_exp", "band"]
    assert list(tiny.truth_walks.columns) == ["walk_id", "x0_m", "y0_m", "heading0_rad"]
    assert list(tiny.truth_devices.columns) == ["device_id", "k", "b"]
    assert list(tiny.truth_users.columns) == ["user_id", "alpha", "beta"]
    assert list(tiny.truth_landmarks.columns) == ["label", "x_m", "y_m"]
    assert set(tiny.walks["role"]) <= {"map", "test"}
    assert (tiny.walks["role"] == "test").sum() == preset_config("tiny", 3).walkers.n_test_walks
    assert set(tiny.poses["walk_id"]) == set(tiny.walks["walk_id"])
    assert set(tiny.walks["device_id"]) <= set(tiny.truth_devices["device_id"])
    assert set(tiny.walks["user_id"]) <= set(tiny.truth_users["user_id"])
    v = tiny.venue
    assert {"bounds", "walls", "wall_atten_db", "rooms", "hall", "corridors"} <= set(v)
    assert len(v["walls"]) == len(v["wall_atten_db"]) > 10 and all(len(w) == 4 for w in v["walls"])
    assert all(a >= 0 for a in v["wall_atten_db"])


def test_walk_frames_and_times(tiny):
    first = tiny.poses.groupby("walk_id", sort=False).head(1)
    assert (first[["x_m", "y_m", "heading_rad"]].to_numpy() == 0.0).all()
    for _, g in tiny.poses.groupby("walk_id", sort=False):
        assert (np.diff(g["t_s"].to_numpy()) > 0.2).all()
    assert tiny.poses["heading_rad"].between(-np.pi, np.pi).all()
    f = tiny.poses["step_freq_hz"]
    assert f.between(1.0, 3.0).all() and 1.4 < f.median() < 2.2
    assert (tiny.poses["t_s"].to_numpy() == tiny.truth_poses["t_s"].to_numpy()).all()
    assert (tiny.poses["walk_id"].to_numpy() == tiny.truth_poses["walk_id"].to_numpy()).all()


def test_truth_start_pose_matches_truth_poses(tiny):
    first = tiny.truth_poses.groupby("walk_id", sort=False).head(1).reset_index(drop=True)
    tw = tiny.truth_walks
    assert (first["walk_id"] == tw["walk_id"]).all()
    np.testing.assert_allclose(first[["x_m", "y_m", "heading_rad"]].to_numpy(),
                               tw[["x0_m", "y0_m", "heading0_rad"]].to_numpy())
    # true heading = direction of the step into the pose; true step lengths look like walking
    for _, g in tiny.truth_poses.groupby("walk_id", sort=False):
        xy = g[["x_m", "y_m"]].to_numpy()
        d = np.diff(xy, axis=0)
        ang = np.arctan2(d[:, 1], d[:, 0]) - g["heading_rad"].to_numpy()[1:]
        assert np.abs(np.angle(np.exp(1j * ang))).max() < 1e-9
        step = np.hypot(d[:, 0], d[:, 1])
        assert 0.4 < np.median(step) < 1.0 and step.max() < 1.6
    b = tiny.venue["bounds"]
    t = tiny.truth_poses
    assert t["x_m"].between(b[0], b[2]).all() and t["y_m"].between(b[1], b[3]).all()


def test_dead_reckoning_error_model(tiny, variant):
    err = np.hypot(*(_placed(tiny) - tiny.truth_poses[["x_m", "y_m"]].to_numpy()).T)
    per_walk = raw_walk_errors(tiny)
    assert (per_walk["max_err_m"] <= 0.15 * per_walk["length_m"] + 0.5).all()
    assert (per_walk["end_err_m"] > 0.05).all()  # the IMU errs
    # the error grows along a walk: late steps are worse than early ones
    early, late = [], []
    for _, idx in tiny.poses.groupby("walk_id", sort=False).indices.items():
        n = len(idx)
        early.append(err[idx[: max(2, n // 10)]].mean())
        late.append(err[idx[-max(2, n // 10):]].mean())
    assert np.mean(late) > 2 * np.mean(early)
    # without IMU errors, the own-frame poses reproduce the truth exactly
    exact = variant
    np.testing.assert_allclose(_placed(exact), exact.truth_poses[["x_m", "y_m"]].to_numpy(), atol=1e-6)
    dh = exact.poses["heading_rad"].to_numpy() + exact.truth_walks.set_index("walk_id").loc[
        exact.poses["walk_id"], "heading0_rad"].to_numpy() - exact.truth_poses["heading_rad"].to_numpy()
    assert np.abs(np.angle(np.exp(1j * dh))).max() < 1e-6


def test_magnetometer(tiny, variant):
    yaw = tiny.poses["yaw_abs_rad"].to_numpy()
    assert np.isfinite(yaw).all() and (np.abs(yaw) <= np.pi).all()
    assert (tiny.poses["yaw_abs_sigma_rad"] == 0.25).all()
    e = np.rad2deg(np.angle(np.exp(1j * (yaw - tiny.truth_poses["heading_rad"].to_numpy()))))
    assert 3.0 < np.median(np.abs(e)) < 20.0  # disturbed, but informative
    assert np.percentile(np.abs(e), 99) > 20.0  # some places are much worse
    no_mag = variant
    assert no_mag.poses["yaw_abs_rad"].isna().all() and no_mag.poses["yaw_abs_sigma_rad"].isna().all()


def test_wifi_readings(tiny):
    w = tiny.wifi
    r = w["rssi_dbm"].to_numpy()
    assert (r == np.round(r)).all()
    assert r.min() >= -100.0 and r.max() <= -20.0
    assert -92.0 < np.median(r) < -65.0
    # a soft floor: few readings right at the hard floor, most of the weak ones in the upper 90s
    assert (r <= -98).mean() < 0.08
    assert w["bssid"].map(lambda b: re.fullmatch(r"([0-9a-f]{2}:){5}[0-9a-f]{2}", b) is not None).all()
    assert set(w["bssid"]) <= set(tiny.truth_aps["bssid"])
    f = w["freq_mhz"]
    assert (f.between(2412, 2484) | f.between(5180, 5825)).all() and f.between(5180, 5825).any()
    assert (w["ssid"].str.len() > 0).all()
    scans = w.groupby(["walk_id", "t_s"])
    per_scan = scans.size()
    assert 8 < per_scan.mean() < 40 and per_scan.min() >= 1
    assert (scans["bssid"].nunique() == per_scan).all()  # one reading per BSSID and scan
    # scan interval 2-4 s
    for _, g in w.groupby("walk_id"):
        dt = np.diff(np.unique(g["t_s"].to_numpy()))
        assert np.median(dt) == pytest.approx(np.clip(np.median(dt), 1.9, 4.5))
    # readings scatter around the noise-free field at the true position (device offset, body loss, noise)
    t_pos = tiny.truth_poses
    xy = np.empty((len(w), 2))
    for wid, idx in w.groupby("walk_id").indices.items():
        m = (t_pos["walk_id"] == wid).to_numpy()
        xy[idx, 0] = np.interp(w["t_s"].to_numpy()[idx], t_pos.loc[m, "t_s"], t_pos.loc[m, "x_m"])
        xy[idx, 1] = np.interp(w["t_s"].to_numpy()[idx], t_pos.loc[m, "t_s"], t_pos.loc[m, "y_m"])
    bss = np.array(sorted(w["bssid"].unique()))
    field = radio_field(tiny, xy, bss)
    mean = field[np.arange(len(w)), np.searchsorted(bss, w["bssid"].to_numpy())]
    strong = mean > -75.0  # far from the detection floor: no selection bias
    resid = r[strong] - mean[strong]
    assert abs(np.median(resid)) < 4.0
    assert 3.0 < resid.std() < 10.0


def test_radio_field(tiny):
    aps = tiny.truth_aps
    b = list(aps["bssid"].iloc[[2, 0]])
    xy = aps[["x_m", "y_m"]].to_numpy()[[2, 0]]
    f = radio_field(tiny, xy, b)
    assert f.shape == (2, 2)
    assert f[0, 0] > -60 and f[1, 1] > -60  # at the AP itself: about its 1 m power
    assert np.all(f == radio_field(tiny.radio, xy, b))
    assert radio_field(tiny, xy).shape == (2, len(aps))
    with pytest.raises(KeyError):
        radio_field(tiny, xy, ["00:00:00:00:00:00"])
    # far away it is weaker
    ap = xy[0]
    ring = ap + np.c_[np.cos(np.linspace(0, 6, 30)), np.sin(np.linspace(0, 6, 30))] * 25.0
    assert np.median(radio_field(tiny, ring, b[:1])) < f[0, 0] - 25.0


def test_fixes_at_landmarks(tiny):
    fx = tiny.fixes
    assert len(fx) >= 3
    lm = tiny.truth_landmarks.set_index("label")
    at = lm.loc[fx["label"], ["x_m", "y_m"]].to_numpy(float)
    np.testing.assert_allclose(fx[["x_m", "y_m"]].to_numpy(float), at)
    radius = preset_config("tiny", 3).venue.landmark_radius_m
    for _, row in fx.iterrows():
        tp = tiny.truth_poses[(tiny.truth_poses["walk_id"] == row["walk_id"])
                              & (tiny.truth_poses["t_s"] == row["t_s"])]
        assert len(tp) == 1
        assert np.hypot(tp["x_m"].iloc[0] - row["x_m"], tp["y_m"].iloc[0] - row["y_m"]) <= radius + 1e-9


def test_tiny_size_and_progress():
    calls = []
    data = simulate(preset_config("tiny", 5), progress=lambda stage, frac: calls.append((stage, frac)))
    assert len(data.walks) == 5 and 400 <= len(data.poses) <= 900
    assert calls and all(0.0 <= f <= 1.0 for _, f in calls) and calls[-1][1] == 1.0


def _expected_steps(cfg: SimulateConfig) -> float:
    w = cfg.walkers
    return w.n_long_walks * np.mean(w.long_walk_steps) + w.n_short_walks * np.mean(w.short_walk_steps)


def test_preset_sizes():
    assert 400 <= _expected_steps(preset_config("tiny", 0)) <= 900
    d = preset_config("default", 0)
    assert 8 <= d.walkers.n_long_walks + d.walkers.n_short_walks <= 12
    assert 4000 <= _expected_steps(d) <= 6000
    assert 40_000 <= _expected_steps(preset_config("large", 0)) <= 60_000
    month, large = preset_config("month", 0), preset_config("large", 0)
    assert 450_000 <= _expected_steps(month) <= 550_000  # a venue-month: large's venue, ten times the walks
    assert month.walkers.n_long_walks + month.walkers.n_short_walks == 1000
    assert month.venue == large.venue and month.radio == large.radio
    year = preset_config("year", 0)  # four venue-months
    assert 1_800_000 <= _expected_steps(year) <= 2_200_000 and year.venue == large.venue
    for w in (month.walkers, year.walkers):  # within the simulator's bound on the most steps a simulation may draw
        assert w.n_long_walks * w.long_walk_steps[1] + w.n_short_walks * w.short_walk_steps[1] <= MAX_SIMULATED_STEPS
    assert 100 <= d.venue.width_m <= 150 and 60 <= d.venue.height_m <= 100 and d.venue.hall_width_m > 20
    assert SimulateConfig() == preset_config("default", 7)
    with pytest.raises(ValueError, match="unknown simulate preset"):
        preset_config("huge", 0)


def test_corridor12():
    data = simulate(preset_config("corridor12", 2))
    assert len(data.walks) == 12 and (data.walks["role"] == "map").all()
    ext = data.truth_poses.groupby("walk_id")["x_m"].agg(lambda x: x.max() - x.min())
    assert (ext > 60.0).all()  # long, straight-ish walks along the corridor
    corr = data.venue["corridors"][0]
    assert data.truth_poses["y_m"].between(corr[1], corr[3]).all()
    # random initial headings: the start poses face all ways
    h = data.truth_walks["heading0_rad"].to_numpy()
    assert np.abs(np.mean(np.exp(1j * h))) < 0.6


def test_test_device(variant):
    data = variant
    test = data.walks[data.walks["role"] == "test"]
    assert len(test) == 1 and (test["device_id"] == "dtest").all()
    row = data.truth_devices.set_index("device_id").loc["dtest"]
    assert (row["k"], row["b"]) == (0.8, -6.0)
    assert (data.walks.loc[data.walks["role"] == "map", "device_id"] != "dtest").all()


@pytest.mark.parametrize("section,key,value", [
    ("venue", "width_m", -5.0),
    ("venue", "n_x_corridors", 0),
    ("venue", "hall_width_m", 5.0),
    ("radio", "n_aps", 0),
    ("radio", "path_loss_exp", [3.5, 2.0]),
    ("radio", "miss_prob", 1.0),
    ("radio", "detect_mid_dbm", -110.0),
    ("walkers", "n_test_walks", 99),
    ("walkers", "step_freq_hz", [0.1, 2.0]),
    ("imu", "step_scale_sd", -0.1),
    ("magnetometer", "missing_fraction", 1.5),
    ("devices", "test_device", [0.0, 0.0]),
])
def test_validate_rejects(section, key, value):
    with pytest.raises(ConfigError):
        from_dict(SimulateConfig, {section: {key: value}})
    sub = getattr(SimulateConfig(), section)
    with pytest.raises(ValueError):
        dataclasses.replace(sub, **{key: tuple(value) if isinstance(value, list) else value}).validate()


def test_config_strict_and_round_trip():
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(SimulateConfig, {"venue": {"widht_m": 100.0}})
    with pytest.raises(ConfigError):
        from_dict(SimulateConfig, {"walkers": {"start_facing": "sideways"}})
    for name in ("tiny", "large", "month", "year", "corridor12"):
        cfg = preset_config(name, 11)
        text = to_toml(cfg, "simulate")
        assert from_dict(SimulateConfig, tomllib.loads(text)["simulate"]) == cfg


def test_geometry_helpers():
    walls = np.array([[0.0, -1.0, 0.0, 1.0], [5.0, -1.0, 5.0, 1.0], [2.0, 3.0, 2.0, 4.0]])
    p0 = np.array([[-1.0, 0.0], [-1.0, 0.0], [1.0, 0.0]])
    p1 = np.array([[6.0, 0.0], [1.0, 0.0], [4.0, 0.0]])
    np.testing.assert_array_equal(segments_cross(p0, p1, walls),
                                  [[True, True, False], [True, False, False], [False, False, False]])
    rng = np.random.default_rng(0)
    walls = np.c_[rng.uniform(0, 50, (40, 2)), rng.uniform(0, 50, (40, 2))]
    pts = rng.uniform(0, 50, (3000, 2))
    src = np.array([20.0, 30.0])
    att = rng.uniform(1, 5, 40)
    ref = segments_cross(np.repeat(src[None], len(pts), 0), pts, walls).astype(float) @ att
    got = wall_loss_from_point(src, pts, walls, att, chunk=128)
    assert np.mean(np.abs(got - ref) < 1e-4) > 0.999


def test_pair_rule_diagnostics(tiny):
    a = np.array([[-50.0, np.nan, -70.0], [-55.0, -80.0, np.nan]])
    d = rss_distance(a, a)
    assert d[0, 0] == 0.0
    assert d[0, 1] == pytest.approx(np.sqrt((5.0**2 + 30.0**2 + 40.0**2) / 3))
    st = pair_rule_stats(tiny)
    assert st.n_scan_nodes == tiny.wifi.groupby(["walk_id", "t_s"]).ngroups
    assert st.n_pairs > 0 and 0.2 < st.false_rate < 0.9
