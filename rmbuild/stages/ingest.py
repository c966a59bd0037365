"""`rmbuild ingest`: read input files, validate, attach readings to pose nodes, write a new workspace."""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rmbuild.config import IngestConfig, PdrConfig, to_toml
from rmbuild.errors import InputError
from rmbuild.floorplan import from_local_geojson, image_extent_m
from rmbuild.ingest.checks import evidence_warnings
from rmbuild.ingest.core import build_dataset
from rmbuild.ingest.floors import floor_level, split_floors, whole_floor
from rmbuild.io.atomic import write_json_atomic
from rmbuild.io.floor_image import attach_image, check_extent, read_image, split_image
from rmbuild.io.floorplan import check_plan_frame, read_user_plan
from rmbuild.io.formats import choose_reader, expand_inputs
from rmbuild.io.formats.base import RawInput, Reader
from rmbuild.io.lock import workspace_lock
from rmbuild.io.workspace import StageWriter, Workspace, building_report_path, check_replaceable, write_dataset
from rmbuild.stages.building import building_report
from rmbuild.stages.common import Progress, captured_warnings, ensure_progress
from rmbuild.stages.view import log_workspace
from rmbuild.types import Dataset, Fingerprints
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
    floorplan_image: str | Path | None = None,
    image_extent: tuple[float, float, float, float] | None = None,
    runner: Any = None,
) -> dict:
    """Ingest ``inputs`` (files or directories) into a new workspace; returns the ingest report.

    ``pdr_cfg``: options of the raw-IMU formats (phone PDR, ILC/IPIN specifics); defaults when None.
    ``floorplan``: a GeoJSON floor plan (:func:`rmbuild.io.floorplan.read_user_plan`) in the frame of the
    data's fixes; it replaces a plan the input format carries. ``floorplan_image``: a raster image of the
    plan for display, over ``image_extent`` (:func:`rmbuild.floorplan.image_extent_m`; the plan's bounding
    box when None); it replaces an image the input format carries.
    """
    plan = read_user_plan(floorplan) if floorplan is not None else None
    image = None
    if floorplan_image is not None:
        extent = None if image_extent is None else check_extent(image_extent, "--floorplan-image-extent")
        image = (read_image(floorplan_image), extent)
    files = _input_files(inputs, workspace)
    Path(workspace).resolve().parent.mkdir(parents=True, exist_ok=True)  # the lock lives beside the workspace
    with workspace_lock(workspace, "ingest"):
        check_replaceable(Path(workspace), force)
        return _run(inputs, files, workspace, cfg, fmt, force, ensure_progress(progress), pdr_cfg or PdrConfig(),
                    ensure_viewer(viewer), plan, image, runner)


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
         force: bool, progress: Progress, pdr_cfg: PdrConfig, viewer: Viewer, plan: dict | None,
         image: tuple[bytes, list[float] | None] | None, runner: Any = None) -> dict:
    t0 = time.perf_counter()
    reader = choose_reader(files, fmt)
    groups = folder_groups(inputs, files) if runner is not None and reader.reads_folders_apart else None
    if groups is not None and plan is None and image is None:
        built = _read_folders_as_tasks(runner, groups, reader, cfg, pdr_cfg, progress)
        if built is not None:
            return _write_building(inputs, workspace, cfg, reader.name, force, progress, pdr_cfg, viewer, *built,
                                   t0, time.perf_counter() - t0)
    progress.phase(f"reading {reader.name}", len(files), "files")
    counted = [0]

    def on_file(f: Path) -> None:
        counted[0] += 1
        progress.advance()

    reader.on_file = on_file
    raw = reader.read(files, cfg)
    progress.advance(len(files) - counted[0])  # readers that do not count files (or skip some) end at N / N
    t_read = time.perf_counter() - t0
    cfg = pinned_origin(cfg, raw)
    floors = split_floors(raw)
    if floors is not None:
        if image is not None:
            raise InputError(f"--floorplan-image gives one image, but the input holds {len(floors)} floors "
                             f"({', '.join(floors)}); ingest them one floor at a time to give images")
        return _run_building(inputs, workspace, cfg, reader.name, force, progress, pdr_cfg, viewer, plan, raw,
                             floors, t0, t_read)
    if raw.imu:  # the count is the PDR's; validating and attaching follow it in the same phase
        progress.phase("phone PDR, validating, attaching readings", len(raw.imu), "walks")
    else:
        progress.phase("validating and attaching readings")
    t1 = time.perf_counter()
    ds, fp, summary, plan = _build(raw, cfg, reader.name, pdr_cfg, plan, image, on_walk=lambda w: progress.advance())
    progress.message(f"{len(ds.walks)} walks, {len(ds.poses):,} poses, {len(ds.wifi):,} Wi-Fi readings")
    t_build = time.perf_counter() - t1
    summary = {"stage": "ingest", "format": reader.name, "inputs": [str(p) for p in inputs], **summary}
    if raw.floor_name:  # the one floor the input names: its level numbers the floor as in a building
        summary["floor"] = raw.floor_name
    progress.phase("writing workspace")
    with Workspace.create(workspace, force=force) as w:
        _write(w, ds, fp, plan, cfg, pdr_cfg, reader.name != "rmbuild" or bool(raw.imu))
        summary["time_s"] = {"read": round(t_read, 3), "validate_attach": round(t_build, 3),
                             "total": round(time.perf_counter() - t0, 3)}
        w.report = summary
    for msg in summary["warnings"]:
        log.warning(msg)
    log_workspace(Workspace.open(workspace), viewer)
    return summary


