"""`make run` and `make run-real`: their recipes, run as written (the CLI in this process, the outputs under a
temporary directory, the tiny preset for speed), leave every path they print behind."""

from __future__ import annotations

import glob
import re
from pathlib import Path

import pytest
from cli_util import run_cli

ROOT = Path(__file__).resolve().parents[1]
MAKEFILE = ROOT / "Makefile"


def recipe(target: str) -> tuple[list[list[str]], list[str]]:
    """(the rmbuild commands of ``target``, the paths its closing echo lines name), Make variables as is."""
    lines = MAKEFILE.read_text().splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"{target}:"))
    commands, paths = [], []
    for ln in lines[start + 1:]:
        if not ln.startswith("\t"):
            break
        body = ln.strip()
        if body.startswith("$(RM_CLI) "):
            commands.append(body.split()[1:])
        elif m := re.match(r'@echo "\s+[^:]+:\s+([^\s"]+)', body):
            paths.append(m.group(1))
    return commands, paths


def _expand(text: str, variables: dict[str, str]) -> str:
    return re.sub(r"\$\((\w+)\)", lambda m: variables[m.group(1)], text)


@pytest.mark.parametrize("target", ["run", "run-real"])
def test_make_targets_print_paths_that_exist(target: str, tmp_path: Path, capsys) -> None:
    variables = {"RUN_DIR": str(tmp_path / "default"), "REAL_DIR": str(tmp_path / "real"), "PRESET": "tiny",
                 "SEED": "7", "REAL_DATA": str(ROOT / "datasets" / "msft-ilc20" / "site1" / "F1")}
    commands, paths = recipe(target)
    assert len(commands) >= 5 and len(paths) >= 5
    if target == "run-real" and not Path(variables["REAL_DATA"]).is_dir():
        pytest.skip("the real sample (datasets/msft-ilc20) is not in this checkout")
    for args in commands:
        r = run_cli(capsys, *(_expand(a, variables) for a in args), "-q")
        assert r.code == 0, (args, r.err)
    for p in paths:
        expanded = _expand(p, variables)
        assert glob.glob(expanded), f"{target} prints {p}, which does not exist after the run"
