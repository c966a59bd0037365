"""`simulate`: the seeded synthetic venue as the input tables a user would hand to `rmbuild ingest`, plus
the truth behind them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.config.simulate import SimulateConfig
from rmbuild.synthetic.radio import RadioModel, build_radio, scan_cull_level, scan_readings
from rmbuild.synthetic.venue import Venue, build_venue
from rmbuild.synthetic.walkers import MagneticField, Router, User, dead_reckon, plan_route, walk_route

# independent random streams (numpy SeedSequence children), so e.g. the walks do not change when only
# the radio section of the config changes
_STREAMS = ("venue", "radio", "people", "magnetic", "walks", "scans")
#: spawn key of the BLE beacons' random stream (far past the spawned streams' 0, 1, ...)
BLE_STREAM_KEY = 1000


@dataclass
class SimulatedData:
    """Input tables (walks, poses, wifi, fixes) and truth tables of one simulated venue.

    Input schemas (one row per ...):
      walks: walk_id, device_id, user_id, role ("map" / "test")
      poses (step): walk_id, t_s, x_m, y_m, heading_rad (own frame, first pose (0, 0, 0)), yaw_abs_rad,
        yaw_abs_sigma_rad (NaN without magnetometer), step_freq_hz
      wifi (reading): walk_id, t_s, bssid, rssi_dbm, freq_mhz, ssid (readings of one scan share t_s)
      fixes (landmark press): walk_id, t_s, x_m, y_m, label (true building-frame landmark position)
    Truth: truth_poses (same rows as poses, building frame), truth_aps, truth_devices (k, b),
    truth_users (alpha, beta), truth_walks (x0_m, y0_m, heading0_rad = world_T_walk), truth_landmarks,
    venue (JSON-able floor plan). ``radio`` is the true radio field model (see :func:`radio_field`).
    """

    walks: pd.DataFrame
    poses: pd.DataFrame
    wifi: pd.DataFrame
    fixes: pd.DataFrame
    truth_poses: pd.DataFrame
    truth_aps: pd.DataFrame
    truth_devices: pd.DataFrame
    truth_users: pd.DataFrame
    truth_walks: pd.DataFrame
    truth_landmarks: pd.DataFrame
    venue: dict
    radio: RadioModel
    #: a building's floor changes (walk_id, kind, from / to floor, step index and time of the first step on
    #: the new floor), :mod:`rmbuild.synthetic.floor_change`; None for one floor
    truth_floor_changes: pd.DataFrame | None = None
    #: BLE readings (walk_id, t_s, bssid, rssi_dbm) and the true beacons (bssid, x_m, y_m), with
    #: ``[simulate.ble] n_beacons`` > 0 (:mod:`rmbuild.synthetic.ble`); None without beacons
    ble: pd.DataFrame | None = None
    truth_beacons: pd.DataFrame | None = None


def radio_field(
    data_or_model: SimulatedData | RadioModel, xy: np.ndarray, bssids: Sequence[str] | None = None
) -> np.ndarray:
    """The true, noise-free mean RSSI in dBm (n, n_ap) at positions ``xy`` (n, 2) m, building frame.

    Path loss + walls + static shadowing of a reference device (k = 1, b = 0), without body loss, noise or
    detection. ``bssids`` picks and orders the columns (default: every BSSID in truth_aps order); an
    unknown BSSID raises KeyError.
    """
    model = data_or_model.radio if isinstance(data_or_model, SimulatedData) else data_or_model
    if bssids is None:
        cols = np.arange(len(model.bssid))
    else:
        index = {str(b): i for i, b in enumerate(model.bssid)}
        missing = [b for b in bssids if str(b) not in index]
        if missing:
            raise KeyError(f"unknown BSSID {missing[0]!r}")
        cols = np.array([index[str(b)] for b in bssids], dtype=np.int64)
    used, inverse = np.unique(model.bssid_radio[cols], return_inverse=True)
    field = model.mean_rss_radios(np.asarray(xy, dtype=np.float64).reshape(-1, 2), radios=used)
    return field[:, inverse]


def _walk_kinds(cfg: SimulateConfig, rng: np.random.Generator) -> list[str]:
    w = cfg.walkers
    short = "end_to_end" if w.short_walk_route == "end_to_end" else "short"
    kinds = ["long"] * w.n_long_walks + [short] * w.n_short_walks
    return [kinds[i] for i in rng.permutation(len(kinds))]


@dataclass
class _WalkPlan:
    """One walk to simulate: id, route kind ("long" / "short" / "end_to_end"), role, user and device row."""

    walk_id: str
    kind: str
    role: str
    user: int
    device: int
    n_steps: int


@dataclass
class _Scans:
    """The Wi-Fi scans of one walk before their readings are drawn: times, where the walker was at the
    start / end of each scan, heading, the device model and the walk's scan random stream."""

    walk_id: str
    t_s: np.ndarray
    xy0: np.ndarray
    xy1: np.ndarray
    heading: np.ndarray
    k: float
    b: float
    rng: np.random.Generator


