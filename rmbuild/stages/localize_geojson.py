"""`rmbuild localize -o OUT.geojson`: the per-scan positions as a GeoJSON FeatureCollection (RFC 7946).

Only a georeferenced map can be written so: one in the building frame (optimize used anchors or the floor
plan) whose workspace holds a floor plan with lon/lat (`ingest --floorplan` of a WGS84 GeoJSON or an MS
ILC floor, :class:`rmbuild.floorplan.Georef`). Each scan is a Point feature (lon, lat; null geometry for a
scan without an estimate) with properties walk, time (s), uncertainty (m), floor, x_m / y_m (the map's
frame) and, when the input has ground truth, error_m.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from rmbuild.errors import InputError
from rmbuild.floorplan import Georef, from_local_geojson
from rmbuild.io.workspace import Workspace
from rmbuild.radiomap.build import RadioMap

WHY = "GeoJSON needs a georeferenced map (write .csv or .parquet instead)"


def map_georef(ws: Workspace, rm: RadioMap) -> tuple[Georef, str]:
    """(georeference, plan name) of the workspace's map; InputError saying why when it has none."""
    georef, name, why, where = find_georef(ws, rm.frame)
    if georef is None:
        raise InputError(f"{WHY}: {why}", where)
    return georef, name


def find_georef(ws: Workspace, frame: str) -> tuple[Georef | None, str, str, str]:
    """(georeference, plan name, "", "") of a map in ``frame`` that can be put on the globe, else (None, "",
    why not, the path it concerns)."""
    if frame != "building":
        return None, "", (f"the map is in the frame {frame!r}, not the building's (optimize used neither "
                          "anchors nor the floor plan)"), str(ws.root)
    if not ws.exists("data.floorplan"):
        return None, "", ("the map is in the building frame but the workspace has no floor plan with lon/lat "
                          "(`rmbuild ingest --floorplan FILE`)"), str(ws.root)
    plan = from_local_geojson(ws.read_json("data.floorplan"))
    if plan.georef is None:
        return None, "", "the workspace's floor plan is in local metres, without lon/lat", \
            str(ws.path("data.floorplan"))
    return plan.georef, plan.name, "", ""


def _num(v) -> float | None:
    f = float(v)
    return None if math.isnan(f) else f


def feature_collection(table: pd.DataFrame, georef: Georef, floor: str | None) -> dict:
    """The positions ``table`` (:func:`rmbuild.localize.apply.positions_table`) as a FeatureCollection."""
    xy = table[["x_m", "y_m"]].to_numpy(float)
    ok = np.isfinite(xy).all(axis=1)
    lonlat = np.full_like(xy, np.nan)
    if ok.any():
        lonlat[ok] = georef.to_lonlat(xy[ok])
    has_err = "error_m" in table
    features = []
    for i, row in enumerate(table.itertuples(index=False)):
        props = {"walk": str(row.walk_id), "time": _num(row.t_s), "uncertainty": _num(row.uncertainty_m),
                 "floor": floor, "x_m": _num(row.x_m), "y_m": _num(row.y_m)}
        if has_err:
            props["error_m"] = _num(row.error_m)
        geom = ({"type": "Point", "coordinates": [round(float(lonlat[i, 0]), 8), round(float(lonlat[i, 1]), 8)]}
                if ok[i] else None)
        features.append({"type": "Feature", "geometry": geom, "properties": props})
    return {"type": "FeatureCollection", "features": features}


def geojson_bytes(table: pd.DataFrame, georef: Georef, floor: str | None) -> bytes:
    return json.dumps(feature_collection(table, georef, floor)).encode("utf-8")
