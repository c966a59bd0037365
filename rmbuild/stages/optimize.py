"""`rmbuild optimize`: align every walk into one frame; write poses, pairs, per-walk report, TUM files."""

from __future__ import annotations

import logging
import math
import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from rmbuild.config import OptimizeConfig, to_toml
from rmbuild.errors import InputError
from rmbuild.evaluate.trajectory import landmark_error_unlinked_at_raw, trajectory_metrics
from rmbuild.io.tum import tum_texts
from rmbuild.io.workspace import Workspace
from rmbuild.stages.building import floor_workspaces, no_viewer_for_building, run_floors
from rmbuild.stages.common import Progress, ensure_progress, locked_workspace
from rmbuild.viz.viewer import Viewer, ensure_viewer

if TYPE_CHECKING:
    from rmbuild.floorplan import FloorPlan

log = logging.getLogger(__name__)


def run(
    workspace: str | Path,
    cfg: OptimizeConfig,
    anchors_path: str | Path | None = None,
    progress: Progress | None = None,
    force: bool = False,
    viewer: Viewer | None = None,
    floor: str | None = None,
    incremental: bool = False,
) -> dict:
    """Run the SLAM back end on the workspace's walks; returns the optimize report (a building's: every
    floor's, or the one ``floor`` names, :mod:`rmbuild.stages.building`). ``incremental``: place only the
    walks appended since the last optimize against its solution (:mod:`rmbuild.slam.incremental`)."""
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        no_viewer_for_building(viewer, floors)
        if anchors_path is not None and len(floors) > 1:
            raise InputError("--anchors name one floor's walks: pick the floor with --floor NAME")
        return run_floors(workspace, "optimize", floors,
                          lambda _, p: run(p, cfg, anchors_path, progress, force, viewer, incremental=incremental))
    with locked_workspace(workspace, "optimize") as ws:
        return _run(ws, cfg, anchors_path, ensure_progress(progress), force, ensure_viewer(viewer), incremental)


def _run(ws: Workspace, cfg: OptimizeConfig, anchors_path: str | Path | None, progress: Progress, force: bool,
         viewer: Viewer, incremental: bool = False) -> dict:
    t0 = time.perf_counter()
    ds = ws.read_dataset(readings=False)  # the optimisation works from the fingerprints
    fp = ws.read_fingerprints()
    from rmbuild.slam import optimize

    held = _held_map(ws, anchors_path is not None) if incremental else None
    anchor_table = ws.read_table("optimize.anchors") if held is not None and ws.exists("optimize.anchors") else None
    if anchors_path is not None:
        from rmbuild.io.anchors import check_anchors, read_anchors

        anchors = read_anchors(anchors_path)
        check_anchors(anchors, ds, cfg.anchors.max_gap_s)
        anchor_table = anchors.table
    if held is None:
        ws.check_can_write("optimize", force)
    on_progress = _progress_adapter(progress, viewer)
    plan, plan_check = _floor_plan(ws, cfg, ds)
    result = optimize(ds, fp, cfg, anchors=None if held else anchor_table, progress=on_progress, floorplan=plan,
                      held=held)
    gave_up = (result.stats.get("incremental") or {}).get("gave_up")
    if gave_up:  # the new walks disagree with the held map: the full method's answer instead
        log.warning("--incremental: %s; running the full optimization instead", gave_up)
        checked = {**result.stats["incremental"], "tried_s": round(result.stats["time_s"]["total"], 4)}
        result = optimize(ds, fp, cfg, anchors=anchor_table, progress=on_progress, floorplan=plan)
        result.stats["incremental"] = checked  # time_s: the full run's; tried_s: the incremental try's
        result.stats["warnings"] = [f"--incremental gave up: {gave_up}; the full optimization ran instead",
                                    *result.stats.get("warnings", [])]
    gauge = result.state.gauge
    if plan_check is not None:
        result.stats["floorplan_check"] = plan_check
        result.stats["warnings"] = [*result.stats.get("warnings", []), *([plan_check["warning"]]
                                                                         if plan_check.get("warning") else [])]
    return _write(ws, ds, cfg, result, gauge, anchor_table, progress, viewer, t0)