@dataclass
class _WalkTables:
    poses: pd.DataFrame
    truth: pd.DataFrame
    start: tuple[str, float, float, float]
    fixes: pd.DataFrame
    scans: _Scans


def simulate(cfg: SimulateConfig, progress: Callable[[str, float], None] | None = None) -> SimulatedData:
    """Simulate the venue, walks, sensors and Wi-Fi scans of ``cfg`` (deterministic in ``cfg.seed``).

    ``progress(stage, fraction)`` is called now and then with fraction in [0, 1]. Pure: no I/O.
    """
    cfg.validate()
    report = progress or (lambda stage, frac: None)
    seeds = dict(zip(_STREAMS, np.random.SeedSequence(cfg.seed).spawn(len(_STREAMS))))
    rngs = {name: np.random.default_rng(s) for name, s in seeds.items()}

    report("venue", 0.0)
    venue = build_venue(cfg.venue, rngs["venue"])
    radio = build_radio(cfg.radio, venue, rngs["radio"])
    magnetic = MagneticField(cfg.magnetometer, venue, rngs["magnetic"])
    router = Router(venue)
    users, devices = _people(cfg, rngs["people"])
    plans = _walk_plans(cfg, rngs["people"])

    n_walks = len(plans)
    walk_seeds = seeds["walks"].spawn(n_walks)
    scan_seeds = seeds["scans"].spawn(n_walks)
    walks: list[_WalkTables] = []
    for i, plan in enumerate(plans):
        walks.append(_simulate_walk(cfg, plan, users[plan.user], devices.iloc[plan.device], venue, router, magnetic,
                                    np.random.default_rng(walk_seeds[i]), np.random.default_rng(scan_seeds[i])))
        report("walks", (i + 1) / n_walks)
    wifi = _wifi_readings(cfg, radio, devices, [w.scans for w in walks], report)

    data = SimulatedData(
        walks=pd.DataFrame({
            "walk_id": [p.walk_id for p in plans],
            "device_id": [str(devices.iloc[p.device]["device_id"]) for p in plans],
            "user_id": [users[p.user].user_id for p in plans],
            "role": [p.role for p in plans],
        }),
        poses=pd.concat([w.poses for w in walks], ignore_index=True),
        wifi=wifi,
        fixes=pd.concat([w.fixes for w in walks], ignore_index=True),
        truth_poses=pd.concat([w.truth for w in walks], ignore_index=True),
        truth_aps=radio.truth_table(),
        truth_devices=devices[["device_id", "k", "b"]].copy(),
        truth_users=pd.DataFrame({"user_id": [u.user_id for u in users], "alpha": [u.alpha for u in users],
                                  "beta": [u.beta for u in users]}),
        truth_walks=pd.DataFrame([w.start for w in walks], columns=["walk_id", "x0_m", "y0_m", "heading0_rad"]),
        truth_landmarks=pd.DataFrame({"label": venue.landmark_labels, "x_m": venue.landmark_xy[:, 0],
                                      "y_m": venue.landmark_xy[:, 1]}),
        venue=venue.to_dict(),
        radio=radio,
    )
    if cfg.ble.n_beacons:
        from rmbuild.synthetic.ble import beacon_readings, place_beacons

        # a stream of its own (outside the spawned ones), so that the other tables do not change with it
        rb = np.random.default_rng(np.random.SeedSequence(cfg.seed, spawn_key=(BLE_STREAM_KEY,)))
        data.truth_beacons = place_beacons(cfg.ble, venue, rb)
        data.ble = beacon_readings(cfg.ble, data.truth_beacons, data.truth_poses, rb)
    report("done", 1.0)
    return data


