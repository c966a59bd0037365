"""Run the real CLI entry point in-process and capture exit code, stdout and stderr."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from rmbuild.cli import main


@dataclass
class Result:
    code: int
    out: str
    err: str


def run_cli(capsys: pytest.CaptureFixture, *args: str) -> Result:
    capsys.readouterr()
    try:
        main(list(map(str, args)))
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    cap = capsys.readouterr()
    return Result(code, cap.out, cap.err)


def split_input(src: Path, dst: Path, walks: set[str]) -> Path:
    """The part of an rmbuild-schema input at ``src`` that belongs to ``walks`` (tables without walk_id
    copied whole)."""
    import shutil

    import pandas as pd

    for f in sorted(p for p in src.rglob("*") if p.is_file()):
        out = dst / f.relative_to(src)
        out.parent.mkdir(parents=True, exist_ok=True)
        if f.suffix != ".csv":
            shutil.copy(f, out)
            continue
        df = pd.read_csv(f, dtype={"walk_id": str})
        (df[df["walk_id"].isin(walks)] if "walk_id" in df else df).to_csv(out, index=False)
    return dst
