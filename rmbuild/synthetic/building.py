"""A synthetic building: several floors stacked, each a venue of its own (same outline, its own layout, APs,
people and walks), with every floor's APs also heard on the others through the floors between.

A scan on floor f hears an AP of floor g at its same-floor mean RSSI less ``floor_attenuation_db`` per
floor between them, drawn like any reading (:func:`rmbuild.synthetic.radio.scan_readings`: body loss,
noise, device model, detection). The tables carry a ``floor`` column (walks, truth APs and landmarks), so
``rmbuild ingest`` makes a building workspace of them. Some map walks change floor by the stairs or the
lift (:mod:`rmbuild.synthetic.floor_change`): their poses carry the floor of each step, and every walk's
poses the barometer's ``pressure_hpa``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from rmbuild.config.simulate import BuildingConfig, SimulateConfig
from rmbuild.synthetic import floor_change as fc
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
    for k, d in enumerate(floors):
        d.truth_poses["k"] = k
        d.truth_poses["h_m"] = k * cfg.building.storey_m
    glued, changes = _floor_changes(floors, cfg, rng)
    wifi = [pd.concat([d.wifi[~d.wifi["walk_id"].isin(glued)]]
                      + [_heard_from(d, floors[g], abs(k - g) * cfg.building.floor_attenuation_db, cfg, rng,
                                     skip=set(glued)) for g in range(n) if g != k], ignore_index=True)
            for k, d in enumerate(floors)]
    wifi += [_glued_readings(w, t, floors, cfg, rng) for w, t in glued.items()]
    wifi = [w.sort_values(["walk_id", "t_s", "rssi_dbm", "bssid"], ascending=[True, True, False, True],
                          kind="stable") for w in wifi]

    def cat(attr: str, parts: list[pd.DataFrame] | None = None) -> pd.DataFrame:
        return pd.concat(parts if parts is not None else [getattr(d, attr) for d in floors], ignore_index=True)

    truth = cat("truth_poses")
    poses = cat("poses").assign(floor=truth["k"].map(floor_name).to_numpy(),
                                pressure_hpa=_barometers(truth, cfg.building, rng))
    return SimulatedData(
        walks=cat("walks"), poses=poses, wifi=cat("wifi", wifi), fixes=cat("fixes"),
        truth_poses=truth.drop(columns=["k", "h_m"]), truth_aps=cat("truth_aps"),
        truth_devices=cat("truth_devices"), truth_users=cat("truth_users"), truth_walks=cat("truth_walks"),
        truth_landmarks=cat("truth_landmarks"), venue=floors[0].venue, radio=floors[0].radio,
        truth_floor_changes=changes,
    )


def _floor_changes(floors: list[SimulatedData], cfg: SimulateConfig,
                   rng: np.random.Generator) -> tuple[dict[str, np.ndarray], pd.DataFrame]:
    """Swap the parts of map walks passing the stairs or the lift (in the floors' tables, in place): the
    glued walks' scan times by walk id (their Wi-Fi is drawn anew), and the floor changes' truth."""
    cols = ["walk_id", "kind", "from_floor", "to_floor", "step", "t_s"]
    if len(floors) < 2 or cfg.building.floor_change_walks < 2:
        return {}, pd.DataFrame(columns=cols)
    truth = [d.truth_poses for d in floors]
    maps = [set(d.walks.loc[d.walks["role"] == "map", "walk_id"].astype(str)) for d in floors]
    points = fc.transition_points(truth, maps)
    glued: dict[str, np.ndarray] = {}
    rows = []
    for sw in fc.choose_swaps(truth, maps, points, cfg.building.floor_change_walks, rng):
        a, b = _walk_tables(floors[sw.k], sw.a), _walk_tables(floors[sw.k + 1], sw.b)
        new_a, ch_a = fc.glue(a, sw.i, b, sw.j, sw, True, cfg.building.storey_m, rng)
        new_b, ch_b = fc.glue(b, sw.j, a, sw.i, sw, False, cfg.building.storey_m, rng)
        _replace(floors[sw.k], sw.a, new_a)
        _replace(floors[sw.k + 1], sw.b, new_b)
        glued[sw.a], glued[sw.b] = new_a["scans"], new_b["scans"]
        rows += [ch_a, ch_b]
    changes = pd.DataFrame(rows).rename(columns={"from": "from_floor", "to": "to_floor"}) if rows else \
        pd.DataFrame(columns=cols)
    for c in ("from_floor", "to_floor"):
        changes[c] = changes[c].map(floor_name)
    return glued, changes[cols]


def _walk_tables(d: SimulatedData, wid: str) -> dict:
    scans = d.wifi.loc[d.wifi["walk_id"] == wid, "t_s"].drop_duplicates().to_numpy(float)
    return {"poses": d.poses[d.poses["walk_id"] == wid].reset_index(drop=True),
            "truth": d.truth_poses[d.truth_poses["walk_id"] == wid].reset_index(drop=True),
            "fixes": d.fixes[d.fixes["walk_id"] == wid], "scans": scans}


def _replace(d: SimulatedData, wid: str, new: dict) -> None:
    for attr, key in (("poses", "poses"), ("truth_poses", "truth"), ("fixes", "fixes")):
        df = getattr(d, attr)
        setattr(d, attr, pd.concat([df[df["walk_id"] != wid], new[key]], ignore_index=True))


def _barometers(truth: pd.DataFrame, cfg: BuildingConfig, rng: np.random.Generator) -> np.ndarray:
    """Every step's barometer reading (hPa), walk by walk in the table's order."""
    out = np.zeros(len(truth))
    for _, rows in truth.groupby("walk_id", sort=False).indices.items():
        out[rows] = fc.pressure(truth["t_s"].to_numpy(float)[rows], truth["h_m"].to_numpy(float)[rows], cfg, rng)
    return np.round(out, 4)


def _glued_readings(wid: str, t: np.ndarray, floors: list[SimulatedData], cfg: SimulateConfig,
                    rng: np.random.Generator) -> pd.DataFrame:
    """A glued walk's readings of every floor's APs, each scan on its true floor."""
    home = next(d for d in floors if (d.walks["walk_id"] == wid).any())
    tp = next(d.truth_poses for d in floors if (d.truth_poses["walk_id"] == wid).any())
    tp = tp[tp["walk_id"] == wid]
    k_scan = tp["k"].to_numpy()[np.clip(np.searchsorted(tp["t_s"].to_numpy(float), t), 0, len(tp) - 1)]
    scans = pd.DataFrame({"walk_id": wid, "t_s": t})
    parts = []
    for g, other in enumerate(floors):
        for k in np.unique(k_scan):
            sub = _heard_from(home, other, abs(int(k) - g) * cfg.building.floor_attenuation_db, cfg, rng,
                              scans=scans[k_scan == k], truth=tp)
            parts.append(sub)
    return pd.concat(parts, ignore_index=True)


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
                rng: np.random.Generator, skip: set[str] | None = None, scans: pd.DataFrame | None = None,
                truth: pd.DataFrame | None = None) -> pd.DataFrame:
    """Readings of ``other``'s APs in ``d``'s scans (or ``scans``: walk_id, t_s; their walk's ``truth``
    poses), ``atten_db`` below their same-floor mean RSSI; walks in ``skip`` left out."""
    if scans is None:
        scans = d.wifi.drop_duplicates(["walk_id", "t_s"])[["walk_id", "t_s"]]
        scans = scans[~scans["walk_id"].isin(skip or set())]
    dev = d.walks.set_index("walk_id")["device_id"].map(d.truth_devices.set_index("device_id")[["k", "b"]]
                                                        .apply(tuple, axis=1))
    model = other.radio
    parts = []
    for wid, g in scans.groupby("walk_id", sort=False):
        tp = truth if truth is not None else d.truth_poses[d.truth_poses["walk_id"] == wid]
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
