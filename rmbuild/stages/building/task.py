"""One floor's work in `rmbuild build`: optimize → export-map → evaluate (when it can be scored) → report,
on the floor's own workspace, as one task (:mod:`rmbuild.stages.dask_run`).

The task takes plain values (the floor's name and workspace path, each stage's config as TOML text) and
returns a plain dict, so that it runs alike in this process and in a Dask worker on another machine; the
stages write the floor's outputs through the workspace's atomic writers, as when run one by one.
"""

from __future__ import annotations

import logging
import os
import resource
import socket
import time
from pathlib import Path
from typing import Any

from rmbuild.config import load_stage_config_text
from rmbuild.errors import InputError, RmbuildError, one_line
from rmbuild.io.atomic import write_json_atomic, write_text_atomic
from rmbuild.io.workspace import Workspace, building_report_path
from rmbuild.stages.building import building_page, building_report
from rmbuild.stages.common import captured_warnings

#: the stage config sections a floor task needs (TOML text of each, as written next to outputs)
TASK_SECTIONS = ("optimize", "map", "evaluate")
#: building report per floor-task stage: (command, stage whose floor reports it gathers)
BUILDING_REPORTS = (("optimize", "optimize"), ("export-map", "map"), ("evaluate", "evaluate"))


def run_floor(name: str, path: str, configs: dict[str, str], force: bool) -> dict:
    """Run the floor's stages; returns {"floor", "ok", "stages": {stage: summary}, "evaluate_skipped",
    "warnings", "time_s", "peak_rss_mb", "worker"}. Raises what a stage raises (the caller reports it)."""
    from rmbuild.stages import evaluate, export_map, optimize, report

    t0 = time.perf_counter()
    cfg = {s: load_stage_config_text(s, configs[s], f"[{s}] config of the build") for s in TASK_SECTIONS}
    stages: dict[str, dict] = {}
    with captured_warnings() as warnings:
        stages["optimize"] = _optimize_summary(optimize.run(path, cfg["optimize"], force=force))
        stages["export-map"] = _map_summary(export_map.run(path, cfg["map"], force=force))
        skip = why_no_evaluate(Workspace.open(path).read_report("ingest") or {})
        if skip is None:
            try:
                rep, _ = evaluate.run(path, cfg["evaluate"], cfg["map"], force=force)
                stages["evaluate"] = _evaluate_summary(rep)
            except InputError as e:  # too little ground truth to score: the map stands, unscored
                skip = f"evaluate: {e}"
                logging.getLogger(__name__).warning(f"not evaluated: {e}")
        r = report.run(path, force=force)
        stages["report"] = {"path": r["path"], "figures": r["figures"], "missing": r["missing"],
                            "time_s": r["time_s"]}
    return {"floor": name, "ok": True, "stages": stages, "evaluate_skipped": skip, "warnings": warnings,
            "time_s": round(time.perf_counter() - t0, 3),
            # the process' peak resident memory (a worker that ran several floors: the largest so far)
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def import_floor_modules() -> None:
    """Import what a floor task uses (run on a cluster's workers as they start, while the client ingests)."""
    import matplotlib.pyplot  # noqa: F401

    from rmbuild.stages import evaluate, export_map, optimize, report  # noqa: F401


def why_no_evaluate(ingest_report: dict) -> str | None:
    """Why a floor is not evaluated (None: it is): no ground truth to score against, or too few walks to
    hold one out."""
    if not ingest_report.get("has_truth_poses") and not ingest_report.get("fixes"):
        return "no ground truth (neither true paths nor position fixes)"
    if int(ingest_report.get("walks") or 0) < 2:
        return "a single walk: none to hold out for testing"
    return None


def _optimize_summary(r: dict) -> dict:
    opt = r.get("optimized") or {}
    return {"walks": r["walks"], "poses": r["poses"], "poses_solved": r.get("poses_solved", r["poses"]),
            "gauge": r.get("gauge"), "ate_rmse_m": (opt.get("ate_m") or {}).get("rmse"),
            "time_s": (r.get("time_s") or {}).get("stage_total")}


def _map_summary(r: dict) -> dict:
    return {"cells": r["cells"], "aps": r["aps"], "frame": r["frame"], "time_s": r["time_s"]["total"]}


def _evaluate_summary(r: dict) -> dict:
    """The mean error of each map and localizer (m), and the scans scored."""
    means = {m: {loc: s.get("mean") for loc, s in d.items()} for m, d in (r.get("maps") or {}).items()}
    return {"mean_error_m": means, "n_queries": r.get("n_queries"), "time_s": r["time_s"]["total"]}


def ingest_venue(name: str, inputs: list[str], workspace: str, configs: dict[str, str], fmt: str | None,
                 force: bool, floorplan: str | None) -> dict:
    """`rmbuild ingest` of one venue (a task of `build --venues`); returns {"venue", "ok", "ingest" (the
    ingest report), "warnings", "time_s"}."""
    from rmbuild.stages import ingest

    t0 = time.perf_counter()
    cfg = {s: load_stage_config_text(s, configs[s], f"[{s}] config of venue {name}") for s in ("ingest", "pdr")}
    with captured_warnings() as warnings:
        report = ingest.run(list(inputs), workspace, cfg["ingest"], fmt=fmt, force=force, pdr_cfg=cfg["pdr"],
                            floorplan=floorplan)
    return {"venue": name, "ok": True, "ingest": report, "warnings": warnings,
            "time_s": round(time.perf_counter() - t0, 3)}


def building_reports_task(workspace: str, results: dict[str, dict], evaluate_toml: str, index: str) -> dict:
    """:func:`write_building_reports` as a task of `build --venues` (its caller holds the building's lock)."""
    cfg = load_stage_config_text("evaluate", evaluate_toml, "[evaluate] config of the build")
    with captured_warnings() as warnings:
        write_building_reports(workspace, results, cfg, Path(index))
    return {"ok": True, "warnings": warnings}


def write_building_reports(workspace: str | Path, results: dict[str, dict], eval_cfg: Any, index: Path) -> None:
    """building/<command>.json of each stage some floor ran now, and the page linking the floors' reports."""
    from rmbuild.stages.building.evaluate import floor_totals

    log = logging.getLogger(__name__)
    ok = {n: r for n, r in results.items() if r.get("ok")}
    for command, stage in BUILDING_REPORTS:
        ran = [n for n, r in ok.items() if command in r["stages"]]
        if not ran:
            continue
        report = building_report(workspace, command, stage)
        report["ran_floors"] = ran
        if command == "evaluate":
            try:
                report["building"].update(floor_totals(Path(workspace), report["floors"], eval_cfg))
            except RmbuildError as e:  # classifying needs every floor's data: a broken floor stops only this
                report["building"]["floor_classification_error"] = one_line(str(e))
                log.warning(f"building evaluate: no floor classification: {one_line(str(e))}")
        write_json_atomic(building_report_path(workspace, command), report)
    pages = {n: r["stages"]["report"] for n, r in ok.items()}
    write_text_atomic(index, building_page(workspace, pages, index))
