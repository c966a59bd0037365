"""`rmbuild report`: write a one-page self-contained HTML report of a workspace, plus its PNGs.

Without ``out`` the page is WORKSPACE/report.html and its PNGs WORKSPACE/report/. With ``out`` everything
the report makes goes beside that page, nothing into the workspace: the PNGs to ``<out stem>_figures/``
and, for a building, each floor's page to ``<out stem>_floors/<floor>.html`` (its PNGs beside it).
"""

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


def figures_dir(out: Path) -> Path:
    """Where the PNGs of a report written to ``out`` (not the workspace's default) go: beside it."""
    return out.with_name(f"{out.stem}_figures")


def floors_dir(out: Path) -> Path:
    """Where the floors' pages of a building report written to ``out`` go: beside it."""
    return out.with_name(f"{out.stem}_floors")


def run(workspace: str | Path, out: str | Path | None = None, heatmap_top_n: int = 6, force: bool = False,
        floor: str | None = None) -> dict:
    """Write the report (see the module) atomically; returns {"path", "png_dir", "figures", "missing",
    "time_s"}, for a building each floor's under "floors".

    An existing report (the HTML file, or PNGs in its figure directory) is replaced only with ``force``. A
    building: each floor's report (or the one ``floor`` names), and at ``out`` (default
    WORKSPACE/report.html) a page with the building's per-floor figures linking them."""
    out_p = Path(out) if out is not None else None
    floors = floor_workspaces(workspace, floor)
    if floors is not None:
        index = check_output_file(out_p if out_p is not None else Workspace(workspace).path("report.html"), force,
                                  "report")

        def one(name: str, path: Path) -> dict:
            return run(path, None if out_p is None else floors_dir(out_p) / f"{name}.html", heatmap_top_n, force)

        r = run_floors(workspace, "report", floors, one, exclusive=False, summaries=True)
        write_text_atomic(index, building_page(workspace, r["floors"], index))
        return {**r, "path": str(index)}
    with locked_workspace(workspace, "report", exclusive=False) as ws:
        page = check_output_file(out_p if out_p is not None else ws.path("report.html"), force, "report")
        png_p = figures_dir(out_p) if out_p is not None else ws.path("report.png_dir")
        if png_p.is_symlink():
            raise InputError(f"{png_p} is a symbolic link; rmbuild never writes through one: give the folder it "
                             "points to, or another")
        check_outside_workspace(png_p / "figure.png", "report figures")
        if not force and png_p.is_dir() and any(png_p.glob("*.png")):
            raise InputError(f"{png_p} already holds report figures; pass --force to replace them")
        return _write(ws, page, png_p, heatmap_top_n)


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