def pinned_origin(cfg: IngestConfig, raw: RawInput) -> IngestConfig:
    """``cfg`` with the WGS84 origin the reader chose for the fixes' local frame (IPIN's first fix) made
    explicit, so that the config written beside the data reads later input (``ingest --append``,
    ``localize``) in the same frame; unchanged when the reader chose none."""
    if raw.enu_origin is None:
        return cfg
    lat, lon = raw.enu_origin
    return replace(cfg, ipin=replace(cfg.ipin, origin_lat_deg=lat, origin_lon_deg=lon))


def _build(raw: RawInput, cfg: IngestConfig, fmt: str, pdr_cfg: PdrConfig, plan: dict | None,
           image: tuple[bytes, list[float] | None] | None = None, on_walk=None
           ) -> tuple[Dataset, Fingerprints, dict, dict | None]:
    """Validate and attach one floor's input: (dataset, fingerprints, summary, the floor plan kept, with the
    user's ``image`` (PNG, extent) when given); ``on_walk(walk_id)`` after each walk's PDR."""
    plan = plan if plan is not None else raw.floorplan
    if image is not None:
        plan = _with_image(plan, *image)
    ds, fp, summary = build_dataset(raw, cfg, source=fmt, pdr_cfg=pdr_cfg, on_walk=on_walk)
    summary["warnings"].extend(evidence_warnings(ds))
    summary["floorplan"] = plan_summary(plan, ds, summary["warnings"])
    return ds, fp, summary, plan


def _with_image(plan: dict | None, png: bytes, extent: list[float] | None) -> dict:
    """``plan`` carrying the user's image ``png`` over ``extent`` (in the plan's own coordinates; None: its
    bounding box); InputError without a plan."""
    if plan is None:
        raise InputError("--floorplan-image needs a floor plan: give --floorplan, or an input that comes with "
                         "one (an MS ILC floor folder)")
    tup = None if extent is None else (extent[0], extent[1], extent[2], extent[3])
    return attach_image(plan, png, image_extent_m(from_local_geojson(plan), tup))


def _write(w: StageWriter, ds: Dataset, fp: Fingerprints, plan: dict | None, cfg: IngestConfig,
           pdr_cfg: PdrConfig, uses_pdr: bool) -> None:
    write_dataset(w, ds, fp)
    if plan is not None:
        plan, png = split_image(plan)
        w.json("data.floorplan", plan)
        if png is not None:
            w.binary("data.floor_image", png)
    w.config(to_toml(cfg, "ingest") + ("\n" + to_toml(pdr_cfg, "pdr") if uses_pdr else ""))


