"""`map/cells.geojson`: the radio map's cells in WGS84 (RFC 7946), when the map can be put on the globe.

A map that :func:`rmbuild.stages.localize_geojson.map_georef` puts on the globe (in the building frame,
with a floor plan that has lon/lat) gets one
Polygon feature per cell — the cell's square, corners through :meth:`rmbuild.floorplan.Georef.to_lonlat`,
counter-clockwise — with properties cell, ix, iy, x_m / y_m (the cell's centre in the map's frame),
n_scans, n_walks, n_aps (APs heard in it), strongest_bssid / strongest_rssi_dbm (its strongest AP by mean
RSSI) and interpolated. GIS tools and web maps read it as is.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.floorplan import Georef

#: decimal places of the written lon/lat (1e-8 deg: about a millimetre)
LONLAT_DECIMALS = 8


def cells_feature_collection(cells: pd.DataFrame, long: pd.DataFrame, cell_size_m: float, georef: Georef,
                             name: str = "") -> dict:
    """The cells (``RadioMap.cells``; ``long``: its long table, one row per cell and AP) as a
    FeatureCollection of lon/lat squares (module docstring)."""
    per_cell = _strongest(long)
    h = cell_size_m / 2.0
    x, y = cells["x_m"].to_numpy(float), cells["y_m"].to_numpy(float)
    corners = np.stack([np.c_[x - h, y - h], np.c_[x + h, y - h], np.c_[x + h, y + h], np.c_[x - h, y + h]], axis=1)
    lonlat = np.round(georef.to_lonlat(corners.reshape(-1, 2)), LONLAT_DECIMALS).reshape(len(cells), 4, 2)
    features = []
    for i, row in enumerate(cells.itertuples(index=False)):
        ring = [[float(a), float(b)] for a, b in lonlat[i]]
        strongest = per_cell.get(int(row.cell), (0, None, None))
        features.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring + ring[:1]]},
                         "properties": {"cell": int(row.cell), "ix": int(row.ix), "iy": int(row.iy),
                                        "x_m": float(row.x_m), "y_m": float(row.y_m), "n_scans": int(row.n_scans),
                                        "n_walks": int(row.n_walks), "n_aps": strongest[0],
                                        "strongest_bssid": strongest[1], "strongest_rssi_dbm": strongest[2],
                                        "interpolated": bool(row.interpolated)}})
    return {"type": "FeatureCollection", "name": name or "radio map cells", "features": features}


def _strongest(long: pd.DataFrame) -> dict[int, tuple[int, str, float]]:
    """cell -> (APs heard, the strongest AP by mean RSSI, its mean RSSI rounded to 0.1 dBm)."""
    if not len(long):
        return {}
    n = long.groupby("cell").size()
    top = long.loc[long.groupby("cell")["rssi_mean_dbm"].idxmax()]
    return {int(c): (int(n[c]), str(b), round(float(r), 1))
            for c, b, r in zip(top["cell"], top["bssid"], top["rssi_mean_dbm"])}
