"""`rmbuild report`: write a one-page self-contained HTML report of a workspace, plus its PNGs."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

from rmbuild.io.atomic import write_bytes_atomic, write_text_atomic
from rmbuild.io.workspace import Workspace

log = logging.getLogger(__name__)


def run(workspace: str | Path, out: str | Path | None = None, png_dir: str | Path | None = None,
        heatmap_top_n: int = 6) -> dict:
    """Write the report to ``out`` (default WORKSPACE/report.html) atomically and each figure as a PNG in
    ``png_dir`` (default WORKSPACE/report/); returns {"path", "png_dir", "figures", "missing", "time_s"}."""
    from rmbuild.viz.report import build_report

    t0 = time.perf_counter()
    ws = Workspace.open(workspace)
    report = build_report(ws, heatmap_top_n=heatmap_top_n)
    out = Path(out) if out is not None else ws.root / "report.html"
    png_dir = Path(png_dir) if png_dir is not None else ws.root / "report"
    for f in report.figures:
        write_bytes_atomic(png_dir / f"{f.name}.png", f.png)
        _readable(png_dir / f"{f.name}.png")
    write_text_atomic(out, report.html)
    _readable(out)
    return {
        "stage": "report",
        "path": str(out),
        "png_dir": str(png_dir),
        "figures": [f.name for f in report.figures],
        "missing": report.missing,
        "bytes": len(report.html.encode("utf-8")),
        "time_s": round(time.perf_counter() - t0, 3),
    }


def _readable(path: Path) -> None:
    """Atomic writes create 0600 files; a report is meant to be shared: apply the usual umask instead."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)
