"""Errors name file and line (anchors, CSV quirks, corrupt Parquet); nonsense is refused or warned about
(absurd and contradictory anchors, duplicated walks, device offsets, very short walks, sparse Wi-Fi)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild.errors import InputError
from rmbuild.ingest.checks import evidence_warnings, walk_rss_offsets
from rmbuild.io.anchors import check_anchors, read_anchors
from rmbuild.io.workspace import Workspace


@pytest.fixture(scope="module")
def ingested(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ing")
    inp = write_tables(make_input_tables(n_walks=3, n_steps=40), root / "in")
    from rmbuild.config import IngestConfig
    from rmbuild.stages import ingest

    ingest.run([inp], root / "ws", IngestConfig())
    return root / "ws"


def _one_error(r, pattern: str) -> str:
    assert r.code == 2, r.err
    lines = r.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.err
    assert re.search(pattern, lines[0]), lines[0]
    return lines[0]


# ------------------------------------------------------------------------------------- anchors
ANCHOR_ROWS = "walk_id,t_s,x_m,y_m\nwalk0,5.0,10.0,2.0\nwalk1,110.0,3.0,4.0\n"


@pytest.mark.parametrize("body, line, pattern", [
    ("walk0,5.0,abc,2.0\n", 4, r"column x_m: not a number: 'abc'"),
    ("ghost,5.0,1.0,2.0\n", 4, r"anchor of unknown walk 'ghost'"),
    ("walk0,5000.0,1.0,2.0\n", 4, r"anchor time t_s=5000 is outside walk 'walk0'"),
    ("walk0,6.0,1e300,2.0\n", 4, r"more than 100000 m from the origin"),
    ("walk0,5.0,60.0,2.0\n", 4, r"anchors of walk 'walk0' contradict each other: this one is 50.0 m from the one at "
                                r"\S+anchors.csv:2"),
])
def test_anchor_errors_name_file_and_line(body: str, line: int, pattern: str, ingested: Path, tmp_path: Path) -> None:
    f = tmp_path / "anchors.csv"
    f.write_text(ANCHOR_ROWS + body)
    ds = Workspace.open(ingested).read_dataset()
    with pytest.raises(InputError) as e:
        check_anchors(read_anchors(f), ds)
    assert str(e.value).startswith(f"{f}:{line}: "), str(e.value)
    assert re.search(pattern, str(e.value)), str(e.value)


def test_anchor_rows_of_parquet_count_from_one(ingested: Path, tmp_path: Path) -> None:
    f = tmp_path / "anchors.parquet"
    pd.read_csv(pd.io.common.StringIO(ANCHOR_ROWS + "ghost,1.0,1.0,1.0\n")).to_parquet(f)
    with pytest.raises(InputError, match=re.escape(f"{f}:row 3: anchor of unknown walk 'ghost'")):
        check_anchors(read_anchors(f), Workspace.open(ingested).read_dataset())


def test_consistent_anchors_pass(ingested: Path, tmp_path: Path) -> None:
    f = tmp_path / "anchors.csv"
    f.write_text(ANCHOR_ROWS + "walk0,10.0,16.5,2.5\n")  # ~10 steps later, ~7 m on: reachable
    check_anchors(read_anchors(f), Workspace.open(ingested).read_dataset())


# ------------------------------------------------------------------------------------- CSV quirks
def _corrupt_wifi(tmp_path: Path, edit) -> Path:
    folder = write_tables(make_input_tables(), tmp_path / "in")
    f = folder / "wifi.csv"
    f.write_bytes(edit(f.read_bytes()))
    return folder


def test_non_utf8_byte_names_its_line(tmp_path: Path, capsys) -> None:
    def edit(data: bytes) -> bytes:
        lines = data.split(b"\n")
        lines[40] = lines[40].replace(b"net", b"n\xe9t")
        return b"\n".join(lines)

    folder = _corrupt_wifi(tmp_path, edit)
    _one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), rf"{folder / 'wifi.csv'}:41: not UTF-8")


def test_blank_lines_and_quoted_newlines_keep_line_numbers_exact(tmp_path: Path, capsys) -> None:
    def edit(data: bytes) -> bytes:
        lines = data.split(b"\n")
        assert b",net0" in lines[1]
        lines[1] = lines[1].replace(b",net0", b',"net\n0"')  # one record spanning two lines
        lines[10] = lines[10].replace(b",-", b",+99", 1)      # rssi out of range
        return b"\n".join(lines[:6] + [b"", b""] + lines[6:])

    folder = _corrupt_wifi(tmp_path, edit)
    physical = (folder / "wifi.csv").read_bytes().split(b"\n")
    line = next(i for i, ln in enumerate(physical, 1) if b",+99" in ln)
    assert line == 14  # record 10 + the header, the quoted newline and two blank lines
    _one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), rf"{folder / 'wifi.csv'}:14: rssi_dbm")


def test_a_row_longer_than_the_header_is_named(tmp_path: Path, capsys) -> None:
    folder = _corrupt_wifi(tmp_path, lambda d: d.replace(b"\n", b",,,,\n", 2).replace(b",,,,\n", b"\n", 1))
    _one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), r"wifi.csv:2: 10 fields, the header has 6")


def test_corrupt_parquet_is_one_line(tmp_path: Path, capsys) -> None:
    folder = write_tables(make_input_tables(), tmp_path / "in", fmt="parquet")
    f = folder / "poses.parquet"
    data = f.read_bytes()
    f.write_bytes(data[:100] + b"\x00" * 64 + data[164:])
    _one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), rf"{f}: unreadable (Parquet|file) \(")


def test_huge_values_are_cut_in_messages(tmp_path: Path, capsys) -> None:
    folder = _corrupt_wifi(tmp_path, lambda d: d.replace(b"2437.0", b"z" * 10**6, 1))
    line = _one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), r"wifi.csv:2: column freq_mhz")
    assert len(line) < 1000


# ------------------------------------------------------------------------------------- nonsense evidence
def _tables(**kw) -> dict[str, pd.DataFrame]:
    return make_input_tables(n_walks=kw.get("n_walks", 5), n_steps=kw.get("n_steps", 60), seed=3)


def test_a_duplicated_walk_is_reported(tmp_path: Path, capsys) -> None:
    t = _tables()
    for name in ("poses", "wifi"):
        copy = t[name][t[name]["walk_id"] == "walk1"].assign(walk_id="walk1_copy")
        copy["t_s"] += 1000.0  # recorded "later": same steps and scans relative to the start
        t[name] = pd.concat([t[name], copy], ignore_index=True)
    t["walks"] = pd.concat([t["walks"], t["walks"].iloc[[1]].assign(walk_id="walk1_copy")], ignore_index=True)
    r = run_cli(capsys, "ingest", write_tables(t, tmp_path / "in"), "-w", tmp_path / "ws")
    assert r.code == 0
    assert "walk 'walk1_copy' repeats the steps of walk 'walk1'" in r.err


def test_a_device_offset_is_reported_and_plain_walks_are_not(tmp_path: Path) -> None:
    from rmbuild.config import IngestConfig, SimulateConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import ingest, simulate

    simulate.run(tmp_path / "in", preset_config("tiny", 5), fmt="parquet")
    s = ingest.run([tmp_path / "in"], tmp_path / "ws", IngestConfig())
    assert not any("device offset" in w for w in s["warnings"])
    ds = Workspace.open(tmp_path / "ws").read_dataset()
    base = walk_rss_offsets(ds)
    assert len(base) >= 4 and max(abs(v) for v in base.values()) < 4.0, base
    wid = ds.walks["walk_id"].iloc[1]
    for shift in (10.0, -10.0):
        ds2 = Workspace.open(tmp_path / "ws").read_dataset()
        ds2.wifi.loc[ds2.wifi["walk_id"] == wid, "rssi_dbm"] += shift
        off = walk_rss_offsets(ds2)
        assert abs(off[wid] - base[wid] - shift) < 2.0, (off, base)
        warnings = evidence_warnings(ds2)
        assert len(warnings) == 1 and warnings[0].startswith(f"walk {wid!r} reads {off[wid]:+.1f} dB"), warnings
        assert "slac localizer calibrates devices" in warnings[0]
    # several offset walks: one warning naming each with its offset, largest first
    ids = [str(w) for w in ds.walks["walk_id"].iloc[1:3]]
    ds3 = Workspace.open(tmp_path / "ws").read_dataset()
    for wid, shift in zip(ids, (10.0, -16.0), strict=True):
        ds3.wifi.loc[ds3.wifi["walk_id"] == wid, "rssi_dbm"] += shift
    warnings = evidence_warnings(ds3)
    assert len(warnings) == 1 and warnings[0].startswith("2 walks read 6 dB or more"), warnings
    assert warnings[0].index(repr(ids[1])) < warnings[0].index(repr(ids[0]))  # the larger offset first
    assert "they may stay unlinked" in warnings[0]
    assert isinstance(SimulateConfig(), SimulateConfig)


def test_many_offset_walks_are_one_short_warning() -> None:
    from rmbuild.ingest.checks import NAMED_OFFSETS, offset_warning

    offsets = {f"walk{i:02d}": (-1) ** i * (6.0 + i) for i in range(11)}
    (text,) = offset_warning(offsets)
    assert text.count(" dB,") == NAMED_OFFSETS - 1 and "'walk10' +16.0 dB" in text
    assert f"and {11 - NAMED_OFFSETS} more" in text and "'walk00'" not in text and len(text) < 450
    assert offset_warning({}) == []


def test_a_three_step_walk_is_reported(tmp_path: Path, capsys) -> None:
    t = _tables()
    keep = ~((t["poses"]["walk_id"] == "walk2") & (t["poses"].groupby("walk_id").cumcount() >= 3))
    t["poses"] = t["poses"][keep.to_numpy()]
    r = run_cli(capsys, "ingest", write_tables(t, tmp_path / "in"), "-w", tmp_path / "ws")
    assert r.code == 0 and "fewer than 5 steps" in r.err and "walk2" in r.err


# ------------------------------------------------------------------------------------- degraded evidence
@pytest.fixture(scope="module")
def tiny_input(tmp_path_factory) -> Path:
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate

    root = tmp_path_factory.mktemp("tiny")
    simulate.run(root / "in", preset_config("tiny", 7), fmt="parquet")
    return root / "in"


def _drop_readings(src: Path, dst: Path, fraction: float) -> Path:
    shutil.copytree(src, dst)
    w = pd.read_parquet(dst / "wifi.parquet")
    keep = np.random.default_rng(1).random(len(w)) >= fraction
    w[keep].to_parquet(dst / "wifi.parquet", index=False)
    return dst


def test_half_the_readings_dropped_still_optimizes(tiny_input: Path, tmp_path: Path, capsys) -> None:
    folder = _drop_readings(tiny_input, tmp_path / "in", 0.5)
    assert run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws", "-q").code == 0
    r = run_cli(capsys, "optimize", "-w", tmp_path / "ws", "-q")
    assert r.code == 0, r.err
    walks = Workspace.open(tmp_path / "ws").read_table("optimize.walks")
    assert walks["linked"].sum() >= 2


@pytest.mark.parametrize("drop", [0.9, 0.97])
def test_sparse_wifi_gives_unlinked_walks_not_a_crash(tiny_input: Path, tmp_path: Path, capsys, drop) -> None:
    folder = _drop_readings(tiny_input, tmp_path / "in", drop)
    assert run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws", "-q").code == 0
    r = run_cli(capsys, "optimize", "-w", tmp_path / "ws", "-q")
    assert r.code == 0, r.err
    walks = Workspace.open(tmp_path / "ws").read_table("optimize.walks")
    if drop > 0.95:
        assert not walks["linked"].all()  # 3 % of the readings cannot link every walk
    if not walks["linked"].all():  # sparse evidence: unlinked walks, and a warning that names them
        assert "not linked" in r.err or "disconnected" in r.err
    if drop > 0.95:  # unlinked walks are marked wherever poses go
        _unlinked_walks_are_marked(tmp_path / "ws", walks, capsys)


def _unlinked_walks_are_marked(ws_dir: Path, walks: pd.DataFrame, capsys) -> None:
    from rmbuild.viz.rerun_bridge import rrd_entities

    ws = Workspace.open(ws_dir)
    tum = pd.read_csv(ws.path("optimize.tum_index"), dtype={"walk_id": str})
    linked = dict(zip(walks["walk_id"].astype(str), walks["linked"].astype(bool), strict=True))
    assert dict(zip(tum["walk_id"], tum["linked"].astype(bool), strict=True)) == linked
    n_unlinked = sum(not v for v in linked.values())
    assert run_cli(capsys, "report", "-w", ws_dir).code == 0
    page = (ws_dir / "report.html").read_text()
    assert f"the {n_unlinked} walk(s) optimize could not link" in page and "they are not drawn after" in page
    assert run_cli(capsys, "view", "-w", ws_dir, "--save", ws_dir / "v.rrd").code == 0
    ents = rrd_entities(ws_dir / "v.rrd")
    assert sum(e.startswith("/floor/optimized_unlinked/") and e.count("/") == 3 for e in ents) == n_unlinked
    assert sum(e.startswith("/floor/optimized/") and e.count("/") == 3 for e in ents) == len(linked) - n_unlinked
