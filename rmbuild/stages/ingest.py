"""`rmbuild ingest`: read input files, validate, attach readings to pose nodes, write a new workspace."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from rmbuild.config import IngestConfig, PdrConfig, to_toml
from rmbuild.errors import InputError
from rmbuild.ingest_checks import evidence_warnings
from rmbuild.ingest_core import build_dataset
from rmbuild.io.floorplan import MIN_FIXES_INSIDE, fixes_inside_share, read_user_plan
from rmbuild.io.formats import choose_reader, expand_inputs
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import Workspace, check_replaceable, write_dataset
from rmbuild.stages.common import Progress, ensure_progress
from rmbuild.stages.view import log_workspace
from rmbuild.viz.viewer import Viewer, ensure_viewer

log = logging.getLogger(__name__)


def run(
    inputs: list[str | Path],
    workspace: str | Path,
    cfg: IngestConfig,
    fmt: str | None = None,
    force: bool = False,
    progress: Progress | None = None,
    pdr_cfg: PdrConfig | None = None,
    viewer: Viewer | None = None,
    floorplan: str | Path | None = None,
) -> dict:
    """Ingest ``inputs`` (files or directories) into a new workspace; returns the ingest report.

    ``pdr_cfg``: options of the raw-IMU formats (phone PDR, ILC/IPIN specifics); defaults when None.
    ``floorplan``: a GeoJSON floor plan (:func:`rmbuild.io.floorplan.read_user_plan`) in the frame of the
    data's fixes; it replaces a plan the input format carries.
    """
    plan = read_user_plan(floorplan) if floorplan is not None else None
    files = _input_files(inputs, workspace)
    Path(workspace).resolve().parent.mkdir(parents=True, exist_ok=True)  # the lock lives beside the workspace
    with workspace_lock(workspace, "ingest"):
        check_replaceable(Path(workspace), force)
        return _run(inputs, files, workspace, cfg, fmt, force, ensure_progress(progress), pdr_cfg or PdrConfig(),
                    ensure_viewer(viewer), plan)


def _input_files(inputs: list[str | Path], workspace: str | Path) -> list[Path]:
    """The input files; an input inside the workspace (which ingest replaces) is an error, and the files of
    a workspace that lies inside an input directory are not inputs."""
    ws_root = Path(workspace).resolve()
    for p in inputs:
        rp = Path(p).resolve()
        if rp == ws_root or ws_root in rp.parents:
            raise InputError(f"input lies inside the workspace {workspace}, which ingest replaces; move it out "
                             "or choose another -w", str(p))
    files = [f for f in expand_inputs(inputs) if ws_root not in f.resolve().parents]
    if not files:
        raise InputError("no input files found outside the workspace", ", ".join(map(str, inputs)))
    return files


def _run(inputs: list[str | Path], files: list[Path], workspace: str | Path, cfg: IngestConfig, fmt: str | None,
         force: bool, progress: Progress, pdr_cfg: PdrConfig, viewer: Viewer, plan: dict | None) -> dict:
    t0 = time.perf_counter()
    reader = choose_reader(files, fmt, pdr_cfg)
    progress.phase(f"reading {reader.name}", len(files), "files")
    counted = [0]

    def on_file(f: Path) -> None:
        counted[0] += 1
        progress.advance()

    reader.on_file = on_file
    raw = reader.read(files, cfg)
    progress.advance(len(files) - counted[0])  # readers that do not count files (or skip some) end at N / N
    t_read = time.perf_counter() - t0
    if raw.imu:  # the count is the PDR's; validating and attaching follow it in the same phase
        progress.phase("phone PDR, validating, attaching readings", len(raw.imu), "walks")
    else:
        progress.phase("validating and attaching readings")
    t1 = time.perf_counter()
    ds, fp, summary = build_dataset(raw, cfg, source=reader.name, pdr_cfg=pdr_cfg,
                                    on_walk=lambda w: progress.advance())
    progress.message(f"{len(ds.walks)} walks, {len(ds.poses):,} poses, {len(ds.wifi):,} Wi-Fi readings")
    summary["warnings"].extend(evidence_warnings(ds))
    plan = plan if plan is not None else raw.floorplan
    summary["floorplan"] = _plan_summary(plan, ds, summary["warnings"])
    t_build = time.perf_counter() - t1
    summary = {"stage": "ingest", "format": reader.name, "inputs": [str(p) for p in inputs], **summary}
    progress.phase("writing workspace")
    with Workspace.create(workspace, force=force) as w:
        write_dataset(w, ds, fp)
        if plan is not None:
            w.json("data.floorplan", plan)
        uses_pdr = reader.name != "rmbuild" or bool(raw.imu)
        w.config(to_toml(cfg, "ingest") + ("\n" + to_toml(pdr_cfg, "pdr") if uses_pdr else ""))
        summary["time_s"] = {"read": round(t_read, 3), "validate_attach": round(t_build, 3),
                             "total": round(time.perf_counter() - t0, 3)}
        w.report = summary
    for msg in summary["warnings"]:
        log.warning(msg)
    log_workspace(Workspace.open(workspace), viewer)
    return summary


def _plan_summary(plan: dict | None, ds, warnings: list[str]) -> dict | None:
    """What the report says of the floor plan; a warning when the fixes mostly fall outside it."""
    if plan is None:
        return None
    fixes = ds.fixes[["x_m", "y_m"]].to_numpy(float) if ds.fixes is not None and len(ds.fixes) else np.empty((0, 2))
    share = fixes_inside_share(plan, fixes)
    if share is not None and share < MIN_FIXES_INSIDE:
        warnings.append(f"floor plan: only {share:.0%} of the fixes lie in its walkable space (1 m tolerance); "
                        "is the plan in the fixes' frame?")
    return {"name": plan.get("name", ""), "fixes_inside": None if share is None else round(share, 3)}
