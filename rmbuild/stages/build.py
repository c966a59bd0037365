"""`rmbuild build`: the whole pipeline in one command (docs/scale-out.md).

ingest (in this process) → per floor, as one task each (:mod:`rmbuild.stages.floor_task`): optimize,
export-map, evaluate when the floor has ground truth, report → the building's reports (this process, under
the building's lock, once every floor is done). The floors run in this process one after the other
(``serial``) or as Dask tasks (:mod:`rmbuild.stages.dask_run`); a failed floor is reported with its error
and does not stop the others. ``--venues``: every venue's ingest is a task too, then the floors of all
venues are one round of tasks.
"""

from __future__ import annotations

import logging
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from rmbuild.config import load_stage_config, to_toml
from rmbuild.config.build import parse_scheduler
from rmbuild.errors import RmbuildError, one_line
from rmbuild.io.atomic import write_json_atomic
from rmbuild.io.lock import workspace_lock
from rmbuild.io.venues import Venue
from rmbuild.io.workspace import (
    Workspace,
    building_floors,
    building_report_path,
    check_output_file,
    check_replaceable,
)
from rmbuild.stages.common import Progress, ensure_progress
from rmbuild.stages.dask_run import Runner, executor
from rmbuild.stages.floor_task import (
    TASK_SECTIONS,
    building_reports_task,
    ingest_venue,
    run_floor,
    write_building_reports,
)

log = logging.getLogger(__name__)

#: the config sections `build` uses (one table each in a config file)
SECTIONS = ("ingest", "pdr", *TASK_SECTIONS, "build")


class FloorsFailedError(RmbuildError):
    """Some floors or venues failed (each reported with its error); the others completed (exit code 2)."""

    exit_code = 2


def run(inputs: list[str | Path], workspace: str | Path, cfgs: dict[str, Any], fmt: str | None = None,
        force: bool = False, floorplan: str | Path | None = None, progress: Progress | None = None,
        on_cluster: Any = None) -> dict:
    """Ingest ``inputs`` into ``workspace`` and run every floor's stages; ``cfgs``: section -> config of
    each of :data:`SECTIONS`. Returns the build report (:func:`run_floors_as_tasks`) with ``ingest``."""
    from rmbuild.stages import ingest

    t0 = time.perf_counter()
    sched = parse_scheduler(cfgs["build"].scheduler)
    Path(workspace).resolve().parent.mkdir(parents=True, exist_ok=True)  # the lock lives beside the workspace
    with ExitStack() as stack:
        stack.enter_context(workspace_lock(workspace, "build"))
        # a cluster given by its address is reached first: unreachable, nothing is written
        runner = stack.enter_context(executor(sched, None, cfgs["build"].worker_memory_gb, on_cluster)) \
            if sched.kind == "address" else None
        summary = ingest.run(inputs, workspace, cfgs["ingest"], fmt=fmt, force=force, progress=progress,
                             pdr_cfg=cfgs["pdr"], floorplan=floorplan)
        out = run_floors_as_tasks(workspace, cfgs, force, progress, on_cluster, runner)
    out["ingest"] = summary
    out["time_s"]["ingest"] = _seconds((summary.get("building") or summary).get("time_s"))
    out["time_s"]["total"] = round(time.perf_counter() - t0, 3)
    if out["building"]:
        write_json_atomic(building_report_path(workspace, "build"), out)
    return out


