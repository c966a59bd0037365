"""Property: any corruption of a valid input file gives success or one clean error line, never a crash."""

from __future__ import annotations

import shutil
from pathlib import Path

from cli_util import run_cli
from conftest import make_input_tables, write_tables
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

TOKENS = ["", "nan", "NaN", "inf", "-inf", "1e999", "abc", "-130", "5", "0x1F", '"', "'", "\x00", "é",
          "1,2", ";", "-50.5", "   ", "None", "true", "9" * 40]


@st.composite
def corruption(draw):
    table = draw(st.sampled_from(["poses", "wifi", "walks", "fixes"]))
    kind = draw(st.sampled_from(["cell", "drop_line", "dup_line", "swap_lines", "truncate", "garbage"]))
    return table, kind, draw(st.integers(0, 10_000)), draw(st.integers(0, 10_000)), draw(st.sampled_from(TOKENS))


def apply(path: Path, kind: str, a: int, b: int, token: str) -> None:
    data = path.read_bytes()
    lines = data.decode("utf-8").splitlines(keepends=True)
    if kind == "cell":
        i = a % len(lines)
        cells = lines[i].rstrip("\n").split(",")
        cells[b % len(cells)] = token
        lines[i] = ",".join(cells) + "\n"
    elif kind == "drop_line":
        del lines[a % len(lines)]
    elif kind == "dup_line":
        i = a % len(lines)
        lines.insert(i, lines[i])
    elif kind == "swap_lines":
        i, j = a % len(lines), b % len(lines)
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "truncate":
        path.write_bytes(data[: a % (len(data) + 1)])
        return
    elif kind == "garbage":
        i = a % (len(data) + 1)
        path.write_bytes(data[:i] + token.encode("utf-8") * (1 + b % 3) + b"\xff\xfe" * (b % 2) + data[i:])
        return
    path.write_text("".join(lines))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(c=corruption())
def test_random_corruption_gives_clean_outcome(c, tmp_path_factory, capsys) -> None:
    base = tmp_path_factory.mktemp("fuzz")
    folder = write_tables(make_input_tables(), base / "in")
    table, kind, a, b, token = c
    apply(folder / f"{table}.csv", kind, a, b, token)
    ws = base / "ws"
    r = run_cli(capsys, "ingest", folder, "-w", ws)
    assert r.code in (0, 2), (c, r.err)
    if r.code == 2:
        lines = r.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), (c, r.err)
        assert "Traceback" not in r.err and "internal error" not in r.err
        assert not ws.exists()
    shutil.rmtree(base)
