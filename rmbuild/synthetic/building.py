"""A synthetic building: several floors stacked, each a venue of its own (same outline, its own layout, APs,
people and walks), with every floor's APs also heard on the others through the floors between.

A scan on floor f hears an AP of floor g at its same-floor mean RSSI less ``floor_attenuation_db`` per
floor between them, drawn like any reading (:func:`rmbuild.synthetic.radio.scan_readings`: body loss,
noise, device model, detection). The tables carry a ``floor`` column (walks, truth APs and landmarks), so
``rmbuild ingest`` makes a building workspace of them. Walks stay on one floor (no stairs or lifts yet).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from rmbuild.config.simulate import SimulateConfig
from rmbuild.synthetic.radio import scan_readings
from rmbuild.synthetic.simulate import SimulatedData, simulate


def floor_name(k: int) -> str:
    """Floor k (0 = ground) as the MS ILC data names them: F1, F2, ..."""
    return f"F{k + 1}"


def simulate_building(cfg: SimulateConfig) -> SimulatedData:
    """``cfg.building.floors`` floors, each :func:`simulate` of ``cfg`` with a seed of its own; ids of walks,
    users and devices get the floor's name as a prefix. The venue and radio model given are floor 0's."""
    n = cfg.building.floors
    seeds = np.random.SeedSequence(cfg.seed).spawn(n + 1)
    floors = [simulate(dataclasses.replace(cfg, seed=int(seeds[k].generate_state(1)[0]))) for k in range(n)]
    for k, d in enumerate(floors):
        _prefix(d, floor_name(k))
    rng = np.random.default_rng(seeds[n])
    wifi = [pd.concat([d.wifi] + [_heard_from(d, floors[g], abs(k - g) * cfg.building.floor_attenuation_db, cfg, rng)
                                  for g in range(n) if g != k], ignore_index=True)
            for k, d in enumerate(floors)]
    wifi = [w.sort_values(["walk_id", "t_s", "rssi_dbm", "bssid"], ascending=[True, True, False, True],
                          kind="stable") for w in wifi]

    def cat(attr: str, parts: list[pd.DataFrame] | None = None) -> pd.DataFrame:
        return pd.concat(parts if parts is not None else [getattr(d, attr) for d in floors], ignore_index=True)

    return SimulatedData(
        walks=cat("walks"), poses=cat("poses"), wifi=cat("wifi", wifi), fixes=cat("fixes"),
        truth_poses=cat("truth_poses"), truth_aps=cat("truth_aps"), truth_devices=cat("truth_devices"),
        truth_users=cat("truth_users"), truth_walks=cat("truth_walks"), truth_landmarks=cat("truth_landmarks"),
        venue=floors[0].venue, radio=floors[0].radio,
    )


def _prefix(d: SimulatedData, name: str) -> None:
    """Make one floor's ids unique in the building and give its tables their ``floor``."""
    for df in (d.walks, d.poses, d.wifi, d.fixes, d.truth_poses, d.truth_walks):
        df["walk_id"] = name + "-" + df["walk_id"].astype(str)
    for df, col in ((d.walks, "device_id"), (d.truth_devices, "device_id"), (d.walks, "user_id"),
                    (d.truth_users, "user_id")):
        df[col] = name + "-" + df[col].astype(str)
    for df in (d.walks, d.truth_aps, d.truth_landmarks):
        df["floor"] = name


def _heard_from(d: SimulatedData, other: SimulatedData, atten_db: float, cfg: SimulateConfig,
                rng: np.random.Generator) -> pd.DataFrame:
    """Readings of ``other``'s APs in ``d``'s scans, ``atten_db`` below their same-floor mean RSSI."""
    scans = d.wifi.drop_duplicates(["walk_id", "t_s"])[["walk_id", "t_s"]]
    dev = d.walks.set_index("walk_id")["device_id"].map(d.truth_devices.set_index("device_id")[["k", "b"]]
                                                        .apply(tuple, axis=1))
    model = other.radio
    parts = []
    for wid, g in scans.groupby("walk_id", sort=False):
        tp = d.truth_poses[d.truth_poses["walk_id"] == wid]
        t = g["t_s"].to_numpy(float)
        xy = np.column_stack([np.interp(t, tp["t_s"], tp["x_m"]), np.interp(t, tp["t_s"], tp["y_m"])])
        heading = tp["heading_rad"].to_numpy(float)[np.clip(np.searchsorted(tp["t_s"].to_numpy(float), t), 0,
                                                              len(tp) - 1)]
        mean = model.mean_rss_radios(xy) - atten_db
        k, b = dev[wid]
        si, bi, rssi = scan_readings(model, cfg.radio, mean, mean, xy, heading, float(k), float(b), rng)
        parts.append(pd.DataFrame({
            "walk_id": wid, "t_s": t[si], "bssid": model.bssid[bi].astype(str), "rssi_dbm": rssi,
            "freq_mhz": model.radio_freq_mhz[model.bssid_radio[bi]].astype(np.int64),
            "ssid": model.bssid_ssid[bi].astype(str)}))
    return pd.concat(parts, ignore_index=True) if parts else d.wifi.iloc[:0]
