"""`rmbuild view`: log whatever a workspace holds to a rerun recording (file, native viewer or web viewer).

Every stage's outputs are optional: a stage that has not run is skipped (and said so in the summary), and
tables lacking optional columns are logged as far as they go.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rmbuild.io.floor_image import load_image
from rmbuild.io.workspace import STAGE_COMMANDS, Workspace, walk_file_names
from rmbuild.stages.building import floor_workspaces, no_viewer_for_building, run_floors
from rmbuild.stages.common import Progress, ensure_progress, locked_workspace
from rmbuild.viz import Viewer, ViewTarget, open_viewer
from rmbuild.viz.align import frame_to_fixes, frame_to_truth, plan_segments

log = logging.getLogger(__name__)


def _stale_stages(ws: Workspace, skipped: dict[str, str]) -> set[str]:
    """The stages whose outputs were built from an earlier run of a stage they read (e.g. optimize before an
    ``ingest --append``): not logged beside the current ones, with a warning and a reason in ``skipped``."""
    out = set()
    for s in ("optimize", "map", "evaluate"):
        if ws.has(s) and (old := ws.stale_inputs(s)):
            out.add(s)
            skipped[s] = (f"stale: {STAGE_COMMANDS[s]} ran on an earlier {', '.join(old)}; re-run "
                          f"`rmbuild {STAGE_COMMANDS[s]} --force`")
            log.warning(f"{ws.root}: {skipped[s]}")
    return out


def log_workspace(ws: Workspace, viewer: Viewer, progress: Progress | None = None) -> dict:
    """Log every stage ``ws`` holds to ``viewer``; returns {"logged": [...], "skipped": {...}, "time_s"}.

    With a disabled viewer (:class:`rmbuild.viz.viewer.NullViewer`) nothing is read."""
    progress = ensure_progress(progress)
    logged: list[str] = []
    skipped: dict[str, str] = {}
    times: dict[str, float] = {}
    if not viewer.enabled:
        return {"logged": logged, "skipped": {"all": "viewing is off"}, "time_s": times}

    def step(name: str) -> float:
        progress.phase(name)
        return time.perf_counter()

    t = step("ingest")
    ds = ws.read_dataset()
    viewer.set_walks(ds.walk_ids())
    walls = plan_segments(ds.venue, ws.read_json("data.floorplan") if ws.exists("data.floorplan") else None)
    viewer.log_venue(None if walls is None else {"walls": walls.tolist()})
    if (image := load_image(ws)) is not None:
        viewer.log_plan_image(*image)
    viewer.log_raw_walks(ds.poses)
    logged.append("raw walks")
    if ds.truth_poses is not None and len(ds.truth_poses):
        viewer.log_truth(ds.truth_poses)
        logged.append("truth")
    else:
        skipped["truth"] = "no data/truth/poses.parquet"
    if ds.fixes is not None and len(ds.fixes):
        viewer.log_fixes(ds.fixes)
        logged.append("waypoints")
    times["ingest"] = time.perf_counter() - t

    stale = _stale_stages(ws, skipped)
    if ws.has("optimize") and "optimize" not in stale:
        t = step("optimize")
        opt = ws.read_table("optimize.poses")
        gauge = ws.read_optimize_state().gauge if ws.exists("optimize.state") else None
        rt = frame_to_truth(opt, ds.truth_poses, gauge)
        if rt is None and ds.truth_poses is None:  # real data: the waypoints place the map in the building
            rt = frame_to_fixes(opt[opt["linked"].astype(bool)] if "linked" in opt else opt, ds.fixes, gauge)
        if rt is not None:
            viewer.log_alignment(float(np.arctan2(rt[0][1, 0], rt[0][0, 0])), rt[1])
        viewer.log_optimized(opt)
        if ws.exists("optimize.initial_poses"):
            viewer.log_optimized(ws.read_table("optimize.initial_poses"), kind="initial")
        pairs = ws.read_table("optimize.pairs") if ws.exists("optimize.pairs") else None
        if pairs is not None:
            viewer.log_vicinity(pairs, opt[["x_m", "y_m"]].to_numpy(dtype=np.float64))
        if ws.exists("optimize.history"):
            h = ws.read_table("optimize.history")
            if "cost" in h:
                viewer.log_cost_history(h["cost"].to_numpy(), h["iteration"].to_numpy() if "iteration" in h
                                        else None)
        if len(opt) == len(ds.poses):
            viewer.log_residuals(ds.poses, opt, pairs)
        logged.append("optimize")
        times["optimize"] = time.perf_counter() - t
    elif "optimize" not in stale:
        skipped["optimize"] = "stage not run"

    if ws.has("map") and ws.exists("map.cells") and "map" not in stale:
        t = step("map")
        sidecar = ws.read_json("map.sidecar") if ws.exists("map.sidecar") else {}
        grid = (sidecar or {}).get("grid") or {}
        viewer.log_radiomap(ws.read_table("map.cells"), cell_size_m=grid.get("cell_size_m"),
                            origin_xy_m=grid.get("origin_xy_m"))
        logged.append("map")
        times["map"] = time.perf_counter() - t
    elif "map" not in stale:
        skipped["map"] = "stage not run"

    if ws.has("evaluate") and ws.exists("evaluate.tracks") and "evaluate" not in stale:
        t = step("evaluate")
        n = viewer.log_tracks(ws.read_table("evaluate.tracks"))
        (logged.append("evaluate") if n else skipped.__setitem__("evaluate", "no usable tracks"))
        times["evaluate"] = time.perf_counter() - t
    elif "evaluate" not in stale:
        skipped["evaluate"] = "stage not run"
    return {"logged": logged, "skipped": skipped, "time_s": {k: round(v, 4) for k, v in times.items()}}


def floor_target(target: ViewTarget | None, floor: str) -> ViewTarget | None:
    if target is None or target.path is None:
        return target
    name = walk_file_names([floor])[floor]
    return replace(target, path=target.path.with_name(f"{target.path.stem}-{name}{target.path.suffix}"))


def run(workspace: str | Path, target: ViewTarget | None = None, viewer: Viewer | None = None,
        progress: Progress | None = None, floor: str | None = None) -> dict:
    """Log ``workspace`` to ``viewer`` (left open: the caller closes it, e.g. a served viewer that must stay
    up) or else to a new viewer for ``target`` (closed at the end: the .rrd is complete on return).
    Returns a summary: what was logged and skipped, where, counts, timings.

    A building: one recording per floor (or the one ``floor`` names); a saved one goes to ``PATH-<floor>.rrd``
    beside ``target``'s path, a spawned one is a recording of its own in the viewer."""
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        no_viewer_for_building(viewer, floors)
        if viewer is not None:
            return run(next(iter(floors.values())), target, viewer, progress)
        return run_floors(workspace, "view", floors, lambda n, p: run(p, floor_target(target, n), None, progress),
                          stage="view", exclusive=False, summaries=True)
    t0 = time.perf_counter()
    with locked_workspace(workspace, "view", exclusive=False) as ws:
        ws.require("ingest")
        if viewer is None:
            if target is None:
                raise ValueError("view.run needs a target or a viewer")
            with open_viewer(target, recording_name=f"rmbuild {Path(workspace).name}") as v:
                summary = log_workspace(ws, v, progress)
                counts = dict(v.counts)
        else:
            summary = log_workspace(ws, viewer, progress)
            viewer.flush()
            counts = dict(viewer.counts)
            target = viewer.target or target
    summary.update({
        "stage": "view",
        "mode": target.mode if target is not None else None,
        "path": str(target.path) if target is not None and target.path is not None else None,
        "counts": counts,
        "time_total_s": round(time.perf_counter() - t0, 3),
    })
    return summary