def run_floors_as_tasks(workspace: str | Path, cfgs: dict[str, Any], force: bool = False,
                        progress: Progress | None = None, on_cluster: Any = None, runner: Runner | None = None) -> dict:
    """Every floor of an ingested workspace (a single-floor workspace: itself) as one task (on ``runner``,
    else on the configured scheduler), then the building's reports. Returns {"stage": "build", "scheduler",
    "floors": {name: task result}, "failed": {name: error}, "building": bool, "time_s"}."""
    progress = ensure_progress(progress)
    sched = parse_scheduler(cfgs["build"].scheduler)
    items, index = _floor_items(workspace, cfgs, force)
    t0 = time.perf_counter()
    with ExitStack() as stack:
        stack.enter_context(workspace_lock(workspace, "build"))
        if runner is None or len(items) <= 1:  # one floor (a single-floor workspace): in this process
            runner = stack.enter_context(executor(sched, len(items), cfgs["build"].worker_memory_gb, on_cluster))
        results = _run_round(runner, run_floor, items, progress, f"floors ({cfgs['build'].scheduler})", "floors")
        t_tasks = time.perf_counter() - t0
        out = _finish(workspace, results, cfgs, index, progress)
    out["time_s"] = {"floors": round(t_tasks, 3), "building_reports": round(time.perf_counter() - t0 - t_tasks, 3)}
    return out


def run_venues(venues: list[Venue], out_dir: str | Path, cfgs: dict[str, Any], force: bool = False,
               progress: Progress | None = None, on_cluster: Any = None) -> dict:
    """Build every venue into ``out_dir/<name>``: the venues' ingests as one round of tasks, then all their
    floors as another; each venue's config is its own file's (``config``) or ``cfgs``. Returns
    {"stage": "build", "venues": {name: venue build report}, "failed": {"venue[/floor]": error}, "time_s"}."""
    progress = ensure_progress(progress)
    t0 = time.perf_counter()
    sched = parse_scheduler(cfgs["build"].scheduler)
    vcfgs = {v.name: _venue_configs(v, cfgs) for v in venues}
    wss = {v.name: Path(out_dir) / v.name for v in venues}
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    for ws in wss.values():  # nothing is replaced without --force, and nothing runs when one would be
        check_replaceable(ws, force)
    ing_items = {v.name: (v.name, [str(p) for p in v.inputs], str(wss[v.name]),
                          {s: to_toml(vcfgs[v.name][s], s) for s in ("ingest", "pdr")}, v.format, force,
                          str(v.floorplan) if v.floorplan else None) for v in venues}
    with executor(sched, None, cfgs["build"].worker_memory_gb, on_cluster) as runner:
        ingested = _run_round(runner, ingest_venue, ing_items, progress, "ingest", "venues")
        t_ingest = time.perf_counter() - t0
        ok = [n for n, r in ingested.items() if r.get("ok")]
        for n in ok:
            for w in ingested[n]["warnings"]:
                log.warning(f"venue {n}: {w}")
        venues_out, not_run = _venue_floors(runner, {n: wss[n] for n in ok}, vcfgs, force, progress)
    failed_venues = {n: r["error"] for n, r in ingested.items() if not r.get("ok")} | not_run
    failed = dict(failed_venues)
    for n, rep in venues_out.items():
        rep["ingest"] = ingested[n]["ingest"]
        failed.update({f"{n}/{f}": e for f, e in rep["failed"].items()})
    return {"stage": "build", "scheduler": cfgs["build"].scheduler, "venues": venues_out,
            "failed_venues": failed_venues, "failed": failed,
            "time_s": {"ingest": round(t_ingest, 3), "total": round(time.perf_counter() - t0, 3)}}


