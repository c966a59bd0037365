"""ingest: our schema in CSV and Parquet, attachment rules, workspace safety, and every bad-input case."""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild.config import IngestConfig
from rmbuild.errors import InputError, WorkspaceError
from rmbuild.io.workspace import Workspace
from rmbuild.stages import ingest


def test_ingest_csv_roundtrip(small_input: Path, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    s = ingest.run([small_input], ws, IngestConfig())
    assert s["walks"] == 2 and s["poses"] == 60
    assert s["readings"] == 2 * 8 * 4
    w = Workspace.open(ws)
    ds = w.read_dataset()
    assert list(ds.poses["step"][:3]) == [0, 1, 2]
    assert ds.walks["source"].tolist() == ["rmbuild", "rmbuild"]
    # interval attachment: a reading at t_k + 0.1 goes to node k
    t_node = ds.poses["t_s"].to_numpy()[ds.wifi["node"].to_numpy()]
    np.testing.assert_allclose(ds.wifi["t_s"].to_numpy() - t_node, 0.1, atol=1e-9)
    fp = w.read_fingerprints()
    assert len(fp) == 16 and fp.rss_dbm.shape[1] == 5
    # the stage's record has checksums of every file of the stage (its report and resolved config too)
    files = w.record("ingest")["files"]
    assert {"data/poses.parquet", "data/config.toml", "data/report.json"} <= set(files)
    assert 'attach = "interval"' in (ws / "data" / "config.toml").read_text()
    assert w.read_report("ingest")["walks"] == 2 and w.manifest["format"] == "rmbuild-workspace"


def test_parquet_same_as_csv(tmp_path: Path) -> None:
    tables = make_input_tables()
    a = ingest.run([write_tables(tables, tmp_path / "csv")], tmp_path / "a", IngestConfig())
    b = ingest.run([write_tables(tables, tmp_path / "pq", "parquet")], tmp_path / "b", IngestConfig())
    assert {k: a[k] for k in ("walks", "poses", "readings", "scans")} == {
        k: b[k] for k in ("walks", "poses", "readings", "scans")}
    pa = Workspace.open(tmp_path / "a").read_dataset().poses
    pb = Workspace.open(tmp_path / "b").read_dataset().poses
    pd.testing.assert_frame_equal(pa, pb, check_exact=False, rtol=1e-12)


def test_increments_are_integrated(tmp_path: Path) -> None:
    tables = make_input_tables(n_walks=1, n_steps=5)
    p = tables["poses"]
    inc = pd.DataFrame({"walk_id": p["walk_id"], "t_s": p["t_s"], "step_length_m": 1.0,
                        "dheading_rad": [0.0, 0.0, np.pi / 2, 0.0, 0.0]})
    tables["poses"] = inc
    tables["wifi"] = tables["wifi"][tables["wifi"]["walk_id"] == "walk0"]
    ingest.run([write_tables(tables, tmp_path / "in")], tmp_path / "ws", IngestConfig())
    ds = Workspace.open(tmp_path / "ws").read_dataset()
    np.testing.assert_allclose(ds.poses["x_m"], [0, 1, 1, 1, 1], atol=1e-12)
    np.testing.assert_allclose(ds.poses["y_m"], [0, 0, 1, 2, 3], atol=1e-12)


def test_nearest_attachment(tmp_path: Path) -> None:
    tables = make_input_tables(n_walks=1)
    tables["wifi"]["t_s"] += 0.35  # closer to the next step (steps every 0.5 s)
    ingest.run([write_tables(tables, tmp_path / "in")], tmp_path / "ws", IngestConfig(attach="nearest"))
    ds = Workspace.open(tmp_path / "ws").read_dataset()
    t_node = ds.poses["t_s"].to_numpy()[ds.wifi["node"].to_numpy()]
    np.testing.assert_allclose(t_node - ds.wifi["t_s"].to_numpy(), 0.05, atol=1e-9)


def test_readings_far_outside_walk_are_dropped_with_warning(tmp_path: Path) -> None:
    tables = make_input_tables(n_walks=1)
    extra = tables["wifi"].iloc[:1].copy()
    extra["t_s"] = 1000.0
    tables["wifi"] = pd.concat([tables["wifi"], extra], ignore_index=True)
    s = ingest.run([write_tables(tables, tmp_path / "in")], tmp_path / "ws", IngestConfig())
    assert s["readings_dropped_outside_walk"] == 1
    assert any("not attached" in w for w in s["warnings"])


def test_refuses_to_overwrite_without_force(small_input: Path, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    ingest.run([small_input], ws, IngestConfig())
    before = (ws / "data" / "poses.parquet").read_bytes()
    with pytest.raises(WorkspaceError, match="--force"):
        ingest.run([small_input], ws, IngestConfig())
    assert (ws / "data" / "poses.parquet").read_bytes() == before
    ingest.run([small_input], ws, IngestConfig(), force=True)
    assert Workspace.open(ws).has("ingest")


def test_never_replaces_a_foreign_directory(small_input: Path, tmp_path: Path) -> None:
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    with pytest.raises(WorkspaceError, match="not an rmbuild workspace"):
        ingest.run([small_input], foreign, IngestConfig(), force=True)
    assert (foreign / "thesis.tex").read_text() == "precious"


def test_failure_leaves_old_workspace(small_input: Path, tmp_path: Path, monkeypatch) -> None:
    ws = tmp_path / "ws"
    ingest.run([small_input], ws, IngestConfig())
    before = sorted(p.name for p in (ws / "data").iterdir())
    import rmbuild.stages.ingest as mod

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(mod, "write_dataset", boom)
    with pytest.raises(KeyboardInterrupt):
        ingest.run([small_input], ws, IngestConfig(), force=True)
    assert sorted(p.name for p in (ws / "data").iterdir()) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ws.")]  # no temp leftovers


def _corrupt(tmp_path: Path, table: str, edit) -> Path:
    tables = make_input_tables()
    tables[table] = edit(tables[table].copy())
    return write_tables(tables, tmp_path / "bad")


BAD_CASES = {
    "misspelt column": ("wifi", lambda d: d.rename(columns={"rssi_dbm": "rssi_dBm"}), r"wifi.csv:1: unknown column"),
    "missing column": ("poses", lambda d: d.drop(columns=["heading_rad"]), r"poses.csv:1: missing required column"),
    "wrong type": ("wifi", lambda d: d.assign(rssi_dbm=d["rssi_dbm"].astype(object).where(d.index != 5, "loud")),
                   r"wifi.csv:7: column rssi_dbm: not a number"),
    "nan": ("poses", lambda d: d.assign(x_m=d["x_m"].where(d.index != 3, np.nan)), r"poses.csv:5: column x_m"),
    "inf": ("poses", lambda d: d.assign(y_m=d["y_m"].where(d.index != 4, np.inf)), r"poses.csv:6: column y_m: inf"),
    "rssi range": ("wifi", lambda d: d.assign(rssi_dbm=d["rssi_dbm"].where(d.index != 2, 12.0)),
                   r"wifi.csv:4: rssi_dbm 12.0 outside"),
    "time backwards": ("poses", lambda d: d.assign(t_s=d["t_s"].where(d.index != 10, 1.0)),
                       r"poses.csv:12: poses: time goes backwards"),
    "duplicate pose time": ("poses", lambda d: d.assign(t_s=d["t_s"].where(d.index != 10, d["t_s"][9])),
                            r"poses.csv:12: poses: duplicate time"),
    "duplicate rows": ("wifi", lambda d: pd.concat([d.iloc[:3], d.iloc[2:3], d.iloc[3:]], ignore_index=True),
                       r"wifi.csv:5: duplicate reading"),
    "orphan readings": ("wifi", lambda d: d.assign(walk_id=d["walk_id"].where(d.index != 8, "ghost")),
                        r"wifi.csv:10: Wi-Fi reading of walk 'ghost', which has no poses"),
    "empty bssid": ("wifi", lambda d: d.assign(bssid=d["bssid"].where(d.index != 1, None)),
                    r"wifi.csv:3: empty bssid"),
    "bad role": ("walks", lambda d: d.assign(role="tset"), r"walks.csv:2: role must be one of"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_is_one_clean_line(case: str, tmp_path: Path, capsys) -> None:
    table, edit, pattern = BAD_CASES[case]
    folder = _corrupt(tmp_path, table, edit)
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2, r.err
    lines = r.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.err
    import re

    assert re.search(pattern, lines[0]), lines[0]
    assert not (tmp_path / "ws").exists()


def test_empty_and_header_only_files(tmp_path: Path, capsys) -> None:
    folder = write_tables(make_input_tables(), tmp_path / "in")
    (folder / "wifi.csv").write_text("")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and "wifi.csv: empty file" in r.err
    (folder / "wifi.csv").write_text("walk_id,t_s,bssid,rssi_dbm\n")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and "wifi.csv: no data rows" in r.err


def test_unreadable_gzip_and_parquet(tmp_path: Path, capsys) -> None:
    folder = write_tables(make_input_tables(), tmp_path / "in")
    data = gzip.compress((folder / "wifi.csv").read_bytes())
    (folder / "wifi.csv").unlink()
    (folder / "wifi.csv.gz").write_bytes(data[: len(data) // 2])
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and "wifi.csv.gz: unreadable gzip" in r.err, r.err
    folder2 = write_tables(make_input_tables(), tmp_path / "in2", "parquet")
    (folder2 / "poses.parquet").write_bytes(b"PAR1 not really parquet")
    r = run_cli(capsys, "ingest", folder2, "-w", tmp_path / "ws")
    assert r.code == 2 and "poses.parquet: unreadable Parquet" in r.err, r.err


def test_unknown_config_key(small_input: Path, tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[ingest]\natach = 'nearest'\n")
    r = run_cli(capsys, "ingest", small_input, "-w", tmp_path / "ws", "--config", cfg)
    assert r.code == 2 and "unknown key 'atach'" in r.err
    cfg.write_text("[ingest]\nattach = 'closest'\n")
    r = run_cli(capsys, "ingest", small_input, "-w", tmp_path / "ws", "--config", cfg)
    assert r.code == 2 and "must be one of" in r.err
    cfg.write_text("[ingst]\n")
    r = run_cli(capsys, "ingest", small_input, "-w", tmp_path / "ws", "--config", cfg)
    assert r.code == 2 and "unknown section [ingst]" in r.err


def test_missing_input_path(tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "ingest", tmp_path / "nope", "-w", tmp_path / "ws")
    assert r.code == 2 and "no such file or directory" in r.err


def test_ingest_does_not_read_its_own_workspace(small_input: Path, capsys) -> None:
    ws = small_input / "ws"
    assert run_cli(capsys, "ingest", small_input, "-w", ws).code == 0
    assert run_cli(capsys, "ingest", small_input, "-w", ws, "--force").code == 0
    assert Workspace.open(ws).read_report("ingest")["walks"] == 2


def test_stale_swap_is_recovered(small_input: Path, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    ingest.run([small_input], ws, IngestConfig())
    os.replace(ws, tmp_path / f".ws.old-{os.getpid()}")  # as if killed between the two renames
    assert Workspace.open(ws).has("ingest")


def test_input_error_names_where() -> None:
    e = InputError("bad value", "f.csv:3")
    assert str(e) == "f.csv:3: bad value" and e.exit_code == 2