def _run_building(inputs: list[str | Path], workspace: str | Path, cfg: IngestConfig, fmt: str, force: bool,
                  progress: Progress, pdr_cfg: PdrConfig, viewer: Viewer, plan: dict | None, whole: RawInput,
                  floors: dict[str, RawInput], t0: float, t_read: float) -> dict:
    """Ingest an input of several floors into a building workspace: one floor workspace each."""
    if plan is not None:
        raise InputError(f"--floorplan gives one plan, but the input holds {len(floors)} floors "
                         f"({', '.join(floors)}); ingest them one floor at a time to give plans")
    built = {}
    for name, raw in floors.items():
        if raw.imu:
            progress.phase(f"floor {name}: phone PDR, validating, attaching readings", len(raw.imu), "walks")
        else:
            progress.phase(f"floor {name}: validating and attaching readings")
        built[name] = _build_floor(raw, cfg, fmt, pdr_cfg, on_walk=lambda w: progress.advance())
    info = {"skipped": dict(whole.skipped), "notes": list(whole.notes), "transitions": list(whole.transitions)}
    return _write_building(inputs, workspace, cfg, fmt, force, progress, pdr_cfg, viewer, built, info, t0, t_read)


def _build_floor(raw: RawInput, cfg: IngestConfig, fmt: str, pdr_cfg: PdrConfig, on_walk=None) -> tuple:
    """One floor of a building validated and attached: (dataset, fingerprints, its report without the
    inputs, its plan, whether the PDR configuration applies)."""
    t1 = time.perf_counter()
    ds, fp, summary, fplan = _build(raw, cfg, fmt, pdr_cfg, None, on_walk=on_walk)
    summary["time_s"] = {"validate_attach": round(time.perf_counter() - t1, 3)}
    return ds, fp, summary, fplan, fmt != "rmbuild" or bool(raw.imu)


def _write_building(inputs: list[str | Path], workspace: str | Path, cfg: IngestConfig, fmt: str, force: bool,
                    progress: Progress, pdr_cfg: PdrConfig, viewer: Viewer, built: dict[str, tuple], info: dict,
                    t0: float, t_read: float) -> dict:
    """Write the floors ``built`` (name -> :func:`_build_floor`) as a building workspace and its ingest report
    (``info``: what the reader said of the whole input: skipped, notes, transitions)."""
    progress.phase("writing workspace")
    with Workspace.create_building(workspace, {n: floor_level(n) for n in built}, force=force) as writers:
        for name, (ds, fp, summary, fplan, uses_pdr) in built.items():
            summary = {"stage": "ingest", "format": fmt, "inputs": [str(p) for p in inputs], "floor": name, **summary}
            built[name] = (ds, fp, summary, fplan, uses_pdr)
            _write(writers[name], ds, fp, fplan, cfg, pdr_cfg, uses_pdr)
            writers[name].report = summary
    report = building_report(workspace, "ingest", "ingest")
    bssids = set().union(*(set(ds.wifi["bssid"].astype(str)) for ds, *_ in built.values()))
    report["building"].update({"aps": len(bssids), "time_s": {"read": round(t_read, 3),
                                                               "total": round(time.perf_counter() - t0, 3)}})
    report.update({"format": fmt, "inputs": [str(p) for p in inputs], **info})
    write_json_atomic(building_report_path(workspace, "ingest"), report)
    for name, (*_, summary, _p, _u) in built.items():
        for msg in summary["warnings"]:
            log.warning(f"floor {name}: {msg}")
    if viewer.enabled:
        log.warning("--rerun: a building's floors are viewed one at a time (`rmbuild view --floor NAME`)")
    return report


def folder_groups(inputs: list[str | Path], files: list[Path]) -> list[list[Path]] | None:
    """The input files by floor folder: the files under each subfolder of an input directory (the first part
    of their path below it), in order; None when some file is not in such a folder (an input file, a file
    at the top of an input directory) or there is only one folder."""
    roots = [Path(p) for p in inputs]
    groups: dict[tuple[int, str], list[Path]] = {}
    for f in files:
        where = next(((i, f.relative_to(r).parts) for i, r in enumerate(roots) if r.is_dir() and r in f.parents),
                     None)
        if where is None or len(where[1]) < 2:
            return None
        groups.setdefault((where[0], where[1][0]), []).append(f)
    return list(groups.values()) if len(groups) > 1 else None


