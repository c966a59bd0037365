"""`rmbuild export-map`: rasterise the aligned fingerprints into a radio map, in several formats."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from rmbuild.config import MapConfig, to_toml
from rmbuild.errors import InputError
from rmbuild.io.anchors import check_anchors, read_anchors
from rmbuild.io.floor_image import load_image
from rmbuild.io.workspace import ARTEFACTS, StageWriter, Workspace, level_of_floor
from rmbuild.radiomap import devices
from rmbuild.radiomap.build import CELL_COLUMNS, RadioMap
from rmbuild.stages.building import floor_workspaces, no_viewer_for_building, run_floors
from rmbuild.stages.common import Progress, ensure_progress, locked_workspace
from rmbuild.stages.mapping import built_positions, place_with_anchors
from rmbuild.stages.view import log_workspace
from rmbuild.types import BUILDING_FRAME_GAUGES
from rmbuild.viz.align import plan_segments
from rmbuild.viz.figures import coverage_figure, heatmaps_figure
from rmbuild.viz.viewer import Viewer, ensure_viewer

if TYPE_CHECKING:
    from rmbuild.floorplan import Georef  # shapely, pyproj: imported when a map is put on the globe


def run(
    workspace: str | Path,
    cfg: MapConfig,
    anchors_path: str | Path | None = None,
    progress: Progress | None = None,
    force: bool = False,
    viewer: Viewer | None = None,
    floor: str | None = None,
) -> dict:
    """Build the radio map from the optimised poses; returns the export-map report (a building's: every
    floor's, or the one ``floor`` names, :mod:`rmbuild.stages.building`)."""
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        no_viewer_for_building(viewer, floors)
        if anchors_path is not None and len(floors) > 1:
            raise InputError("--anchors name one floor's walks: pick the floor with --floor NAME")
        return run_floors(workspace, "export-map", floors,
                          lambda _, p: run(p, cfg, anchors_path, progress, force, viewer), stage="map")
    with locked_workspace(workspace, "export-map") as ws:
        return _run(ws, cfg, anchors_path, ensure_progress(progress), force, ensure_viewer(viewer))


def _run(ws: Workspace, cfg: MapConfig, anchors_path: str | Path | None, progress: Progress, force: bool,
         viewer: Viewer) -> dict:
    from rmbuild.radiomap import build_radio_map
    from rmbuild.stages.localize_geojson import find_georef  # the plan's georeference (shapely, pyproj)

    t0 = time.perf_counter()
    ds = ws.read_dataset()
    xy, info = _positions(ws, ds, cfg, anchors_path, force)
    progress.phase("rasterising")
    walk_of_node = ds.poses["walk_id"].astype(str).to_numpy()
    offsets = info["device_offsets_db"]
    try:
        rm = build_radio_map(devices.corrected(ds, offsets).wifi, xy, walk_of_node, cfg, frame=info["frame"])
    except InputError as e:  # the map's own limits: name the workspace whose map it is
        raise InputError(e.problem, e.where or str(ws.root)) from None
    rm.device_offsets_db = offsets
    ble_rm, ble_skipped = _ble_map(ds.ble, xy, walk_of_node, cfg, rm)
    t_build = time.perf_counter() - t0
    plan_doc = ws.read_json("data.floorplan") if ws.exists("data.floorplan") else None
    walls = plan_segments(ds.venue, plan_doc) if info["frame"] == "building" else None  # drawn in the pictures
    progress.phase("writing map")
    georef, plan_name, _, _ = find_georef(ws, rm.frame)
    floor = floor_number(ws)
    with ws.writing("map") as w:
        _write_wifi(w, ws, rm, cfg, info, walls, georef, plan_name, floor)
        ble_report = _write_ble(w, ble_rm, info, floor, georef) if ble_rm is not None else ble_skipped
        report = _report(rm, cfg, info, georef, _plan_coverage(plan_doc, rm) if walls is not None else None)
        report["evo"] = _write_evo(w, ws, ds, xy, info, rm.frame)
        report["time_s"] = {"build": round(t_build, 3), "total": round(time.perf_counter() - t0, 3)}
        if ble_report is not None:
            report["ble"] = ble_report
        w.report = report
    log_workspace(ws, viewer)
    return report


def _positions(ws: Workspace, ds, cfg: MapConfig, anchors_path: str | Path | None, force: bool
               ) -> tuple[np.ndarray, dict]:
    """The nodes' positions the map is built from and what export-map says of their frame (``--anchors``
    applied when the map is not in the building frame already)."""
    xy, info = built_positions(ws, ds, cfg)
    ws.check_can_write("map", force)
    if anchors_path is None and ws.exists("optimize.anchors"):
        info["anchors"] = "used by optimize"
    if anchors_path is not None:
        if info["gauge"] in BUILDING_FRAME_GAUGES:
            info["anchors_note"] = (f"optimize already placed the walks in the building frame ({info['gauge']}); "
                                    "--anchors ignored")
        else:
            anchors = read_anchors(anchors_path)
            check_anchors(anchors, ds)
            xy, extra = place_with_anchors(xy, ds, ws.read_table("optimize.poses"), anchors)
            info.update(extra)
    return xy, info


def floor_number(ws: Workspace) -> int:
    """The FLOOR the map's UJIIndoorLoc CSV gives its cells: the floor's level (0 the ground floor, -1 the
    first basement) from its name, in a building and alone alike; 0 when the name does not say."""
    from rmbuild.ingest.floors import floor_level

    level = level_of_floor(ws.root)
    if level is None:
        name = (ws.read_report("ingest") or {}).get("floor")
        level = floor_level(name) if isinstance(name, str) else None
    return level or 0


def _write_evo(w: StageWriter, ws: Workspace, ds, xy: np.ndarray, info: dict, frame: str) -> dict:
    """The map's walks as TUM files for evo on one clock, with their truth (:mod:`rmbuild.stages.map_evo`);
    returns what the report says of them (the files and the evo commands that score the map)."""
    from rmbuild.stages.map_evo import evo_recipe, evo_texts

    heading = ws.read_table("optimize.poses")["heading_rad"].to_numpy(dtype=float)
    if "anchor_fit" in info:  # --anchors turned the map: its headings too
        heading = heading + np.radians(info["anchor_fit"]["rotation_deg"])
    texts, clock = evo_texts(ds, xy, heading)
    for key, text in texts.items():
        w.text(key, text)
    w.text("map.evo_clock", clock.to_csv(index=False))
    return {"files": [ARTEFACTS[k] for k in texts], "clock": ARTEFACTS["map.evo_clock"],
            "commands": evo_recipe(frame, set(texts))}


def _write_wifi(w: StageWriter, ws: Workspace, rm: RadioMap, cfg: MapConfig, info: dict, walls: np.ndarray | None,
                georef: Georef | None, plan_name: str, floor: int) -> None:
    """The Wi-Fi map's tables, CSVs, sidecar, GeoJSON (on the globe) and pictures (over the plan's walls and
    image in the building frame)."""
    from rmbuild.stages.map_geojson import cells_feature_collection

    node_pos = pd.DataFrame({"node": rm.nodes.node, "walk": rm.node_walk, "x_m": rm.node_xy[:, 0],
                             "y_m": rm.node_xy[:, 1]})
    long = rm.long_table()
    w.table("map.cells", long)
    w.table("map.cell_table", rm.cells[list(CELL_COLUMNS)])
    w.table("map.nodes", rm.nodes.to_long().merge(node_pos, on="node", how="left"))
    _write_uji(w, rm, floor, georef, "map.wide_csv", "map.wide_csv_aps")
    if rm.histograms is not None:
        w.table("map.histograms", rm.histograms.long_table(rm.bssids, rm.cells))
    side = rm.sidecar()
    side.update(frame_info=info, uji_coordinates=_uji_coordinates(georef))
    w.json("map.sidecar", side)
    if georef is not None:  # on the globe: the cells as WGS84 squares
        w.json("map.cells_geojson", cells_feature_collection(rm.cells, long, rm.cell_size_m, georef, plan_name))
    image = load_image(ws) if walls is not None else None  # drawn where the plan is: the building frame
    w.figure("map.coverage_png", coverage_figure(rm.cells, rm.cell_size_m, walls, rm.frame, image))
    w.figure("map.heatmaps_png", heatmaps_figure(long, cfg.heatmap_top_n, walls, rm.cell_size_m, image=image))
    w.config(to_toml(cfg, "map"))


def _report(rm: RadioMap, cfg: MapConfig, info: dict, georef: Georef | None, plan_coverage: dict | None) -> dict:
    """export-map's report (without its times and the BLE map's part)."""
    hist = rm.histograms
    return {
        "stage": "export-map",
        "frame": info["frame"],
        "frame_info": info,
        "cells": int(rm.n_cells),
        "cells_interpolated": int(rm.cells["interpolated"].sum()) if "interpolated" in rm.cells else 0,
        "reference_nodes": len(rm.nodes),
        "aps": len(rm.bssids),
        "cell_size_m": cfg.cell_size_m,
        "cells_geojson": ARTEFACTS["map.cells_geojson"] if georef is not None else None,
        "uji_coordinates": _uji_coordinates(georef),
        "plan_coverage": plan_coverage,
        "histograms": None if hist is None else {
            "entries": len(hist), "bin_db": hist.bin_db, "n_directions": hist.n_directions,
            "readings_with_direction": float(hist.count[hist.sector >= 0].sum() / max(hist.count.sum(), 1))},
    }


def _ble_map(ble: pd.DataFrame | None, xy: np.ndarray, walk_of_node: np.ndarray, cfg: MapConfig, rm: RadioMap,
             ) -> tuple[RadioMap | None, dict | None]:
    """The BLE radio map on the Wi-Fi map's grid (its origin and cell size), from the same node positions;
    (None, None) without BLE readings, (None, {"skipped": why}) when none can be placed."""
    from rmbuild.radiomap import build_radio_map

    if ble is None or not len(ble):
        return None, None
    try:
        return build_radio_map(ble, xy, walk_of_node, cfg, rm.origin_xy, frame=rm.frame), None
    except InputError as e:
        return None, {"skipped": str(e).replace("Wi-Fi", "BLE")}


def _plan_coverage(plan_doc: dict | None, rm: RadioMap) -> dict | None:
    """How much of the floor plan's walkable space the map's visited cells cover (the map in the plan's
    frame), None without a plan."""
    if plan_doc is None:
        return None
    from rmbuild.floorplan import covered_share, from_local_geojson

    visited = rm.cells[~rm.cells["interpolated"].to_numpy(bool)] if "interpolated" in rm.cells else rm.cells
    return covered_share(from_local_geojson(plan_doc), visited[["x_m", "y_m"]].to_numpy(float), rm.cell_size_m)


def _uji_coordinates(georef: Georef | None) -> str:
    """What the UJI-layout CSVs' LONGITUDE and LATITUDE hold."""
    return "EPSG:3857" if georef is not None else "map_frame_m"


def _write_uji(w: StageWriter, rm: RadioMap, floor: int, georef: Georef | None, csv_key: str, aps_key: str) -> None:
    """The map in UJIIndoorLoc's wide layout and its WAPnnn -> BSSID table (for tools that read the CSV
    alone); LONGITUDE, LATITUDE in Web Mercator metres as UJIIndoorLoc's when the map is on the globe."""
    xy = None if georef is None else georef.to_web_mercator(rm.cells[["x_m", "y_m"]].to_numpy(float))
    rm.wide_table("uji", floor=floor, uji_xy=xy).to_csv(w.path(csv_key), index=False)
    pd.DataFrame({"column": rm.wap_names(), "bssid": [str(b) for b in rm.bssids]}).to_csv(w.path(aps_key),
                                                                                          index=False)


def _write_ble(w: StageWriter, rm: RadioMap, info: dict, floor: int, georef: Georef | None) -> dict:
    """Write the BLE map's files (the Wi-Fi map's tables, CSV and sidecar under ``map.ble_*`` names);
    returns its part of the report."""
    w.table("map.ble_cells", rm.long_table())
    w.table("map.ble_cell_table", rm.cells[list(CELL_COLUMNS)])
    _write_uji(w, rm, floor, georef, "map.ble_wide_csv", "map.ble_wide_csv_aps")
    side = rm.sidecar()
    side.update(frame_info=info, modality="ble", uji_coordinates=_uji_coordinates(georef))
    w.json("map.ble_sidecar", side)
    keys = ("map.ble_cells", "map.ble_cell_table", "map.ble_wide_csv", "map.ble_wide_csv_aps", "map.ble_sidecar")
    return {"cells": int(rm.n_cells), "beacons": len(rm.bssids), "reference_nodes": len(rm.nodes),
            "files": [ARTEFACTS[k] for k in keys]}