def _people(cfg: SimulateConfig, rp: np.random.Generator) -> tuple[list[User], pd.DataFrame]:
    """The walkers (step model) and the phones (device model k, b; magnetometer; scan period)."""
    wc = cfg.walkers
    users = []
    for i in range(wc.n_users):
        alpha = float(rp.uniform(*wc.step_alpha))
        s18 = float(rp.uniform(*wc.step_len_at_1p8hz_m))
        users.append(User(f"u{i:02d}", alpha, s18 - 1.8 * alpha, float(rp.uniform(*wc.step_freq_hz))))
    dc = cfg.devices
    dev_rows = []
    for i in range(dc.n_devices):
        dev_rows.append((f"d{i:02d}", 1.0 + float(rp.normal(0.0, dc.k_sd)), float(rp.normal(0.0, dc.b_sd_db)),
                         bool(rp.random() >= cfg.magnetometer.missing_fraction),
                         float(rp.uniform(*cfg.radio.scan_period_s))))
    if dc.test_device is not None:
        dev_rows.append(("dtest", float(dc.test_device[0]), float(dc.test_device[1]),
                         bool(rp.random() >= cfg.magnetometer.missing_fraction),
                         float(rp.uniform(*cfg.radio.scan_period_s))))
    devices = pd.DataFrame(dev_rows, columns=["device_id", "k", "b", "has_magnetometer", "scan_period_s"])
    return users, devices


def _walk_plans(cfg: SimulateConfig, rp: np.random.Generator) -> list[_WalkPlan]:
    """Every walk's kind, role, user, device and step count (the last n_test_walks are test walks, on the
    test device when there is one)."""
    wc, dc = cfg.walkers, cfg.devices
    kinds = _walk_kinds(cfg, rp)
    n_walks = len(kinds)
    plans = []
    for i, kind in enumerate(kinds):
        role = "test" if i >= n_walks - wc.n_test_walks else "map"
        user = int(rp.integers(wc.n_users))
        on_test_device = role == "test" and dc.test_device is not None
        dev = dc.n_devices if on_test_device else int(rp.integers(dc.n_devices))
        lo, hi = wc.long_walk_steps if kind == "long" else wc.short_walk_steps
        n_steps = int(rp.integers(int(lo), int(hi) + 1))
        plans.append(_WalkPlan(f"w{i:03d}", kind, role, user, dev, n_steps))
    return plans


def _simulate_walk(cfg: SimulateConfig, plan: _WalkPlan, user: User, dev: pd.Series, venue: Venue, router: Router,
                   magnetic: MagneticField, rw: np.random.Generator, rs: np.random.Generator) -> _WalkTables:
    """One walk: its route and true poses, the dead-reckoned poses and compass of its phone, the landmark
    fixes (``rw``), and the times and places of its scans (``rs``)."""
    wid = plan.walk_id
    max_len = plan.n_steps * (user.alpha * 3.0 + user.beta) + 20.0
    route, pauses = plan_route(venue, router, cfg.walkers, plan.kind, max_len, rw)
    t, xy, heading, freq, knot_t, knot_xy = walk_route(route, pauses, plan.n_steps, user, cfg.walkers, rw)
    own_xy, own_heading = dead_reckon(t, xy, heading, cfg.imu, rw)
    if bool(dev["has_magnetometer"]):
        yaw = magnetic.observe(xy, heading, rw)
        yaw_sigma = np.full(len(t), cfg.magnetometer.reported_sigma_rad)
    else:
        yaw = np.full(len(t), np.nan)
        yaw_sigma = np.full(len(t), np.nan)
    t_s = np.round(t, 3)
    poses = pd.DataFrame({
        "walk_id": wid, "t_s": t_s, "x_m": own_xy[:, 0], "y_m": own_xy[:, 1], "heading_rad": own_heading,
        "yaw_abs_rad": yaw, "yaw_abs_sigma_rad": yaw_sigma, "step_freq_hz": np.round(freq, 4),
    })
    truth = pd.DataFrame({"walk_id": wid, "t_s": t_s, "x_m": xy[:, 0], "y_m": xy[:, 1], "heading_rad": heading})
    start = (wid, float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))
    fixes = _landmark_fixes(wid, t_s, xy, venue, cfg, rw)
    # scan times and where the walker was then
    period = float(dev["scan_period_s"])
    n_max = int(t[-1] / period) + 3
    gaps = period + rs.normal(0.0, cfg.radio.scan_jitter_s, n_max)
    ts = rs.uniform(0.0, period) + np.cumsum(np.r_[0.0, gaps])
    ts = np.round(ts[ts <= t[-1]], 3)
    t0 = np.maximum(ts - cfg.radio.scan_duration_s, 0.0)
    xy0 = np.c_[np.interp(t0, knot_t, knot_xy[:, 0]), np.interp(t0, knot_t, knot_xy[:, 1])]
    xy1 = np.c_[np.interp(ts, knot_t, knot_xy[:, 0]), np.interp(ts, knot_t, knot_xy[:, 1])]
    near = np.clip(np.searchsorted(t, ts), 0, len(t) - 1)
    scans = _Scans(wid, ts, xy0, xy1, heading[near], float(dev["k"]), float(dev["b"]), rs)
    return _WalkTables(poses, truth, start, fixes, scans)


