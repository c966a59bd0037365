"""`rmbuild build`: the whole pipeline in one command (docs/scale-out.md).

ingest (in this process) → per floor, as one task each (:mod:`rmbuild.stages.floor_task`): optimize,
export-map, evaluate when the floor has ground truth, report → the building's reports (this process, under
the building's lock, once every floor is done). The floors run in this process one after the other
(``serial``) or as Dask tasks (:mod:`rmbuild.stages.dask_run`); a failed floor is reported with its error
and does not stop the others.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from rmbuild.config import to_toml
from rmbuild.config.build import parse_scheduler
from rmbuild.errors import RmbuildError, one_line
from rmbuild.io.atomic import write_json_atomic, write_text_atomic
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import Workspace, building_floors, building_report_path, check_output_file
from rmbuild.stages.building import building_page, building_report
from rmbuild.stages.common import Progress, ensure_progress
from rmbuild.stages.dask_run import run_tasks
from rmbuild.stages.floor_task import TASK_SECTIONS, run_floor

log = logging.getLogger(__name__)

#: the config sections `build` uses (one table each in a config file)
SECTIONS = ("ingest", "pdr", *TASK_SECTIONS, "build")
#: building report per floor-task stage: (command, stage whose floor reports it gathers)
BUILDING_REPORTS = (("optimize", "optimize"), ("export-map", "map"), ("evaluate", "evaluate"))


class FloorsFailedError(RmbuildError):
    """Some floors failed (each reported with its error); the others completed (exit code 2)."""

    exit_code = 2


def run(inputs: list[str | Path], workspace: str | Path, cfgs: dict[str, Any], fmt: str | None = None,
        force: bool = False, floorplan: str | Path | None = None, progress: Progress | None = None,
        on_cluster: Any = None) -> dict:
    """Ingest ``inputs`` into ``workspace`` and run every floor's stages; ``cfgs``: section -> config of
    each of :data:`SECTIONS`. Returns the build report (:func:`run_floors_as_tasks`) with ``ingest``."""
    from rmbuild.stages import ingest

    t0 = time.perf_counter()
    parse_scheduler(cfgs["build"].scheduler)
    Path(workspace).resolve().parent.mkdir(parents=True, exist_ok=True)  # the lock lives beside the workspace
    with workspace_lock(workspace, "build"):
        summary = ingest.run(inputs, workspace, cfgs["ingest"], fmt=fmt, force=force, progress=progress,
                             pdr_cfg=cfgs["pdr"], floorplan=floorplan)
        out = run_floors_as_tasks(workspace, cfgs, force, progress, on_cluster)
    out["ingest"] = summary
    out["time_s"]["ingest"] = _seconds((summary.get("building") or summary).get("time_s"))
    out["time_s"]["total"] = round(time.perf_counter() - t0, 3)
    if out["building"]:
        write_json_atomic(building_report_path(workspace, "build"), out)
    return out


def run_floors_as_tasks(workspace: str | Path, cfgs: dict[str, Any], force: bool = False,
                        progress: Progress | None = None, on_cluster: Any = None) -> dict:
    """Every floor of an ingested workspace (a single-floor workspace: itself) as one task, then the
    building's reports. Returns {"stage": "build", "scheduler", "floors": {name: task result},
    "failed": {name: error}, "building": bool, "time_s"}."""
    progress = ensure_progress(progress)
    sched = parse_scheduler(cfgs["build"].scheduler)
    floors = building_floors(workspace)
    targets = floors if floors is not None else {Path(workspace).name: Path(workspace)}
    texts = {s: to_toml(cfgs[s], s) for s in TASK_SECTIONS}
    items = {n: (n, str(p), texts, force) for n, p in targets.items()}
    progress.phase(f"floors ({cfgs['build'].scheduler})", len(items), "floors")

    def done(name: str, r: dict) -> None:
        progress.advance()
        progress.message(f"floor {name} {'done' if r.get('ok') else 'failed'}")

    t0 = time.perf_counter()
    with workspace_lock(workspace, "build"):
        index = check_output_file(Workspace(workspace).path("report.html"), force, "report") if floors else None
        results = run_tasks(run_floor, items, sched, done, cfgs["build"].worker_memory_gb, on_cluster)
        t_tasks = time.perf_counter() - t0
        for name, r in results.items():
            for w in r.get("warnings", []):
                log.warning(f"floor {name}: {w}" if floors else w)
        if floors is not None and index is not None:
            progress.phase("building reports")
            _building_reports(workspace, results, cfgs["evaluate"], index)
    return {"stage": "build", "scheduler": cfgs["build"].scheduler, "floors": results,
            "failed": {n: r["error"] for n, r in results.items() if not r.get("ok")},
            "building": floors is not None,
            "time_s": {"floors": round(t_tasks, 3), "building_reports": round(time.perf_counter() - t0 - t_tasks, 3)}}


def _seconds(t: Any) -> float:
    """A report's time: a number, or the "total" of a dict of times."""
    v = t.get("total") if isinstance(t, dict) else t
    return round(float(v), 3) if isinstance(v, int | float) else 0.0


def _building_reports(workspace: str | Path, results: dict[str, dict], eval_cfg: Any, index: Path) -> None:
    """building/<command>.json of each stage some floor ran now, and the page linking the floors' reports."""
    from rmbuild.stages.floor_eval import floor_totals

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
