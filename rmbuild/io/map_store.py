"""Reading a workspace's radio map back: the map stage's tables -> one in-memory :class:`RadioMap`.

`export-map` writes the map as long tables (``map/radiomap.parquet``: one row per cell and detected AP;
``map/reference_nodes.parquet``: one row per map node and detected AP, with the node's walk and position;
``map/histograms.parquet``) plus a JSON sidecar (grid, frame, AP order) and the config it ran with. This
module pivots them back into the arrays :class:`RadioMap` holds, in the sidecar's AP order, so a map read
back localizes exactly as the one that was written (``tests/test_api.py`` checks the round trip).

File names stay in :mod:`rmbuild.io.workspace` (artefact keys ``map.*``); every file is checked against
the checksums export-map recorded.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.config import MapConfig, load_stage_config_text
from rmbuild.errors import WorkspaceError
from rmbuild.io.workspace import Workspace
from rmbuild.radiomap.build import CELL_COLUMNS, RadioMap
from rmbuild.radiomap.histogram import HistogramLayer
from rmbuild.types import Fingerprints


def read_map_config(ws: Workspace) -> MapConfig:
    """The [map] config export-map ran with in ``ws`` (defaults when it has not run)."""
    text = ws.read_config_text("map")
    if text is None:
        return MapConfig()
    return load_stage_config_text("map", text, str(ws.path("map.config")))


def read_radio_map(ws: Workspace) -> RadioMap:
    """The radio map export-map wrote in ``ws``; WorkspaceError when there is none or it is inconsistent."""
    ws.require("map")
    if ws.stale_inputs("map"):
        raise WorkspaceError(f"{ws.path('map.cells')}: export-map ran on an earlier optimize or ingest of this "
                             "workspace; re-run `rmbuild export-map --force`")
    side = ws.read_json("map.sidecar")
    try:
        bssids = np.asarray([str(b) for b in side["aps"]], dtype=object)
        origin = np.asarray(side["grid"]["origin_xy_m"], dtype=np.float64)
        cell_size = float(side["grid"]["cell_size_m"])
        frame = str(side.get("frame", ""))
        offsets = {str(k): float(v) for k, v in (side.get("device_offsets_db") or {}).items()}
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise WorkspaceError(f"{ws.path('map.sidecar')}: not a radio-map sidecar ({type(e).__name__}: {e})") from None
    long = ws.read_table("map.cells")
    cells = _cells(long)
    if ws.exists("map.cell_table"):  # the per-cell counts (maps written before it have lower bounds / -1)
        cells = _counts(cells, ws.read_table("map.cell_table"), ws)
    arrays = _cell_arrays(long, cells, bssids, ws)
    nodes, node_xy, node_walk = _nodes(ws.read_table("map.nodes"), bssids, ws)
    hist = _histograms(ws, side, bssids, cells) if ws.exists("map.histograms") else None
    return RadioMap(origin_xy=origin, cell_size_m=cell_size, frame=frame, bssids=bssids, cells=cells,
                    **arrays, nodes=nodes, node_xy=node_xy, node_walk=node_walk, config=read_map_config(ws),
                    histograms=hist, device_offsets_db=offsets)


def _cells(long: pd.DataFrame) -> pd.DataFrame:
    """The cell table (:data:`CELL_COLUMNS`): one row per cell id, from the long table.

    The per-cell counts of scans, nodes and walks are not in the long table (they are in the cell table,
    :func:`_counts`): here ``n_walks`` is the largest per-AP count of walks (a lower bound), ``n_scans`` and
    ``n_nodes`` are -1.
    """
    g = long.groupby("cell", sort=True)
    first = g[["ix", "iy", "x_m", "y_m", "interpolated"]].first()
    cells = pd.DataFrame({
        "cell": first.index.to_numpy(dtype=np.int64),
        "ix": first["ix"].to_numpy(dtype=np.int64), "iy": first["iy"].to_numpy(dtype=np.int64),
        "x_m": first["x_m"].to_numpy(dtype=np.float64), "y_m": first["y_m"].to_numpy(dtype=np.float64),
        "n_scans": np.full(len(first), -1, dtype=np.int64), "n_nodes": np.full(len(first), -1, dtype=np.int64),
        "n_walks": g["n_walks"].max().to_numpy(dtype=np.int64),
        "interpolated": first["interpolated"].to_numpy(dtype=bool),
    })
    return cells[list(CELL_COLUMNS)]


def _counts(cells: pd.DataFrame, table: pd.DataFrame, ws: Workspace) -> pd.DataFrame:
    """``cells`` with n_scans, n_nodes and n_walks from the map's cell table."""
    try:
        t = table.set_index("cell").loc[cells["cell"].to_numpy()]
        out = cells.copy()
        for c in ("n_scans", "n_nodes", "n_walks"):
            out[c] = t[c].to_numpy(dtype=np.int64)
    except (KeyError, ValueError, TypeError) as e:
        raise WorkspaceError(f"{ws.path('map.cell_table')}: cells do not match the radio map "
                             f"({type(e).__name__}: {str(e)[:100]})") from None
    return out


