"""A bounded fuzz campaign in the suite (`make fuzz` runs 10,000 cases): mutated inputs of every format,
config files and anchors files, each run under a memory cap, must end with exit 0 or 2, one error line
naming a file of the case, no traceback, nothing written, bounded memory and time.

Defects found by the campaign in code owned elsewhere are listed in :data:`KNOWN`, each with a reproducer
test below marked xfail(strict): when its fix lands the reproducer passes, the strict mark fails the
suite, and the mark and the KNOWN entry are removed together.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bench.fuzz.run import run_cases

#: cases per kind in the suite (`make fuzz` draws 10,000 with the shares of bench.fuzz.cases.KINDS)
SUITE_CASES = {"schema": 50, "schema_parquet": 15, "imu": 12, "ilc": 35, "ipin": 30, "config": 40, "anchors": 20,
               # the second campaign's kinds (issue 40)
               "extreme": 8, "plan": 8, "gzip_bomb": 3, "keys": 2, "floor_info": 6, "venues": 4, "outputs": 6,
               "links": 6}
#: signature (regex on the case's stderr) -> the defect and where it is fixed
KNOWN: dict[str, str] = {}  # none open: the earlier ones (memory on a bad ILC timestamp or an overlong line,
#                            ingest errors naming no file) are fixed; their reproducers stay below


def _known(r: dict) -> str | None:
    return next((why for sig, why in KNOWN.items() if re.search(sig, r.get("stderr") or "")), None)


@pytest.fixture(scope="module")
def results() -> list[dict]:
    cases = [(kind, 900_000 + i) for kind, n in SUITE_CASES.items() for i in range(n)]
    return run_cases(cases, jobs=2, light=True)


def test_fuzzed_inputs_end_cleanly(results: list[dict]) -> None:
    assert len(results) == sum(SUITE_CASES.values())
    unknown = [{k: r.get(k) for k in ("kind", "seed", "problems", "mutations")} | {"err": r["stderr"][-300:]}
               for r in results if r["problems"] and _known(r) is None]
    assert unknown == [], unknown
    # the campaign exercised both outcomes of every kind of input
    for kind in SUITE_CASES:
        codes = {r["code"] for r in results if r["kind"] == kind}
        assert 2 in codes, kind
    assert sum(r["code"] == 0 for r in results) >= 0.1 * len(results)


def test_fuzzed_inputs_stay_within_memory_and_time(results: list[dict]) -> None:
    from bench.fuzz.worker import PEAK_LIMIT_MB

    rss = [r["peak_rss_mb"] for r in results if r.get("peak_rss_mb") is not None]
    assert max(rss) <= PEAK_LIMIT_MB
    assert max(r["time_s"] for r in results if r.get("time_s") is not None) < 60


# ----------------------------------------------------- reproducers (fixed defects stay as regression tests)
FIXTURE = Path(__file__).resolve().parent / "fixtures" / "msft_ilc" / "tiny_trace.txt"


def _ilc_with_time(tmp_path: Path, value: str) -> Path:
    lines = FIXTURE.read_text().split("\n")
    i = next(k for k, ln in enumerate(lines) if "\tTYPE_ACCELEROMETER\t" in ln and k > 600)
    cells = lines[i].split("\t")
    cells[0] = value
    lines[i] = "\t".join(cells)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_text("\n".join(lines))
    return tmp_path / "in"


@pytest.mark.parametrize("value", ["1", "9" * 20])
def test_one_bad_ilc_timestamp_is_a_clean_error(value: str, tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    r = run_cli(capsys, "ingest", _ilc_with_time(tmp_path, value), "-w", tmp_path / "ws")
    assert r.code in (0, 2) and "internal error" not in r.err, r.err


@pytest.mark.parametrize("digits", [20, 400])
def test_a_huge_integer_in_a_numeric_ilc_field_names_its_line(digits: int, tmp_path: Path, capsys) -> None:
    """make fuzz case ilc/580: a rotation-vector value of 400 nines overflowed pandas' float conversion in
    the fast parser (OverflowError, exit 1); the line-by-line parser names the line."""
    from cli_util import run_cli

    lines = FIXTURE.read_text().split("\n")
    i = next(k for k, ln in enumerate(lines) if "\tTYPE_ROTATION_VECTOR\t" in ln)
    cells = lines[i].split("\t")
    cells[5] = "9" * digits  # the accuracy flag
    lines[i] = "\t".join(cells)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_text("\n".join(lines))
    r = run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws")
    if digits > 308:  # beyond the float range: an error naming the line
        assert r.code == 2 and f"trace.txt:{i + 1}:" in r.err and len(r.err.strip().splitlines()) == 1, r.err
    else:
        assert r.code in (0, 2) and "internal error" not in r.err, r.err


def test_ingest_core_errors_name_their_file(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli
    from conftest import make_input_tables, write_tables

    t = make_input_tables()
    t["walks"] = t["walks"].iloc[1:]
    folder = write_tables(t, tmp_path / "in")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and str(folder) in r.err, r.err


def test_an_overlong_ilc_line_is_a_clean_error(tmp_path: Path) -> None:
    """A 2 MB accelerometer line (one 2 MB value) in an ILC trace; run in a child process capped at 2 GB of
    address space and 60 s."""
    import os
    import resource
    import subprocess
    import sys

    lines = FIXTURE.read_text().split("\n")
    i = next(k for k, ln in enumerate(lines) if "\tTYPE_ACCELEROMETER\t" in ln and k > 700)
    cells = lines[i].split("\t")
    cells[3] = "7" * (2 << 20)
    lines[i] = "\t".join(cells)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_text("\n".join(lines))

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, resource.RLIM_INFINITY))

    repo = Path(__file__).resolve().parents[1]
    try:
        p = subprocess.run([sys.executable, "-m", "rmbuild", "ingest", str(tmp_path / "in"), "-w",
                            str(tmp_path / "ws")], preexec_fn=cap, capture_output=True, text=True, timeout=60,
                           cwd=repo, env={**os.environ, "PYTHONPATH": str(repo)})
    except subprocess.TimeoutExpired:
        pytest.fail("ingest of a trace with a 2 MB line took more than 60 s")
    assert p.returncode == 2 and f"trace.txt:{i + 1}" in p.stderr, p.stderr
