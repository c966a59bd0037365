"""Buildings: run a stage on every floor of a building workspace (or on the one ``--floor`` names) and
write the building-level report (each floor's report under ``floors``, totals under ``building``).

Each floor is a whole single-floor workspace (:mod:`rmbuild.io.workspace`), so a stage runs on it
exactly as on a workspace of its own: a floor's figures equal a single-floor run's.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rmbuild.errors import InputError
from rmbuild.io.atomic import write_json_atomic
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import Workspace, building_floors, building_report_path

log = logging.getLogger(__name__)

#: per stage: the report keys summed over the floors for the building totals
SUMMED = {
    "ingest": ("walks", "poses", "readings", "scans", "nodes_with_fingerprint"),
    "optimize": ("walks", "poses", "poses_solved"),
    "map": ("cells", "cells_interpolated", "reference_nodes"),
    "evaluate": ("n_queries", "n_scored"),
}


def floor_workspaces(workspace: str | Path, floor: str | None) -> dict[str, Path] | None:
    """The floors to run a stage on (name -> workspace directory): every floor of a building, or the one
    ``floor`` names; None for a single-floor workspace (``floor`` must then be None)."""
    floors = building_floors(workspace)
    if floors is None:
        if floor is not None:
            raise InputError(f"--floor {floor}: {workspace} is a single-floor workspace")
        return None
    if floor is None:
        return floors
    if floor not in floors:
        raise InputError(f"--floor: no floor {floor!r} in {workspace} (floors: {', '.join(floors)})")
    return {floor: floors[floor]}


def run_floors(workspace: str | Path, command: str, floors: dict[str, Path],
               fn: Callable[[str, Path], dict], stage: str | None = None,
               totals: Callable[[Path, dict[str, dict]], dict] | None = None, exclusive: bool = True,
               summaries: bool = False) -> dict:
    """Run ``fn(name, floor_dir)`` on each of ``floors``, then write and return the building report of
    ``stage`` (its reports over every floor that has one, not only those run now). ``summaries``: for the
    commands without a stage directory (view, report): return what ``fn`` returned per floor, write nothing."""
    with workspace_lock(workspace, command, exclusive):
        out = {}
        for name, path in floors.items():
            log.info(f"floor {name}")
            out[name] = fn(name, path)
        if summaries:
            return {"stage": command, "floors": out, "ran_floors": list(floors)}
        report = building_report(workspace, command, stage or command)
        report["ran_floors"] = list(floors)
        if totals is not None:
            report["building"].update(totals(Path(workspace), report["floors"]))
        write_json_atomic(building_report_path(workspace, command), report)
    return report


def building_report(workspace: str | Path, command: str, stage: str) -> dict:
    """Each floor's current report of ``stage`` and their totals (reports are read, checksums verified)."""
    reports: dict[str, dict] = {}
    for name, path in (building_floors(workspace) or {}).items():
        r = Workspace.open(path).read_report(stage)
        if r is not None:
            reports[name] = r
    tot: dict[str, Any] = {"floors": len(reports)}
    for k in SUMMED.get(stage, ()):
        vals = [r.get(k) for r in reports.values()]
        if any(isinstance(v, int | float) for v in vals):
            tot[k] = sum(v for v in vals if isinstance(v, int | float))
    tot["time_s"] = round(sum(_total_time(r) for r in reports.values()), 3)
    if stage == "optimize":
        from rmbuild.stages.building.frames import floor_frames

        frames = floor_frames(workspace)
        if frames is not None:
            tot["floor_frames"] = frames
    return {"stage": command, "floors": reports, "building": tot}


def _total_time(r: dict) -> float:
    t = r.get("time_s")
    if isinstance(t, int | float):
        return float(t)
    if isinstance(t, dict):
        v = t.get("stage_total", t.get("total"))
        return float(v) if isinstance(v, int | float) else 0.0
    return 0.0


def no_viewer_for_building(viewer: Any, floors: dict[str, Path]) -> None:
    """A stage's --rerun recording holds one floor: with several, ask for one."""
    if getattr(viewer, "enabled", False) and len(floors) > 1:
        raise InputError("--rerun records one floor: pick it with --floor NAME (or `rmbuild view` the building)")


def building_page(workspace: str | Path, reports: dict[str, dict], index: Path) -> str:
    """The building's page (:func:`rmbuild.viz.report.building_html`): per floor its figures from each stage's
    building report and a link to its own report (``reports``: floor -> what `report` returned for it, with
    its "path"), each floor's evaluation table, the floors skipped and the floor classification."""
    import os

    from rmbuild.viz.report import building_html

    stages = {s: _read_building(workspace, cmd) for s, cmd in (("ingest", "ingest"), ("optimize", "optimize"),
                                                                ("map", "export-map"), ("evaluate", "evaluate"))}
    floors = {}
    for name in building_floors(workspace) or {}:
        link = os.path.relpath(reports[name]["path"], index.parent) if name in reports else None
        floors[name] = (link, {s: (rep.get("floors") or {}).get(name) for s, rep in stages.items()})
    ev = stages["evaluate"].get("building") if stages["evaluate"] else None
    return building_html(f"rmbuild building {Path(workspace).name}", floors, ev)


def _read_building(workspace: str | Path, command: str) -> dict:
    """A stage's building report ({} when absent or unreadable)."""
    p = building_report_path(workspace, command)
    try:
        return json.loads(p.read_text()) if p.is_file() else {}
    except (OSError, ValueError, RecursionError):  # unreadable, malformed or absurdly nested: no figures
        return {}