def _held_map(ws: Workspace, anchors_given: bool):
    """``--incremental``: the last optimize's map (its typed state and poses) the new walks are placed
    against. Raises InputError when there is none, when nothing was appended since, or with ``--anchors``
    (the map's frame is the last run's)."""
    from rmbuild.slam.held import HeldMap

    if anchors_given:
        raise InputError("--incremental keeps the last optimize's frame: --anchors apply to a full "
                         "`rmbuild optimize --force`")
    if not ws.has("optimize"):
        raise InputError("--incremental needs an earlier optimize of this workspace to add walks to; run "
                         "`rmbuild optimize` first", str(ws.root))
    if "ingest" not in ws.stale_inputs("optimize"):
        raise InputError("the last optimize already ran on this workspace's current walks: nothing to add "
                         "(append walks with `rmbuild ingest --append` first)", str(ws.root))
    poses = ws.read_table("optimize.poses")
    return HeldMap(ws.read_optimize_state(), poses[["x_m", "y_m", "heading_rad"]].to_numpy(float))


def _write(ws: Workspace, ds, cfg: OptimizeConfig, result, gauge: str, anchor_table: pd.DataFrame | None,
           progress: Progress, viewer: Viewer, t0: float) -> dict:
    """Trajectory metrics, the report and every optimize output, in one commit."""
    progress.phase("trajectory metrics, writing")
    t_metrics = time.perf_counter()
    raw = trajectory_metrics(ds.poses, ds, align=True)
    # the optimised walks' alignment is fitted on the linked walks: an unlinked walk's frame is arbitrary
    linked = result.walks.loc[result.walks["linked"].astype(bool), "walk_id"].astype(str).tolist()
    opt = trajectory_metrics(result.poses, ds, align=gauge == "se2", fit_walks=linked or None)
    if linked:  # whether optimising made the walks worse than raw: null when every walk is linked
        opt["landmark_error_unlinked_at_raw_m"] = landmark_error_unlinked_at_raw(ds.poses, result.poses, ds, linked,
                                                                                 align=gauge == "se2")
    stats = dict(result.stats)
    time_s = dict(stats.pop("time_s", {}))
    time_s["metrics"] = time.perf_counter() - t_metrics
    report = {
        "stage": "optimize",
        "factors": stats.pop("factors"),
        "walks": len(ds.walks),
        "poses": len(ds.poses),
        "gauge": gauge,
        # which walks the one SE(2) alignment of the optimised metrics was fitted on (gauge "se2")
        "metrics_alignment": {"fitted_on": "linked walks" if linked else "all walks",
                              "walks": len(linked) if linked else len(ds.walks)},
        "time_s": {k: round(float(v), 4) for k, v in time_s.items()},
        "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "raw": raw,
        "optimized": opt,
        **stats,
    }
    with ws.writing("optimize") as w:
        w.table("optimize.poses", result.poses)
        w.table("optimize.initial_poses", result.initial_poses)
        w.table("optimize.pairs", result.pairs)
        w.table("optimize.walks", result.walks)
        solve = np.zeros(len(result.cost_history), dtype=np.int64)  # which solve each cost belongs to
        for start in result.solve_starts[1:]:
            solve[start:] += 1
        w.table("optimize.history", pd.DataFrame({"iteration": np.arange(len(result.cost_history)),
                                                  "cost": result.cost_history, "solve": solve}))
        placed = result.poses.groupby("walk_id", sort=False)["linked"].first()  # placed in the map's frame
        w.per_walk_texts("optimize.tum_dir", "optimize.tum_index",
                         tum_texts(result.poses, result.poses["walk_id"]), ".txt",
                         columns={"linked": {str(k): bool(v) for k, v in placed.items()}})
        if ds.truth_poses is not None and len(ds.truth_poses):  # for `evo_ape tum TRUTH ESTIMATE -a`
            w.per_walk_texts("optimize.tum_truth_dir", "optimize.tum_truth_index",
                             tum_texts(ds.truth_poses, ds.truth_poses["walk_id"].astype(str)), ".txt")
        if anchor_table is not None:
            w.table("optimize.anchors", anchor_table)
        w.optimize_state(result.state)
        w.config(to_toml(cfg, "optimize"))
        report["time_s"]["stage_total"] = round(time.perf_counter() - t0, 3)
        w.report = report
    if viewer.enabled:  # rmbuild.stages.view is imported only when viewing
        from rmbuild.stages.view import log_workspace

        log_workspace(ws, viewer)
    return report


