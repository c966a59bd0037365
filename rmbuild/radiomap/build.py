"""Rasterise node positions and their Wi-Fi readings onto a grid (docs/method.md; He et al. 2015 eq. 1-3).

Per cell c and AP j, over the T readings ψ_1..ψ_T of AP j attached to nodes inside c:

* ``count`` T;  ``rssi_mean_dbm`` ψ̄ = (1/T) Σ ψ_t;
* ``rssi_std_db`` σ = sqrt(Σ (ψ_t − ψ̄)² / (T − 1)) — unbiased; NaN when T = 1 (undefined);
* ``detect_ratio`` = (scans in c that saw j) / (scans in c); a scan is the set of readings sharing
  (node, t_s) (or a node, when the readings carry no time), so the ratio is in [0, 1];
* ``n_walks`` = distinct walks whose readings of j fell in c.

The grid is axis-aligned in the map frame: cell (ix, iy) covers [ox + ix·s, ox + (ix+1)·s) × [oy + iy·s,
...), s = cell size, origin (ox, oy) given or the minimum node position snapped down to a multiple of s.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rmbuild.config.base import to_toml
from rmbuild.config.radiomap import MapConfig
from rmbuild.errors import InputError
from rmbuild.limits import MAX_MAP_CELLS, MAX_MAP_RASTER_CELLS
from rmbuild.radiomap.histogram import HistogramLayer, build_histograms, motion_directions
from rmbuild.radiomap.reference import ReferenceSet
from rmbuild.types import Fingerprints

#: Columns of :meth:`RadioMap.cell_table`.
CELL_COLUMNS = ("cell", "ix", "iy", "x_m", "y_m", "n_scans", "n_nodes", "n_walks", "interpolated")
#: Columns of :meth:`RadioMap.long_table` (one row per cell and detected AP).
LONG_COLUMNS = (
    "cell", "ix", "iy", "x_m", "y_m", "bssid", "count", "rssi_mean_dbm", "rssi_std_db", "detect_ratio",
    "n_walks", "interpolated",
)
#: UJIIndoorLoc's value for "AP not detected" in its wide layout.
UJI_NOT_DETECTED = 100
#: UJIIndoorLoc's columns after the WAPnnn block (LONGITUDE/LATITUDE hold Web Mercator metres there).
UJI_TAIL = ("LONGITUDE", "LATITUDE", "FLOOR", "BUILDINGID", "SPACEID", "RELATIVEPOSITION", "USERID",
            "PHONEID", "TIMESTAMP")


@dataclass
class RadioMap:
    """A gridded radio map plus the per-node fingerprint database of the nodes it was built from.

    Cell arrays have one row per reference cell (visited cells passing ``min_scans``, then filled cells):
    ``count`` int32 (n_cells, n_ap); ``mean_dbm`` float32 (NaN = not detected); ``std_db`` float32 (NaN when
    T < 2 or not detected; for filled cells the fill's own uncertainty); ``detect_ratio`` float32 (0 = not
    detected); ``n_walks`` int32. ``cells``: DataFrame with :data:`CELL_COLUMNS`.
    ``nodes``: the map nodes' :class:`Fingerprints`; ``node_xy`` float64 (len(nodes), 2) their positions;
    ``node_walk`` their walk labels. ``histograms``: per (cell, walking direction, AP) RSS histograms of the
    visited cells (:mod:`rmbuild.radiomap.histogram`). ``device_offsets_db``: device -> the offset (dB)
    taken off its readings before rasterising (:mod:`rmbuild.radiomap.devices`); queries of those devices
    are corrected alike; empty: readings as heard.
    """

    origin_xy: np.ndarray
    cell_size_m: float
    frame: str
    bssids: np.ndarray
    cells: pd.DataFrame
    count: np.ndarray
    mean_dbm: np.ndarray
    std_db: np.ndarray
    detect_ratio: np.ndarray
    n_walks: np.ndarray
    nodes: Fingerprints
    node_xy: np.ndarray
    node_walk: np.ndarray
    config: MapConfig
    histograms: HistogramLayer | None = None
    device_offsets_db: dict[str, float] = field(default_factory=dict)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @property
    def cell_xy(self) -> np.ndarray:
        """float64 (n_cells, 2) cell centres, metres."""
        return self.cells[["x_m", "y_m"]].to_numpy(dtype=np.float64)

    # -------------------------------------------------------------- views
    def reference_set(self, kind: str = "cells") -> ReferenceSet:
        """The RPs a localizer matches against: the grid cells or the raw map nodes."""
        if kind == "cells":
            return ReferenceSet(
                self.cell_xy, self.mean_dbm, self.bssids, self.std_db, self.count,
                self.cells["interpolated"].to_numpy(dtype=bool), "cells",
            )
        if kind == "nodes":
            return ReferenceSet(
                self.node_xy, self.nodes.rss_dbm, self.bssids, None, self.nodes.count,
                np.zeros(len(self.node_xy), dtype=bool), "nodes",
            )
        raise ValueError(f"unknown reference kind {kind!r}")

    def long_table(self) -> pd.DataFrame:
        """One row per (cell, detected AP) with :data:`LONG_COLUMNS` (the Parquet table)."""
        r, c = np.nonzero(~np.isnan(self.mean_dbm))
        cl = self.cells
        return pd.DataFrame({
            "cell": cl["cell"].to_numpy()[r],
            "ix": cl["ix"].to_numpy()[r],
            "iy": cl["iy"].to_numpy()[r],
            "x_m": cl["x_m"].to_numpy()[r],
            "y_m": cl["y_m"].to_numpy()[r],
            "bssid": self.bssids[c].astype(str),
            "count": self.count[r, c],
            "rssi_mean_dbm": self.mean_dbm[r, c],
            "rssi_std_db": self.std_db[r, c],
            "detect_ratio": self.detect_ratio[r, c],
            "n_walks": self.n_walks[r, c],
            "interpolated": cl["interpolated"].to_numpy()[r],
        })

    def wap_names(self) -> list[str]:
        """UJIIndoorLoc's column names for the map's APs, in ``bssids`` order: WAP001 .. WAP999 with three digits
        as in UJIIndoorLoc (its 520 APs are WAP001 .. WAP520), then WAP1000, WAP1001, ... for a map of more."""
        return [f"WAP{i + 1:03d}" for i in range(len(self.bssids))]

    def wide_table(self, layout: str = "uji", floor: int = 0, uji_xy: np.ndarray | None = None) -> pd.DataFrame:
        """One row per cell, one column per AP, +100 = not detected (UJIIndoorLoc's convention).

        ``layout="uji"``: exactly UJIIndoorLoc's columns — ``WAP001..WAPnnn`` (the sidecar's ``ap_columns``
        maps them to BSSIDs; RSSI rounded to integer dBm like the original), then LONGITUDE, LATITUDE =
        ``uji_xy`` (n_cells, 2) when given (UJIIndoorLoc's are Web Mercator metres), else the cell centre's
        x, y (metres in the map frame), FLOOR = ``floor``,
        BUILDINGID = 0, SPACEID = cell id, RELATIVEPOSITION = 0, USERID = 0, PHONEID = 0, TIMESTAMP = 0.
        ``layout="xy"``: BSSIDs as column names, RSSI unrounded (0.01 dB), then ``x_m``, ``y_m``.
        """
        det = ~np.isnan(self.mean_dbm)
        if layout == "uji":
            vals = np.where(det, np.rint(np.nan_to_num(self.mean_dbm)), UJI_NOT_DETECTED).astype(np.int64)
            df = pd.DataFrame(vals, columns=self.wap_names())
            n = len(df)
            where = self.cells[["x_m", "y_m"]].to_numpy(float) if uji_xy is None else np.asarray(uji_xy, float)
            tail = {
                "LONGITUDE": where[:, 0], "LATITUDE": where[:, 1],
                "FLOOR": np.full(n, floor, np.int64), "BUILDINGID": np.zeros(n, np.int64),
                "SPACEID": self.cells["cell"].to_numpy(), "RELATIVEPOSITION": np.zeros(n, np.int64),
                "USERID": np.zeros(n, np.int64), "PHONEID": np.zeros(n, np.int64),
                "TIMESTAMP": np.zeros(n, np.int64),
            }
            return pd.concat([df, pd.DataFrame(tail)], axis=1)
        if layout == "xy":
            vals = np.where(det, np.round(np.nan_to_num(self.mean_dbm).astype(np.float64), 2), UJI_NOT_DETECTED)
            df = pd.DataFrame(vals, columns=[str(b) for b in self.bssids])
            df["x_m"] = self.cells["x_m"].to_numpy()
            df["y_m"] = self.cells["y_m"].to_numpy()
            return df
        raise ValueError(f"unknown wide layout {layout!r}")

    def sidecar(self) -> dict:
        """JSON-able description: grid, frame, AP list (with the wide CSV's column names), build config."""
        cl = self.cells
        interp = cl["interpolated"].to_numpy(dtype=bool)
        return {
            "grid": {
                "origin_xy_m": [float(self.origin_xy[0]), float(self.origin_xy[1])],
                "cell_size_m": float(self.cell_size_m),
                "ix_range": [int(cl["ix"].min()), int(cl["ix"].max())] if len(cl) else None,
                "iy_range": [int(cl["iy"].min()), int(cl["iy"].max())] if len(cl) else None,
                "cell_centre": "origin + (i + 0.5) * cell_size",
            },
            "frame": self.frame,
            "n_cells": int(len(cl)),
            "n_cells_visited": int((~interp).sum()),
            "n_cells_interpolated": int(interp.sum()),
            "n_nodes": int(len(self.nodes)),
            "n_aps": int(len(self.bssids)),
            "aps": [str(b) for b in self.bssids],
            "ap_columns": dict(zip(self.wap_names(), (str(b) for b in self.bssids), strict=True)),
            "not_detected_value": UJI_NOT_DETECTED,
            "std": "unbiased (T-1 denominator); NaN/null when T = 1",
            "histograms": None if self.histograms is None else self.histograms.sidecar(),
            "device_offsets_db": dict(self.device_offsets_db),
            "config": dataclasses.asdict(self.config),
            "config_toml": to_toml(self.config, "map"),
        }

    def strongest_aps(self, top_n: int) -> list[int]:
        """Column indices of the ``top_n`` APs with the highest peak cell mean (ties: AP order)."""
        peak = np.where(np.isnan(self.mean_dbm), -np.inf, self.mean_dbm).max(axis=0, initial=-np.inf)
        order = np.lexsort((np.arange(len(peak)), -peak))
        return [int(j) for j in order[:top_n] if np.isfinite(peak[j])]


def check_raster(xy: np.ndarray, origin: np.ndarray, cell_size_m: float) -> None:
    """InputError unless the grid's bounding box over the positions ``xy`` (n, 2) has at most
    :data:`MAX_MAP_RASTER_CELLS` cells (the map's pictures and viewer images are rasters of it)."""
    lo = np.floor((xy.min(axis=0) - origin) / cell_size_m)
    hi = np.floor((xy.max(axis=0) - origin) / cell_size_m)
    nx, ny = (hi - lo + 1).tolist()
    if nx * ny > MAX_MAP_RASTER_CELLS:
        w, h = (xy.max(axis=0) - xy.min(axis=0)).tolist()
        raise InputError(f"the map's nodes span {w:,.0f} x {h:,.0f} m: at cell_size_m = {cell_size_m:g} m a raster of "
                         f"{nx * ny:,.0f} cells, at most {MAX_MAP_RASTER_CELLS:,} (the map's pictures are rasters of "
                         "it); give a larger cell size")


def check_table(n_cells: int, n_aps: int) -> None:
    """InputError unless a map of ``n_cells`` cells and ``n_aps`` APs (its tables dense: cells × APs) has at
    most :data:`MAX_MAP_CELLS` entries."""
    if n_cells * n_aps > MAX_MAP_CELLS:
        raise InputError(f"a map of {n_cells:,} cells x {n_aps:,} APs: {n_cells * n_aps:,} entries, at most "
                         f"{MAX_MAP_CELLS:,} (its tables are dense); give a larger cell size")


def grid_origin(xy: np.ndarray, cell_size_m: float) -> np.ndarray:
    """Minimum of the finite positions snapped down to a multiple of the cell size (so grids line up)."""
    xy = np.asarray(xy, dtype=float)
    ok = np.isfinite(xy).all(axis=1)
    if not ok.any():
        raise InputError("no node has a finite position")
    return np.floor(xy[ok].min(axis=0) / cell_size_m) * cell_size_m


def _unique_count(*keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique rows of the stacked integer keys and the inverse index."""
    k = np.stack(keys, axis=1)
    u, inv = np.unique(k, axis=0, return_inverse=True)
    return u, inv.reshape(-1)


def _usable_readings(wifi: pd.DataFrame, node_xy: np.ndarray, node_walk: np.ndarray, bssids: np.ndarray | None):
    """The readings attached to a node with a known position, of a known AP: (readings, node row, AP
    column, bssids). Raises InputError when there are none or the input is malformed."""
    if node_xy.ndim != 2 or node_xy.shape[1] != 2 or len(node_walk) != len(node_xy):
        raise InputError("node_xy must be (n_nodes, 2) and node_walk (n_nodes,)")
    if wifi is None or len(wifi) == 0:
        raise InputError("no Wi-Fi readings to build a radio map from")
    for col in ("node", "bssid", "rssi_dbm"):
        if col not in wifi:
            raise InputError(f"Wi-Fi readings lack column {col!r}")
    node = pd.to_numeric(wifi["node"], errors="coerce").to_numpy(dtype=np.float64)
    ok = np.isfinite(node) & (node >= 0) & (node < len(node_xy))
    node_i = np.where(ok, node, 0).astype(np.int64)
    ok &= np.isfinite(node_xy[node_i]).all(axis=1)
    ok &= np.isfinite(wifi["rssi_dbm"].to_numpy(dtype=np.float64))
    w = wifi.loc[ok]
    node_i = node_i[ok]
    if len(w) == 0:
        raise InputError("no Wi-Fi reading is attached to a node with a known position")
    if bssids is None:
        bssids = np.array(sorted(w["bssid"].astype(str).unique()), dtype=object)
    bssids = np.asarray(bssids, dtype=object)
    col_i = pd.Index(bssids).get_indexer(w["bssid"].astype(str))
    keep = col_i >= 0
    if not keep.any():
        raise InputError("no Wi-Fi reading of a known AP")
    return w.loc[keep], node_i[keep], col_i[keep], bssids


def build_radio_map(
    wifi: pd.DataFrame,
    node_xy: np.ndarray,
    node_walk: np.ndarray,
    cfg: MapConfig | None = None,
    origin_xy: np.ndarray | None = None,
    *,
    bssids: np.ndarray | None = None,
    frame: str | None = None,
) -> RadioMap:
    """Rasterise readings at their nodes' positions into a :class:`RadioMap`.

    ``wifi``: readings with columns node (int, row of ``node_xy``), bssid, rssi_dbm (dBm) and optionally
    t_s (scan time, s) — readings of one node at one time form one scan. ``node_xy``: float (n_nodes, 2)
    metres in the map frame; rows with NaN (position unknown) and their readings are left out.
    ``node_walk``: (n_nodes,) walk label of each node. ``origin_xy``: grid origin (default
    :func:`grid_origin` of the used nodes). ``bssids``: the AP column order (default: sorted APs of the
    readings; readings of other APs are ignored). ``frame``: overrides ``cfg.frame`` in the sidecar.
    """
    cfg = cfg or MapConfig()
    try:
        cfg.validate()
    except ValueError as e:
        raise InputError(f"map config: {e}") from None
    node_xy = np.asarray(node_xy, dtype=np.float64)
    node_walk = np.asarray(node_walk)
    w, node_i, col, bssids = _usable_readings(wifi, node_xy, node_walk, bssids)
    s = float(cfg.cell_size_m)
    origin = grid_origin(node_xy[np.unique(node_i)], s) if origin_xy is None else np.asarray(origin_xy, float)
    rss = w["rssi_dbm"].to_numpy(dtype=np.float64)
    check_raster(node_xy[np.unique(node_i)], origin, s)
    ixy = np.floor((node_xy[node_i] - origin) / s).astype(np.int64)
    _, walk_code = np.unique(node_walk.astype(str), return_inverse=True)
    walk_r = walk_code[node_i]
    # scans: (node, t_s) or node
    if "t_s" in w:
        t_key = np.unique(w["t_s"].to_numpy(dtype=np.float64), return_inverse=True)[1].reshape(-1)
    else:
        t_key = np.zeros(len(w), dtype=np.int64)
    _, scan = _unique_count(node_i, t_key)

    cells_u, cell_r = _unique_count(ixy[:, 0], ixy[:, 1])
    n_c, m = len(cells_u), len(bssids)
    # statistics over the (cell, AP) entries some reading fell in; the dense (cell, AP) tables are written once
    flat = cell_r * m + col
    ent, inv = np.unique(flat, return_inverse=True)
    cnt_e = np.bincount(inv, minlength=len(ent))
    mean_e = np.bincount(inv, weights=rss, minlength=len(ent)) / cnt_e
    ss_e = np.bincount(inv, weights=(rss - mean_e[inv]) ** 2, minlength=len(ent))
    with np.errstate(invalid="ignore", divide="ignore"):
        std_e = np.where(cnt_e >= 2, np.sqrt(ss_e / np.maximum(cnt_e - 1, 1)), np.nan)
    # scans per cell and scans that saw each AP (a scan's duplicates of one AP count once)
    scan_cell = np.zeros(int(scan.max()) + 1, dtype=np.int64)
    scan_cell[scan] = cell_r
    visits = np.bincount(scan_cell, minlength=n_c)
    sa = np.unique(scan * m + col)
    seen_e = np.bincount(np.searchsorted(ent, scan_cell[sa // m] * m + sa % m), minlength=len(ent))
    ratio_e = seen_e / np.maximum(visits[ent // m], 1)
    n_w = walk_code.max() + 1
    nw_e = np.bincount(np.searchsorted(ent, np.unique(flat * n_w + walk_r) // n_w), minlength=len(ent))
    cwc = np.unique(cell_r * n_w + walk_r)
    n_walk_cell = np.bincount(cwc // n_w, minlength=n_c)
    n_node_cell = np.bincount(np.unique(cell_r * (len(node_xy) + 1) + node_i) // (len(node_xy) + 1),
                              minlength=n_c)

    keep_c = visits >= cfg.min_scans
    if not keep_c.any():
        raise InputError(f"no grid cell has at least min_scans = {cfg.min_scans} scans")
    n_k = int(keep_c.sum())
    check_table(n_k, m)
    row_of_cell = np.full(n_c, -1, dtype=np.int64)
    row_of_cell[keep_c] = np.arange(n_k)
    r_e, c_e = row_of_cell[ent // m], ent % m
    sel = (r_e >= 0) & (cnt_e >= cfg.min_count)  # fewer than min_count readings: not detected
    r_e, c_e = r_e[sel], c_e[sel]
    cnt = np.zeros((n_k, m), dtype=np.int32)
    mean = np.full((n_k, m), np.nan)
    std = np.full((n_k, m), np.nan)
    ratio = np.zeros((n_k, m))
    nw = np.zeros((n_k, m), dtype=np.int32)
    cnt[r_e, c_e] = cnt_e[sel]
    mean[r_e, c_e] = mean_e[sel]
    std[r_e, c_e] = std_e[sel]
    ratio[r_e, c_e] = ratio_e[sel]
    nw[r_e, c_e] = nw_e[sel]
    cells_u = cells_u[keep_c]
    cells = pd.DataFrame({
        "ix": cells_u[:, 0], "iy": cells_u[:, 1],
        "x_m": origin[0] + (cells_u[:, 0] + 0.5) * s, "y_m": origin[1] + (cells_u[:, 1] + 0.5) * s,
        "n_scans": visits[keep_c].astype(np.int64), "n_nodes": n_node_cell[keep_c].astype(np.int64),
        "n_walks": n_walk_cell[keep_c].astype(np.int64), "interpolated": False,
    })
    if cfg.fill.method != "none":
        from rmbuild.radiomap.fill import fill_cells

        cells, cnt, mean, std, ratio, nw = fill_cells(cells, cnt, mean, std, ratio, nw, origin, s, cfg.fill)
    cells.insert(0, "cell", np.arange(len(cells), dtype=np.int64))

    row_of = np.full(n_c, -1, dtype=np.int64)
    row_of[keep_c] = np.arange(int(keep_c.sum()))
    hc = cfg.histogram
    hist = build_histograms(row_of[cell_r], col, rss, motion_directions(node_xy, node_walk)[node_i], hc.bin_db,
                            hc.n_directions)
    wn = w.assign(node=node_i)
    fp = Fingerprints.from_readings(wn, bssids)
    return RadioMap(
        origin_xy=origin, cell_size_m=s, frame=cfg.frame if frame is None else frame, bssids=bssids,
        cells=cells.reset_index(drop=True), count=cnt.astype(np.int32), mean_dbm=mean.astype(np.float32),
        std_db=std.astype(np.float32), detect_ratio=ratio.astype(np.float32), n_walks=nw.astype(np.int32),
        nodes=fp, node_xy=node_xy[fp.node], node_walk=node_walk[fp.node], config=cfg, histograms=hist,
    )
