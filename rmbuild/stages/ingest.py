"""`rmbuild ingest`: read input files, validate, attach readings to pose nodes, write a new workspace."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from rmbuild.config import IngestConfig, PdrConfig, to_toml
from rmbuild.ingest_core import build_dataset
from rmbuild.io.formats import choose_reader, expand_inputs
from rmbuild.io.workspace import Workspace, write_dataset
from rmbuild.stages.common import Progress, ensure_progress

log = logging.getLogger(__name__)


def run(
    inputs: list[str | Path],
    workspace: str | Path,
    cfg: IngestConfig,
    fmt: str | None = None,
    force: bool = False,
    progress: Progress | None = None,
    pdr_cfg: PdrConfig | None = None,
    viewer=None,
) -> dict:
    """Ingest ``inputs`` (files or directories) into a new workspace; returns the ingest report.

    ``pdr_cfg``: options of the raw-IMU formats (phone PDR, ILC/IPIN specifics); defaults when None.
    """
    progress = ensure_progress(progress)
    t0 = time.perf_counter()
    files = expand_inputs(inputs)
    ws_root = Path(workspace).resolve()
    files = [f for f in files if ws_root not in f.resolve().parents]
    pdr_cfg = pdr_cfg or PdrConfig()
    reader = choose_reader(files, fmt, pdr_cfg)
    progress.phase(f"reading {len(files)} file(s) as {reader.name}")
    raw = reader.read(files, cfg)
    t_read = time.perf_counter() - t0
    progress.phase("validating and attaching readings")
    t1 = time.perf_counter()
    ds, fp, summary = build_dataset(raw, cfg, source=reader.name, pdr_cfg=pdr_cfg)
    t_build = time.perf_counter() - t1
    summary = {"stage": "ingest", "format": reader.name, "inputs": [str(p) for p in inputs], **summary}
    progress.phase("writing workspace")
    with Workspace.create(workspace, force=force) as w:
        write_dataset(w, ds, fp)
        uses_pdr = reader.name != "rmbuild" or bool(raw.imu)
        w.config(to_toml(cfg, "ingest") + ("\n" + to_toml(pdr_cfg, "pdr") if uses_pdr else ""))
        summary["time_s"] = {"read": round(t_read, 3), "validate_attach": round(t_build, 3),
                             "total": round(time.perf_counter() - t0, 3)}
        w.report = summary
    for msg in summary["warnings"]:
        log.warning(msg)
    if viewer is not None:
        from rmbuild.stages.view import log_workspace

        log_workspace(Workspace.open(workspace), viewer)
    return summary
