"""Helpers (no tests) shared by the viz and report tests: a tiny workspace built with the real CLI."""

from __future__ import annotations

import os
from pathlib import Path

from rmbuild.cli import main

#: set RMBUILD_DOC_IMAGES=1 to refresh docs/img/report.png and docs/img/rrd_entities.txt from the tests
DOC_IMG = Path(__file__).resolve().parents[1] / "docs" / "img"
WRITE_DOC_IMAGES = os.environ.get("RMBUILD_DOC_IMAGES") == "1"


def cli(*args: object) -> None:
    """Run the rmbuild CLI in-process; raise AssertionError on a non-zero exit."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    assert code == 0, f"rmbuild {' '.join(map(str, args))} exited {code}"


def build_workspace(root: Path, stages: tuple[str, ...] = ("optimize",)) -> Path:
    """simulate tiny + ingest (+ the given later stages); returns WORKSPACE."""
    cli("simulate", root / "in", "--preset", "tiny", "--seed", "7", "-q")
    ws = root / "ws"
    cli("ingest", root / "in", "-w", ws, "-q")
    for st in stages:
        cli(st, "-w", ws, "-q")
    return ws
