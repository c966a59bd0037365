"""BLE beacons of a simulated floor: where they are and what the walkers' phones read of them.

Each beacon sits at a navigation node of the floor (corridors, rooms, hall) and follows a log-distance
model without walls, sharper than the Wi-Fi one: RSS = P1 − 10 n log10(max(d, 1 m)) + noise
(``[simulate.ble]``). A phone reports each beacon once per ``period_s`` at a phase drawn per walk and beacon,
at the walker's true position then, when the reading reaches ``detect_floor_dbm``. Pure: no I/O.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.config.simulate import BleConfig
from rmbuild.synthetic.venue import Venue


def place_beacons(cfg: BleConfig, venue: Venue, rng: np.random.Generator) -> pd.DataFrame:
    """The true beacons: bssid (a locally administered MAC), x_m, y_m (building frame)."""
    n = min(cfg.n_beacons, len(venue.nav_xy))
    at = venue.nav_xy[np.sort(rng.choice(len(venue.nav_xy), n, replace=False))]
    return pd.DataFrame({"bssid": [f"be:ac:00:00:{k // 256:02x}:{k % 256:02x}" for k in range(n)],
                         "x_m": at[:, 0], "y_m": at[:, 1]})


def beacon_readings(cfg: BleConfig, beacons: pd.DataFrame, truth_poses: pd.DataFrame, rng: np.random.Generator,
                    ) -> pd.DataFrame:
    """The BLE readings of every walk (``truth_poses``: walk_id, t_s, x_m, y_m): walk_id, t_s, bssid, rssi_dbm,
    sorted by walk then time."""
    bxy = beacons[["x_m", "y_m"]].to_numpy(float)
    parts = []
    for wid, g in truth_poses.groupby("walk_id", sort=False):
        t = g["t_s"].to_numpy(float)
        for j in range(len(bxy)):
            tr = np.arange(t[0] + rng.uniform(0.0, cfg.period_s), t[-1], cfg.period_s)
            x, y = np.interp(tr, t, g["x_m"].to_numpy(float)), np.interp(tr, t, g["y_m"].to_numpy(float))
            d = np.maximum(np.hypot(x - bxy[j, 0], y - bxy[j, 1]), 1.0)
            rss = cfg.rssi_at_1m_dbm - 10.0 * cfg.path_loss_exp * np.log10(d) + rng.normal(0.0, cfg.noise_sigma_db,
                                                                                            len(d))
            ok = rss >= cfg.detect_floor_dbm
            parts.append(pd.DataFrame({"walk_id": str(wid), "t_s": np.round(tr[ok], 3),
                                       "bssid": beacons["bssid"].iat[j], "rssi_dbm": np.round(rss[ok])}))
    cols = ["walk_id", "t_s", "bssid", "rssi_dbm"]
    if not parts:
        return pd.DataFrame({c: [] for c in cols})
    out = pd.concat(parts, ignore_index=True)[cols]
    order = pd.Index(truth_poses["walk_id"].unique()).get_indexer(out["walk_id"])
    out = out.iloc[np.lexsort((out["bssid"].to_numpy(str), out["t_s"].to_numpy(), order))]
    out = out.drop_duplicates(["walk_id", "t_s", "bssid"])   # two reports rounded onto one millisecond
    return out.reset_index(drop=True)
