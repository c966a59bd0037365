"""`rmbuild build`: the whole pipeline in one command (docs/scale-out.md).

ingest (in this process) → per floor, as one task each (:mod:`rmbuild.stages.building.task`): optimize,
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

from rmbuild import __version__
from rmbuild.config import load_stage_config, to_toml
from rmbuild.config.build import parse_scheduler
from rmbuild.errors import RmbuildError, WorkspaceError, one_line
from rmbuild.io.atomic import write_json_atomic
from rmbuild.io.floorplan import plan_image_file
from rmbuild.io.lock import shared_while, workspace_lock
from rmbuild.io.venues import Venue
from rmbuild.io.workspace import (
    Workspace,
    building_floors,
    building_report_path,
    check_output_file,
    check_replaceable,
)
from rmbuild.stages.building.state import (
    STATE_VERSION,
    floor_is_current,
    hand_made,
    input_fingerprint,
    keeping_unchanged_floors,
    read_state,
    same_inputs,
    stage_records,
    write_state,
)
from rmbuild.stages.building.task import (
    TASK_SECTIONS,
    building_reports_task,
    import_floor_modules,
    ingest_venue,
    run_floor,
    write_building_reports,
)
from rmbuild.stages.common import Progress, ensure_progress
from rmbuild.stages.dask_run import Runner, executor

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
    each of :data:`SECTIONS`. Without ``force``, a workspace an earlier `build` made is brought up to date:
    unchanged inputs are not ingested again and unchanged floors not re-run (:mod:`rmbuild.stages.building.state`).
    Returns the build report (:func:`run_floors_as_tasks`) with ``ingest``."""
    t0 = time.perf_counter()
    sched = parse_scheduler(cfgs["build"].scheduler)
    Path(workspace).resolve().parent.mkdir(parents=True, exist_ok=True)  # the lock lives beside the workspace
    with ExitStack() as stack:
        stack.enter_context(workspace_lock(workspace, "build"))
        state = None if force else _previous_state(workspace)
        made = hand_made(workspace, state) if state is not None else []
        if made:
            raise WorkspaceError(f"{'; '.join(made)}: build would replace that with its own config; pass --force "
                                 "to rebuild it")
        # the floor plan's content (and its image's) is fingerprinted after the inputs
        settings = {"ingest": to_toml(cfgs["ingest"], "ingest"), "pdr": to_toml(cfgs["pdr"], "pdr"), "format": fmt,
                    "floorplan": floorplan is not None}
        fp = input_fingerprint([*inputs, *_plan_files(floorplan)], settings, (state or {}).get("inputs"))
        ingest_now = state is None or not same_inputs(state.get("inputs"), fp)
        runner = None
        if sched.kind == "address" or (sched.kind == "local" and ingest_now):
            # a cluster given by its address is reached first (unreachable: nothing is written); a local one
            # starts now, its workers importing what the floors need while this process ingests
            runner = stack.enter_context(executor(sched, None, cfgs["build"].worker_memory_gb, on_cluster,
                                                  warm=import_floor_modules))
        if ingest_now:
            state = _ingest(inputs, workspace, cfgs, fmt, floorplan, state, fp, force, progress, runner)
        else:
            log.info("inputs and ingest config unchanged since the last build: not ingested again")
        out = run_floors_as_tasks(workspace, cfgs, force, progress, on_cluster, runner, state=state)
    summary = (state or {})["ingest"]
    out["ingest"] = summary
    out["ingested"] = ingest_now
    out["time_s"]["ingest"] = _seconds((summary.get("building") or summary).get("time_s")) if ingest_now else 0.0
    out["time_s"]["total"] = round(time.perf_counter() - t0, 3)
    if out["building"]:
        write_json_atomic(building_report_path(workspace, "build"), out)
    return out


def _plan_files(floorplan: str | Path | None) -> list[Path]:
    """The plan file and the image it names (both part of what is ingested)."""
    if floorplan is None:
        return []
    image = plan_image_file(floorplan)
    return [Path(floorplan), *([image] if image is not None and image.is_file() else [])]


def _previous_state(workspace: str | Path) -> dict | None:
    """The build state of an existing workspace an earlier `build` made; None for a new (or empty)
    workspace; an error for any other existing workspace or directory (replaced only with ``--force``)."""
    state = read_state(workspace)
    if state is None:
        check_replaceable(Path(workspace), False)
    return state


def _ingest(inputs: list[str | Path], workspace: str | Path, cfgs: dict[str, Any], fmt: str | None,
            floorplan: str | Path | None, state: dict | None, fp: dict, force: bool, progress: Progress | None,
            runner: Runner | None = None) -> dict:
    """Ingest (again), keeping the outputs of the floors whose ingested data did not change; the new build
    state (written). On a ``runner`` the floor folders are read as tasks (:func:`rmbuild.stages.ingest.run`)."""
    from rmbuild.stages import ingest

    same_version = (state or {}).get("inputs", {}).get("rmbuild_version") == __version__
    with keeping_unchanged_floors(workspace, state if same_version else None) as kept:
        summary = ingest.run(inputs, workspace, cfgs["ingest"], fmt=fmt, force=force or state is not None,
                             progress=progress, pdr_cfg=cfgs["pdr"], floorplan=floorplan, runner=runner)
    if kept:
        log.info(f"ingested data unchanged on {len(kept)} floor(s), their outputs kept: {', '.join(sorted(kept))}")
    floors = {n: e for n, e in (state or {}).get("floors", {}).items() if n in kept}
    new = {"version": STATE_VERSION, "inputs": fp, "ingest": summary, "floors": floors}
    write_state(workspace, new)
    return new