def _read_folders_as_tasks(runner: Any, groups: list[list[Path]], reader: Reader, cfg: IngestConfig,
                           pdr_cfg: PdrConfig, progress: Progress) -> tuple[dict[str, tuple], dict] | None:
    """Every floor folder read, validated and attached as one task on ``runner`` (:func:`read_floor_folder`):
    (floor name -> :func:`_build_floor`, what the reader said of the whole input: its notes with the summary
    notes of the summed tallies last, as one read of every file gives them); None when the folders do not
    hold one floor each (the caller reads them all at once). A folder whose input is wrong is the error."""
    size = [sum(f.stat().st_size for f in g) for g in groups]  # the largest folder first: it ends the round
    items = {str(i): ([str(f) for f in groups[i]], reader.name, to_toml(cfg, "ingest"), to_toml(pdr_cfg, "pdr"))
             for i in sorted(range(len(groups)), key=lambda i: -size[i])}
    progress.phase("reading, validating and attaching floor folders", len(items), "folders")
    ran = runner(read_floor_folder, items, lambda name, r: progress.advance())
    done = [ran[str(i)] for i in range(len(groups))]  # the floors in the order one read of every file gives
    built: dict[str, tuple] = {}
    skipped: Counter = Counter()
    tallies: Counter = Counter()
    notes: list[str] = []
    for r in done:
        if not r.get("ok"):
            raise InputError(r["error"])
        if r["floor"] is None or r["floor"] in built:
            return None
        built[r["floor"]] = r["built"]
        skipped.update(r["skipped"])
        tallies.update(r["tallies"])
        notes += r["notes"]
        for w in r["warnings"]:
            log.warning(w)
    notes += reader.tally_notes(dict(tallies), cfg)
    return built, {"skipped": dict(sorted(skipped.items())), "notes": notes, "transitions": []}


def read_floor_folder(files: list[str], fmt: str, ingest_toml: str, pdr_toml: str) -> dict:
    """A task of `build`: one floor folder's files read, validated and attached as that floor of a whole
    input's read would be (:func:`rmbuild.ingest.floors.split_floors`). Returns {"ok", "floor" (None when the
    folder holds no floor name or several floors), "built" (:func:`_build_floor`), "skipped", "notes",
    "warnings"}."""
    from rmbuild.config import load_stage_config_text

    cfg = load_stage_config_text("ingest", ingest_toml, "[ingest] config of the build")
    pdr_cfg = load_stage_config_text("pdr", pdr_toml, "[pdr] config of the build")
    with captured_warnings() as warnings:
        paths = [Path(f) for f in files]
        reader = choose_reader(paths, fmt)
        raw = reader.read(paths, cfg)
        if split_floors(raw) is not None or not raw.floor_name or raw.transitions or raw.enu_origin is not None:
            return {"ok": True, "floor": None, "warnings": warnings}
        built = _build_floor(whole_floor(raw, raw.floor_name), cfg, fmt, pdr_cfg)
    own = raw.notes[:len(raw.notes) - len(reader.tally_notes(raw.tallies, cfg))]  # the summary notes come last
    return {"ok": True, "floor": raw.floor_name, "built": built, "skipped": dict(raw.skipped), "notes": own,
            "tallies": dict(raw.tallies), "warnings": warnings}


def plan_summary(plan: dict | None, ds, warnings: list[str]) -> dict | None:
    """What the report says of the floor plan: its name, its image's extent (m) and the check of its frame
    against the fixes (:func:`rmbuild.io.floorplan.check_plan_frame`), whose warning joins ``warnings``."""
    if plan is None:
        return None
    fixes = ds.fixes[["x_m", "y_m"]].to_numpy(float) if ds.fixes is not None and len(ds.fixes) else np.empty((0, 2))
    check = check_plan_frame(plan, fixes)
    if check is not None and check.get("warning"):
        warnings.append(check["warning"])
    return {"name": plan.get("name", ""), "image_extent_m": (plan.get("image") or {}).get("extent_m"),
            "fixes_inside": None if check is None else check["fixes_inside"],
            "frame_check": check}