#: slam's progress phases -> (what the bar says, unit of its count)
PHASE_NAMES = {"pair_search": ("searching Wi-Fi vicinity pairs", "scans"), "init": ("placing walks", ""),
               "solve": ("Levenberg-Marquardt", "iterations")}


def _progress_adapter(progress: Progress, viewer: Viewer):
    """slam's ``progress(phase, info)`` callback -> the stage's progress: scans searched for pairs (of the
    total), walks placed before the RF check (of all), LM iterations of each solve with the cost."""
    state: dict[str, Any] = {"phase": None, "done": 0, "iter": 0, "solve": None, "solve_iter": 0}

    def on_progress(phase: str, info: dict) -> None:
        name, unit = PHASE_NAMES.get(phase, (phase, ""))
        if phase != state["phase"]:
            state.update(phase=phase, done=0)
            total = info.get("total") if phase == "pair_search" else None
            progress.phase(name, total, unit)
        if phase == "pair_search" and "done" in info:
            progress.advance(int(info["done"]) - state["done"])
            state["done"] = int(info["done"])
        elif phase == "init":
            progress.message(f"{info.get('linked')} of {info.get('walks')} walks placed (before the RF check)")
        elif phase == "solve" and "cost_after" in info:
            state["iter"] += 1
            viewer.log_cost(state["iter"], float(info["cost_after"]))
            progress.advance()
            if info.get("outer") != state["solve"]:  # "outer" counts solves from 0
                state.update(solve=info.get("outer"), solve_iter=0)
            state["solve_iter"] += 1
            progress.message(f"solve {int(state['solve'] or 0) + 1}, iteration {state['solve_iter']}: "
                             f"cost {info['cost_after']:.4g}")

    return on_progress


def _floor_plan(ws: Workspace, cfg: OptimizeConfig, ds) -> tuple[FloorPlan | None, dict | None]:
    """The workspace's floor plan (None when it has none or the config says not to use it), and the check of
    its frame against the data's fixes (:func:`rmbuild.io.floorplan.check_plan_frame`); a plan in another
    frame than the fixes is not used (warned)."""
    if not cfg.floorplan.use or not ws.exists("data.floorplan"):
        return None, None
    from rmbuild.floorplan import from_local_geojson  # shapely: imported only when a plan is used
    from rmbuild.io.floorplan import check_plan_frame

    doc = ws.read_json("data.floorplan")
    fixes = ds.fixes[["x_m", "y_m"]].to_numpy(float) if ds.fixes is not None and len(ds.fixes) else np.empty((0, 2))
    check = check_plan_frame(doc, fixes)
    if check is not None and check["wrong_frame"]:
        check["warning"] += "; the plan is not used (the map stays in the reference walk's frame)"
        log.warning(check["warning"])
        return None, check
    return from_local_geojson(doc), check


def _num(m: dict | None, key: str) -> float | None:
    v = (m or {}).get(key)
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def metrics_text(m: dict | None) -> str:
    """The figures of one METRICS block that could be computed, e.g. "ATE rmse 1.20 m, landmark error
    mean 1.04 m (max 1.45, 30 fixes), heading error mean 1.60 deg"; "" when none could."""
    m = m or {}
    parts = []
    if (ate := _num(m.get("ate_m"), "rmse")) is not None:
        parts.append(f"ATE rmse {ate:.2f} m")
    lm = m.get("landmark_error_m")
    if (mean := _num(lm, "mean")) is not None:
        n = (lm or {}).get("n")
        parts.append(f"landmark error mean {mean:.2f} m (max {_num(lm, 'max') or 0:.2f}"
                     + (f", {n} fixes)" if n else ")"))
    if (hd := _num(m.get("heading_alignment_error_deg"), "mean")) is not None:
        parts.append(f"heading error mean {hd:.2f} deg")
    return ", ".join(parts)


def frame_text(r: dict) -> str:
    """Where the optimised map sits, in plain words (the report's "gauge")."""
    g = r.get("gauge")
    if g == "anchors":
        return "map frame: the building's (fixed by the anchors)"
    if g == "floorplan":
        return "map frame: the building's (fitted to the floor plan)"
    ref = r.get("reference_walk")
    return (f"map frame: that of walk {ref}" if ref else "map frame: that of the reference walk") + \
        " (not tied to the building: no anchors, no floor plan used)"
