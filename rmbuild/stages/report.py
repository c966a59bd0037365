"""`rmbuild report`: write a one-page self-contained HTML report of a workspace, plus its PNGs."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from rmbuild.errors import InputError
from rmbuild.io.atomic import write_bytes_atomic, write_text_atomic
from rmbuild.io.workspace import Workspace, check_output_file, check_outside_workspace
from rmbuild.stages.building import building_page, floor_workspaces, run_floors
from rmbuild.stages.common import locked_workspace

log = logging.getLogger(__name__)


def run(workspace: str | Path, out: str | Path | None = None, png_dir: str | Path | None = None,
        heatmap_top_n: int = 6, force: bool = False, floor: str | None = None) -> dict:
    """Write the report to ``out`` (default WORKSPACE/report.html) atomically and each figure as a PNG in
    ``png_dir`` (default WORKSPACE/report/); returns {"path", "png_dir", "figures", "missing", "time_s"}.

    An existing report (the HTML file, or PNGs in ``png_dir``) is replaced only with ``force``. A building:
    each floor's report in its own workspace (or the one ``floor`` names), and at ``out`` (default
    WORKSPACE/report.html) a page linking them with the building's totals."""
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        if png_dir is not None:
            raise InputError("--png-dir: a building's floors keep their figures in their own workspaces")
        index = check_output_file(out if out is not None else Workspace(workspace).path("report.html"), force, "report")
        r = run_floors(workspace, "report", floors, lambda _, p: run(p, None, None, heatmap_top_n, force),
                       exclusive=False, summaries=True)
        write_text_atomic(index, building_page(workspace, r["floors"], index))
        return {**r, "path": str(index)}
    with locked_workspace(workspace, "report", exclusive=False) as ws:
        out_p = check_output_file(out if out is not None else ws.path("report.html"), force, "report")
        png_p = Path(png_dir) if png_dir is not None else ws.path("report.png_dir")
        if png_p.is_symlink():
            raise InputError(f"{png_p} is a symbolic link; rmbuild never writes through one: give the folder it "
                             "points to, or another")
        check_outside_workspace(png_p / "figure.png", "report figures")
        if not force and png_p.is_dir() and any(png_p.glob("*.png")):
            raise InputError(f"{png_p} already holds report figures; pass --force to replace them")
        return _write(ws, out_p, png_p, heatmap_top_n)


def _write(ws: Workspace, out: Path, png_dir: Path, heatmap_top_n: int) -> dict:
    from rmbuild.viz.report import build_report

    t0 = time.perf_counter()
    report = build_report(ws, heatmap_top_n=heatmap_top_n)
    for f in report.figures:
        write_bytes_atomic(png_dir / f"{f.name}.png", f.png)
        log.info(f"report: {f.name}.png ({len(f.png) / 1024:.0f} kB): {f.title}")
    write_text_atomic(out, report.html)
    return {
        "stage": "report",
        "path": str(out),
        "png_dir": str(png_dir),
        "figures": [f.name for f in report.figures],
        "missing": report.missing,
        "bytes": len(report.html.encode("utf-8")),
        "time_s": round(time.perf_counter() - t0, 3),
    }