def _cell_arrays(long: pd.DataFrame, cells: pd.DataFrame, bssids: np.ndarray, ws: Workspace) -> dict:
    """count, mean_dbm, std_db, detect_ratio, n_walks as (n_cells, n_ap) arrays."""
    r = np.searchsorted(cells["cell"].to_numpy(), long["cell"].to_numpy(dtype=np.int64))
    c = pd.Index(bssids).get_indexer(long["bssid"].astype(str))
    if (c < 0).any():
        raise WorkspaceError(f"{ws.path('map.cells')}: AP {long['bssid'].iloc[int(np.argmax(c < 0))]!r} is not "
                             "among the sidecar's APs; re-run `rmbuild export-map --force`")
    shape = (len(cells), len(bssids))

    def pivot(col: str, fill: float, dtype: type) -> np.ndarray:
        out: np.ndarray = np.full(shape, fill, dtype=dtype)
        out[r, c] = long[col].to_numpy(dtype=dtype)
        return out

    return {"count": pivot("count", 0, np.int32), "mean_dbm": pivot("rssi_mean_dbm", np.nan, np.float32),
            "std_db": pivot("rssi_std_db", np.nan, np.float32),
            "detect_ratio": pivot("detect_ratio", 0.0, np.float32), "n_walks": pivot("n_walks", 0, np.int32)}


def _nodes(tab: pd.DataFrame, bssids: np.ndarray, ws: Workspace) -> tuple[Fingerprints, np.ndarray, np.ndarray]:
    """The map nodes' fingerprints (columns in the map's AP order), positions and walks."""
    node = tab["node"].to_numpy(dtype=np.int64)
    uniq, r = np.unique(node, return_inverse=True)
    c = pd.Index(bssids).get_indexer(tab["bssid"].astype(str))
    if (c < 0).any():
        raise WorkspaceError(f"{ws.path('map.nodes')}: an AP is not among the sidecar's APs; re-run "
                             "`rmbuild export-map --force`")
    rss = np.full((len(uniq), len(bssids)), np.nan, dtype=np.float32)
    cnt = np.zeros((len(uniq), len(bssids)), dtype=np.int32)
    rss[r, c] = tab["rssi_dbm"].to_numpy(dtype=np.float32)
    cnt[r, c] = tab["count"].to_numpy(dtype=np.int32)
    first = np.unique(r, return_index=True)[1]
    xy = tab[["x_m", "y_m"]].to_numpy(dtype=np.float64)[first]
    walk = tab["walk"].to_numpy()[first]
    return Fingerprints(uniq, bssids, rss, cnt), xy, walk


def _histograms(ws: Workspace, side: dict, bssids: np.ndarray, cells: pd.DataFrame) -> HistogramLayer:
    tab = ws.read_table("map.histograms")
    meta = side.get("histograms") or {}
    bin_db = float(meta.get("bin_db", 2.0))
    ap = pd.Index(bssids).get_indexer(tab["bssid"].astype(str))
    if (ap < 0).any():
        raise WorkspaceError(f"{ws.path('map.histograms')}: an AP is not among the sidecar's APs; re-run "
                             "`rmbuild export-map --force`")
    row = pd.Index(cells["cell"]).get_indexer(tab["cell"].to_numpy(dtype=np.int64))
    keep = row >= 0  # a cell where no AP was kept has no row in the map (nor a use for a histogram)
    return HistogramLayer(
        bin_db=bin_db, n_directions=int(meta.get("n_directions", 0)), cell=row[keep].astype(np.int64),
        sector=tab["sector"].to_numpy()[keep].astype(np.int8), ap=ap[keep].astype(np.int32),
        bin=np.rint(tab["rssi_lo_dbm"].to_numpy(dtype=np.float64)[keep] / bin_db).astype(np.int32),
        count=tab["count"].to_numpy(dtype=np.int32)[keep],
    )