def _venue_floors(runner: Runner, wss: dict[str, Path], vcfgs: dict[str, dict[str, Any]], force: bool,
                  progress: Progress) -> tuple[dict[str, dict], dict[str, str]]:
    """The floors of every ingested venue as one round of tasks (under each building's lock), then each
    venue's building reports: (venue name -> its build report, venue name -> why it did not run)."""
    not_run: dict[str, str] = {}
    with ExitStack() as locks:
        items: dict[str, tuple] = {}
        indexes: dict[str, Path | None] = {}
        for n, ws in list(wss.items()):
            try:
                vitems, indexes[n] = _floor_items(ws, vcfgs[n], force)
                if indexes[n] is not None:  # a building: its lock is the client's (a single floor's: its task's)
                    locks.enter_context(workspace_lock(ws, "build"))
            except RmbuildError as e:  # taken by another command since its ingest: this venue only
                not_run[n] = one_line(str(e))
                del wss[n]
                continue
            items.update({f"{n}/{f}": args for f, args in vitems.items()})
        t0 = time.perf_counter()
        results = _run_round(runner, run_floor, items, progress, "floors", "floors")
        t_tasks = time.perf_counter() - t0
        out: dict[str, dict] = {}
        reports: dict[str, tuple] = {}
        for n, ws in wss.items():
            mine = {k.split("/", 1)[1]: r for k, r in results.items() if k.split("/", 1)[0] == n}
            out[n] = _finish(ws, mine, vcfgs[n], None, progress, prefix=f"venue {n}: ")
            out[n]["building"] = indexes[n] is not None
            out[n]["time_s"] = {"floors_round": round(t_tasks, 3)}
            if indexes[n] is not None:  # the buildings' reports: one task each, under the client's locks
                reports[n] = (str(ws), mine, to_toml(vcfgs[n]["evaluate"], "evaluate"), str(indexes[n]))
        done = _run_round(runner, building_reports_task, reports, progress, "building reports", "venues")
        for n, r in done.items():
            for w in r.get("warnings", []):
                log.warning(f"venue {n}: {w}")
            if not r.get("ok"):
                out[n]["failed"]["building reports"] = r["error"]
            write_json_atomic(building_report_path(wss[n], "build"), out[n])
    return out, not_run


def _floor_items(workspace: str | Path, cfgs: dict[str, Any], force: bool) -> tuple[dict[str, tuple], Path | None]:
    """The floor tasks' arguments (floor name -> args of :func:`run_floor`) and, for a building, where its
    page linking the floors' reports goes (checked: not replaced without ``force``)."""
    floors = building_floors(workspace)
    targets = floors if floors is not None else {Path(workspace).name: Path(workspace)}
    texts = {s: to_toml(cfgs[s], s) for s in TASK_SECTIONS}
    index = check_output_file(Workspace(workspace).path("report.html"), force, "report") if floors else None
    return {n: (n, str(p), texts, force) for n, p in targets.items()}, index


def _run_round(runner: Runner, fn: Any, items: dict[str, tuple], progress: Progress, what: str,
               unit: str) -> dict[str, dict]:
    progress.phase(what, len(items), unit)

    def done(name: str, r: dict) -> None:
        progress.advance()
        progress.message(f"{name} {'done' if r.get('ok') else 'failed'}")

    return runner(fn, items, done)


def _finish(workspace: str | Path, results: dict[str, dict], cfgs: dict[str, Any], index: Path | None,
            progress: Progress, prefix: str = "") -> dict:
    """Log the floors' warnings, write a building's reports (``index`` None: none); the build report
    without times."""
    for name, r in results.items():
        for w in r.get("warnings", []):
            log.warning(f"{prefix}floor {name}: {w}" if index is not None else f"{prefix}{w}")
    if index is not None:
        progress.phase("building reports")
        write_building_reports(workspace, results, cfgs["evaluate"], index)
    return {"stage": "build", "scheduler": cfgs["build"].scheduler, "floors": results,
            "failed": {n: r["error"] for n, r in results.items() if not r.get("ok")}, "building": index is not None}


def _venue_configs(v: Venue, cfgs: dict[str, Any]) -> dict[str, Any]:
    """A venue's stage configs: its own config file's (over the defaults), else the run's."""
    if v.config is None:
        return cfgs
    own = {s: load_stage_config(s, v.config) for s in SECTIONS if s != "build"}
    return {**own, "build": cfgs["build"]}


def _seconds(t: Any) -> float:
    """A report's time: a number, or the "total" of a dict of times."""
    v = t.get("total") if isinstance(t, dict) else t
    return round(float(v), 3) if isinstance(v, int | float) else 0.0
