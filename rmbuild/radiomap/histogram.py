"""RSS histograms per cell, AP and walking direction: the subway-station paper's fingerprint layer.

That paper (Wi-Fi + PDR positioning in subway stations, §III-A) keeps, per reference point and AP, the
normalised histogram of the readings (bins of ~2 dB) instead of a mean and a standard deviation — walked
surveys mix body shadowing and crowd effects into distributions that fit no standard model — and keeps
the readings taken walking in different directions apart, because the walker's body shadows the phone
from the APs behind them (the PDR says which way they walked). Here:

* a reading's **bin** is ``floor(rssi / bin_db)``: bin b covers ``[b·bin_db, (b+1)·bin_db)`` dBm;
* a node's **walking direction** is the direction of its walk's motion in the map frame (central
  difference of the neighbouring nodes' positions; unknown when they are less than
  :data:`MIN_MOVE_M` apart, e.g. standing);
* its **sector** is the one of ``n_directions`` equal sectors, centred on 0, 360/n, ... degrees from the
  map's +x axis, that holds the direction (−1 = unknown);
* the layer stores the non-zero counts per (cell, sector, AP, bin), so its size is bounded by the number
  of readings. The direction-free histogram of a cell is the sum over its sectors (and the unknown one).

Only visited cells have histograms (filled cells have none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

#: m; a node whose neighbours (previous and next node of its walk) are closer together than this has no
#: walking direction (standing, or a step too short to give one).
MIN_MOVE_M = 0.3
#: Columns of :meth:`HistogramLayer.long_table` (the exported Parquet table).
HISTOGRAM_COLUMNS = ("cell", "x_m", "y_m", "sector", "direction_deg", "bssid", "rssi_lo_dbm", "rssi_hi_dbm",
                     "count")


@dataclass
class HistogramLayer:
    """Non-zero RSS-histogram counts. All arrays (n_entries,): ``cell`` int64 (row of the map's cells),
    ``sector`` int8 (0..n_directions−1, −1 = direction unknown), ``ap`` int32 (column of the map's
    bssids), ``bin`` int32 (bin index: [bin·bin_db, (bin+1)·bin_db) dBm), ``count`` int32 (> 0)."""

    bin_db: float
    n_directions: int
    cell: np.ndarray
    sector: np.ndarray
    ap: np.ndarray
    bin: np.ndarray
    count: np.ndarray

    def __len__(self) -> int:
        return len(self.count)

    def sector_centre_deg(self, sector: np.ndarray) -> np.ndarray:
        """Centre direction (deg from the map's +x axis, counter-clockwise) of sectors; NaN for −1."""
        s = np.asarray(sector, dtype=float)
        return np.where(s >= 0, s * 360.0 / max(self.n_directions, 1), np.nan)

    def long_table(self, bssids: np.ndarray, cells: pd.DataFrame) -> pd.DataFrame:
        """One row per non-zero (cell, sector, AP, bin), columns :data:`HISTOGRAM_COLUMNS`."""
        xy = cells[["x_m", "y_m"]].to_numpy(dtype=float)
        return pd.DataFrame({
            "cell": self.cell, "x_m": xy[self.cell, 0], "y_m": xy[self.cell, 1],
            "sector": self.sector.astype(np.int64), "direction_deg": self.sector_centre_deg(self.sector),
            "bssid": np.asarray(bssids, dtype=object)[self.ap].astype(str),
            "rssi_lo_dbm": self.bin * self.bin_db, "rssi_hi_dbm": (self.bin + 1) * self.bin_db,
            "count": self.count,
        })

    def sidecar(self) -> dict:
        """What the layer is, for the map's JSON sidecar."""
        return {"bin_db": self.bin_db, "n_directions": self.n_directions, "n_entries": len(self),
                "sectors": "sector s is centred on s * 360 / n_directions deg from the map's +x axis "
                           "(counter-clockwise); -1 = walking direction unknown",
                "bins": "bin b covers [b * bin_db, (b + 1) * bin_db) dBm"}


def motion_directions(node_xy: np.ndarray, node_walk: np.ndarray) -> np.ndarray:
    """(n_nodes,) walking direction (rad, map frame) of each node: its walk's motion between the previous
    and the next node (node ids increase in time within a walk); NaN when unknown."""
    xy = np.asarray(node_xy, dtype=float)
    walk = np.asarray(node_walk).astype(str)
    n = len(xy)
    same_prev = np.r_[False, walk[1:] == walk[:-1]]
    same_next = np.r_[walk[:-1] == walk[1:], False]
    prev = np.where(same_prev, np.arange(n) - 1, np.arange(n))
    nxt = np.where(same_next, np.arange(n) + 1, np.arange(n))
    d = xy[nxt] - xy[prev]
    with np.errstate(invalid="ignore"):
        ok = np.hypot(d[:, 0], d[:, 1]) >= MIN_MOVE_M
    return np.where(ok, np.arctan2(d[:, 1], d[:, 0]), np.nan)


def direction_sector(heading_rad: np.ndarray, n_directions: int) -> np.ndarray:
    """int8 sector (0..n−1, −1 for NaN) of headings; sectors are centred on multiples of 2π/n."""
    h = np.asarray(heading_rad, dtype=float)
    if n_directions <= 1:
        return np.where(np.isfinite(h), 0, -1).astype(np.int8)
    w = 2.0 * np.pi / n_directions
    s = np.floor(np.mod(np.nan_to_num(h) + w / 2.0, 2.0 * np.pi) / w).astype(np.int64) % n_directions
    return np.where(np.isfinite(h), s, -1).astype(np.int8)


def build_histograms(
    cell_of_reading: np.ndarray,
    ap_of_reading: np.ndarray,
    rssi_dbm: np.ndarray,
    heading_rad: np.ndarray,
    bin_db: float,
    n_directions: int,
) -> HistogramLayer:
    """Count readings per (cell, sector, AP, bin). Readings with ``cell_of_reading < 0`` are left out.

    All inputs (n_readings,): cell row, AP column, RSSI dBm, the reading's node's walking direction (rad,
    NaN = unknown). ``n_directions = 0`` keeps no direction (every sector −1).
    """
    keep = np.asarray(cell_of_reading) >= 0
    cell = np.asarray(cell_of_reading, dtype=np.int64)[keep]
    ap = np.asarray(ap_of_reading, dtype=np.int64)[keep]
    b = np.floor(np.asarray(rssi_dbm, dtype=float)[keep] / bin_db).astype(np.int64)
    if n_directions > 0:
        sec = direction_sector(np.asarray(heading_rad, dtype=float)[keep], n_directions).astype(np.int64)
    else:
        sec = np.full(len(cell), -1, dtype=np.int64)
    key = pd.DataFrame({"cell": cell, "sector": sec, "ap": ap, "bin": b})
    g = key.groupby(["cell", "sector", "ap", "bin"], sort=True).size()
    idx = g.index
    return HistogramLayer(
        bin_db=float(bin_db), n_directions=int(n_directions),
        cell=idx.get_level_values("cell").to_numpy(dtype=np.int64),
        sector=idx.get_level_values("sector").to_numpy().astype(np.int8),
        ap=idx.get_level_values("ap").to_numpy(dtype=np.int32),
        bin=idx.get_level_values("bin").to_numpy(dtype=np.int32),
        count=g.to_numpy(dtype=np.int32),
    )
