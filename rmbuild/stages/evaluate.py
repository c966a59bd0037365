"""`rmbuild evaluate`: localize held-out walks with the built, surveyed and raw maps; errors vs truth."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config import EvaluateConfig, MapConfig, load_stage_config_text, to_toml
from rmbuild.errors import InputError
from rmbuild.io.workspace import Workspace
from rmbuild.radiomap import devices
from rmbuild.stages.building import floor_workspaces, no_viewer_for_building
from rmbuild.stages.common import Progress, ensure_progress, locked_workspace
from rmbuild.stages.mapping import built_positions
from rmbuild.stages.view import log_workspace
from rmbuild.viz.figures import cdf_figure
from rmbuild.viz.viewer import Viewer, ensure_viewer

log = logging.getLogger(__name__)


def run(
    workspace: str | Path,
    cfg: EvaluateConfig,
    map_cfg: MapConfig | None = None,
    test_walks: list[str] | None = None,
    progress: Progress | None = None,
    force: bool = False,
    viewer: Viewer | None = None,
    floor: str | None = None,
) -> tuple[dict, str]:
    """Evaluate; returns (the evaluate report, a short text table). ``map_cfg`` None: the config export-map
    ran with (the defaults when it has not run). A building: every floor (or the one ``floor`` names), then
    the floor classification of the test scans (:mod:`rmbuild.stages.building.evaluate`)."""
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        from rmbuild.stages.building.evaluate import run_building

        no_viewer_for_building(viewer, floors)
        if test_walks and len(floors) > 1:
            raise InputError("--test-walks name one floor's walks: pick the floor with --floor NAME")
        return run_building(workspace, floors, cfg, lambda p: run(p, cfg, map_cfg, test_walks, progress, force,
                                                                  viewer))
    with locked_workspace(workspace, "evaluate") as ws:
        if map_cfg is None:
            map_cfg = map_config_of(ws)
        return _run(ws, cfg, map_cfg, test_walks, ensure_progress(progress), force, ensure_viewer(viewer))


def map_config_of(ws: Workspace) -> MapConfig:
    """The [map] config export-map ran with in ``ws`` (defaults when it has not run)."""
    text = ws.read_config_text("map")
    if text is None:
        return MapConfig()
    return load_stage_config_text("map", text, str(ws.path("map.config")))


def _progress_adapter(progress: Progress):
    """evaluate's ``progress(phase, info)`` -> one phase counting test scans localized over every map and
    localizer, with a status naming the last localizer and its rate (SLAC and the particle filters are slow)."""

    def on_progress(phase: str, info: dict) -> None:
        if phase == "maps":
            progress.phase(f"localizing with {info['maps']} maps", info["total"], "scans")
        elif phase == "localize_start":
            progress.message(f"{info['map']} / {info['localizer']}: localizing {info['scans']} scans")
        elif phase == "localize":
            progress.advance(info["scans"])
            rate = info["scans"] / info["time_s"] if info["time_s"] > 0 else float("inf")
            progress.message(f"{info['map']} / {info['localizer']}: {info['scans']} scans in {info['time_s']:.1f} s "
                             f"({rate:.0f} scans/s)")
            log.info(f"evaluate: {info['map']} map, {info['localizer']}: {info['scans']} scans in "
                     f"{info['time_s']:.1f} s ({rate:.0f} scans/s)")

    return on_progress


def _run(ws: Workspace, cfg: EvaluateConfig, map_cfg: MapConfig, test_walks: list[str] | None, progress: Progress,
         force: bool, viewer: Viewer) -> tuple[dict, str]:
    from rmbuild.evaluate.localization import evaluate

    t0 = time.perf_counter()
    ds = ws.read_dataset()
    fp = ws.read_fingerprints()
    xy, info = built_positions(ws, ds, map_cfg)
    ds = devices.corrected(ds, info["device_offsets_db"])  # maps and queries in the reference phone's scale
    if test_walks:
        known = set(ds.walks["walk_id"].astype(str))
        unknown = [w for w in test_walks if w not in known]
        if unknown:
            raise InputError(f"--test-walks: unknown walk {unknown[0]!r}")
    from rmbuild.localize.base import localizer_class

    for name in cfg.localizers:
        localizer_class(name)  # an unknown name fails before anything runs
    ws.check_can_write("evaluate", force)
    progress.phase("building the built / surveyed / raw maps")
    res = evaluate(ds, fp, xy, cfg, test_walks=test_walks, gauge=info["gauge"], map_cfg=map_cfg,
                   progress=_progress_adapter(progress))
    report = {"stage": "evaluate", **res.to_json(), "built_map_frame": info}
    report["time_s"] = {"total": round(time.perf_counter() - t0, 3)}
    q = res.query
    rows = []
    for mname, d in res.predictions.items():
        for lname, p in d.items():
            err = res.errors.get(mname, {}).get(lname)
            rows.append(pd.DataFrame({
                "map": mname, "localizer": lname, "walk_id": q.walk_id.astype(str), "t_s": q.t_s,
                "x_est_m": p[:, 0], "y_est_m": p[:, 1],
                "x_true_m": res.query_ref_xy[:, 0], "y_true_m": res.query_ref_xy[:, 1],
                "error_m": err if err is not None else np.full(len(q), np.nan),
            }))
    tracks = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()
    progress.phase("writing tracks, errors, CDF")
    with ws.writing("evaluate") as w:
        w.table("evaluate.tracks", tracks)
        if len(tracks):
            w.table("evaluate.errors", tracks[["map", "localizer", "walk_id", "t_s", "error_m"]])
        w.figure("evaluate.cdf_png", cdf_figure(res.errors_by_label(), f"localization error CDF, "
                                                f"{len(res.test_walks)} test walks; {res.frame_note()}"))
        w.config(to_toml(cfg, "evaluate") + "\n" + to_toml(map_cfg, "map"))
        w.report = report
    log_workspace(ws, viewer)
    return report, res.table()