def run_floors_as_tasks(workspace: str | Path, cfgs: dict[str, Any], force: bool = False,
                        progress: Progress | None = None, on_cluster: Any = None, runner: Runner | None = None,
                        state: dict | None = None) -> dict:
    """Every floor of an ingested workspace (a single-floor workspace: itself) as one task (on ``runner``,
    else on the configured scheduler), the largest floors first, then the building's reports. With the
    build ``state`` (kept up to date as floors finish), a floor that is current is not re-run: its previous
    result comes back with "reused": true. Returns {"stage": "build", "scheduler", "floors": {name: task
    result}, "failed": {name: error}, "building": bool, "time_s"}."""
    progress = ensure_progress(progress)
    sched = parse_scheduler(cfgs["build"].scheduler)
    items, index = _floor_items(workspace, cfgs, force or state is not None)
    reused = {} if force or state is None else \
        {n: {**state["floors"][n]["result"], "reused": True} for n, a in items.items()
         if floor_is_current(a[1], a[2], state["floors"].get(n))}
    todo = {n: (a[0], a[1], a[2], force or state is not None) for n, a in _largest_first(items).items()
            if n not in reused}
    t0 = time.perf_counter()
    with ExitStack() as stack:
        stack.enter_context(workspace_lock(workspace, "build"))
        if runner is None or len(todo) <= 1:  # one floor (a single-floor workspace): in this process
            runner = stack.enter_context(executor(sched, len(todo), cfgs["build"].worker_memory_gb, on_cluster))
        runner.fit(len(todo))
        if index is not None and not runner.in_process:
            # the floors' tasks lock their floors (and the building, shared): in worker processes they could
            # not while this one held the building exclusively
            stack.enter_context(shared_while(workspace))
        ran = _run_round(runner, run_floor, todo, progress, f"floors ({cfgs['build'].scheduler})", "floors",
                         _state_keeper(workspace, state, items)) if todo else {}
        t_tasks = time.perf_counter() - t0
        results = {n: reused.get(n) or ran[n] for n in items}
        out = _finish(workspace, results, cfgs, index, progress,
                      write=bool(ran) or not (index is not None and index.exists()))
    out["time_s"] = {"floors": round(t_tasks, 3), "building_reports": round(time.perf_counter() - t0 - t_tasks, 3)}
    return out


def _largest_first(items: dict[str, tuple]) -> dict[str, tuple]:
    """The floor tasks, the largest (most poses ingested) first: on N workers the longest floor starts at
    once instead of after shorter ones (the run ends with its longest chain of floors)."""
    def poses(args: tuple) -> int:
        try:
            return int((Workspace.open(args[1]).read_report("ingest") or {}).get("poses") or 0)
        except (RmbuildError, OSError, ValueError):
            return 0  # its task reports what is wrong

    return dict(sorted(items.items(), key=lambda kv: -poses(kv[1])))


def _state_keeper(workspace: str | Path, state: dict | None, items: dict[str, tuple]) -> Any:
    """A callback that records each finished floor in the build state (None without a state)."""
    if state is None:
        return None

    def keep(name: str, r: dict) -> None:
        if r.get("ok"):
            state["floors"][name] = {"configs": items[name][2], "result": r, "records": stage_records(items[name][1])}
        else:
            state["floors"].pop(name, None)
        write_state(workspace, state)

    return keep


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
        order: dict[str, list[str]] = {}
        for n, ws in list(wss.items()):
            try:
                vitems, indexes[n] = _floor_items(ws, vcfgs[n], force)
                if indexes[n] is not None:  # a building: its lock is the client's (a single floor's: its task's),
                    # shared while the floors' tasks run on the workers (they lock their floors and it, shared)
                    locks.enter_context(workspace_lock(ws, "build"))
                    locks.enter_context(shared_while(ws))
            except RmbuildError as e:  # taken by another command since its ingest: this venue only
                not_run[n] = one_line(str(e))
                del wss[n]
                continue
            items.update({f"{n}/{f}": args for f, args in vitems.items()})
            order[n] = list(vitems)
        t0 = time.perf_counter()
        results = _run_round(runner, run_floor, _largest_first(items), progress, "floors", "floors")
        t_tasks = time.perf_counter() - t0
        out: dict[str, dict] = {}
        reports: dict[str, tuple] = {}
        for n, ws in wss.items():
            mine = {f: results[f"{n}/{f}"] for f in order[n]}
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
               unit: str, also: Any = None) -> dict[str, dict]:
    progress.phase(what, len(items), unit)

    def done(name: str, r: dict) -> None:
        progress.advance()
        progress.message(f"{name} {'done' if r.get('ok') else 'failed'}")
        if also is not None:
            also(name, r)

    return runner(fn, items, done)


def _finish(workspace: str | Path, results: dict[str, dict], cfgs: dict[str, Any], index: Path | None,
            progress: Progress, prefix: str = "", write: bool = True) -> dict:
    """Log the warnings of the floors that ran, write a building's reports (``index`` None or not
    ``write``: none); the build report without times."""
    for name, r in results.items():
        for w in [] if r.get("reused") else r.get("warnings", []):
            log.warning(f"{prefix}floor {name}: {w}" if index is not None else f"{prefix}{w}")
    if index is not None and write:
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