def _wifi_readings(cfg: SimulateConfig, radio: RadioModel, devices: pd.DataFrame, scans: list[_Scans],
                   report: Callable[[str, float], None]) -> pd.DataFrame:
    """The Wi-Fi readings of every scan: the mean field of all scans in one vectorised pass, then each
    walk's readings from its own random stream (so the result does not depend on the walk order)."""
    report("wifi", 0.0)
    all_xy = np.vstack([np.vstack([s.xy0, s.xy1]) for s in scans])
    cull = scan_cull_level(cfg.radio)
    cull = min(cull, (cull - float(devices["b"].max())) / float(devices["k"].min()))
    n_chunks = 10
    bounds = np.linspace(0, len(all_xy), n_chunks + 1).astype(int)
    chunks = []
    for c in range(n_chunks):  # in pieces, only to report progress
        chunks.append(radio.mean_rss_radios(all_xy[bounds[c]:bounds[c + 1]], cull_below_dbm=cull))
        report("radio field", (c + 1) / n_chunks)
    field = np.vstack(chunks)
    wifi_parts = []
    at = 0
    for j, s in enumerate(scans):
        n = len(s.t_s)
        f0, f1 = field[at:at + n], field[at + n:at + 2 * n]
        at += 2 * n
        si, bi, rssi = scan_readings(radio, cfg.radio, f0, f1, s.xy1, s.heading, s.k, s.b, s.rng)
        df = pd.DataFrame({
            "walk_id": s.walk_id, "t_s": s.t_s[si], "bssid": radio.bssid[bi].astype(str), "rssi_dbm": rssi,
            "freq_mhz": radio.radio_freq_mhz[radio.bssid_radio[bi]].astype(np.int64),
            "ssid": radio.bssid_ssid[bi].astype(str),
        })
        df = df.sort_values(["t_s", "rssi_dbm", "bssid"], ascending=[True, False, True], kind="stable")
        wifi_parts.append(df)
        report("wifi", (j + 1) / len(scans))
    return pd.concat(wifi_parts, ignore_index=True)


def _landmark_fixes(
    wid: str, t_s: np.ndarray, xy: np.ndarray, venue: Venue, cfg: SimulateConfig, rng: np.random.Generator
) -> pd.DataFrame:
    """One fix per pass of a landmark (closest step of a run of steps within the landmark radius)."""
    rows = []
    for label, (lx, ly) in zip(venue.landmark_labels, venue.landmark_xy):
        d = np.hypot(xy[:, 0] - lx, xy[:, 1] - ly)
        inside = np.flatnonzero(d <= cfg.venue.landmark_radius_m)
        if len(inside) == 0:
            continue
        runs = np.split(inside, np.flatnonzero(np.diff(inside) > 2) + 1)
        for run in runs:
            if rng.random() >= cfg.venue.landmark_press_prob:
                continue
            k = int(run[np.argmin(d[run])])
            rows.append((wid, float(t_s[k]), float(lx), float(ly), label))
    df = pd.DataFrame(rows, columns=["walk_id", "t_s", "x_m", "y_m", "label"])
    df = df.astype({"walk_id": str, "t_s": np.float64, "x_m": np.float64, "y_m": np.float64, "label": str})
    return df.sort_values(["t_s", "label"], kind="stable").reset_index(drop=True)
