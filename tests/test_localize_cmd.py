"""The map in use: reading a radio map back, the Python API (docs/api.md runs), `rmbuild localize`."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli

from rmbuild.io.workspace import Workspace

DOCS_API = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def _split_by_role(src: Path, dst: Path, test: bool) -> Path:
    """A copy of a simulated input folder with only the test walks (or only the map walks)."""
    walks = pd.read_csv(src / "walks.csv", dtype={"walk_id": str})
    test_ids = set(walks.loc[walks["role"] == "test", "walk_id"])
    for f in src.rglob("*"):
        if f.is_dir():
            continue
        out = dst / f.relative_to(src)
        out.parent.mkdir(parents=True, exist_ok=True)
        if f.suffix == ".csv":
            df = pd.read_csv(f, dtype={"walk_id": str})
            if "walk_id" in df:
                df = df[df["walk_id"].isin(test_ids) == test]
            df.to_csv(out, index=False)
        else:
            shutil.copy(f, out)
    return dst


@pytest.fixture(scope="module")
def venue(tmp_path_factory) -> Path:
    """The tiny venue: ws_all (every walk, evaluated), ws_map (map walks only, map exported), test_in."""
    base = tmp_path_factory.mktemp("inuse")
    from rmbuild.cli import main

    def run(*args) -> None:
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0, args

    run("simulate", base / "in", "--preset", "tiny", "--seed", "5", "-q")
    _split_by_role(base / "in", base / "map_in", test=False)
    _split_by_role(base / "in", base / "test_in", test=True)
    for inp, ws in ((base / "in", base / "ws_all"), (base / "map_in", base / "ws_map")):
        run("ingest", inp, "-w", ws, "-q")
        run("optimize", "-w", ws, "-q")
        run("export-map", "-w", ws, "-q")
    run("evaluate", "-w", base / "ws_all", "-q")
    return base


def test_radio_map_reads_back_exactly(venue: Path) -> None:
    from rmbuild.io.map_store import read_map_config, read_radio_map
    from rmbuild.radiomap import build_radio_map
    from rmbuild.stages.mapping import built_positions

    ws = Workspace.open(venue / "ws_map")
    got = read_radio_map(ws)
    ds = ws.read_dataset()
    xy, info = built_positions(ws, ds, read_map_config(ws))
    want = build_radio_map(ds.wifi, xy, ds.poses["walk_id"].astype(str).to_numpy(), got.config, frame=info["frame"])
    assert got.frame == want.frame and got.cell_size_m == want.cell_size_m
    for name in ("origin_xy", "bssids", "count", "mean_dbm", "std_db", "detect_ratio", "n_walks", "node_xy",
                 "node_walk"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    cols = ["cell", "ix", "iy", "x_m", "y_m", "n_scans", "n_nodes", "n_walks", "interpolated"]
    pd.testing.assert_frame_equal(got.cells[cols].reset_index(drop=True), want.cells[cols].reset_index(drop=True))
    for name in ("node", "rss_dbm", "count"):
        a, b = getattr(got.nodes, name), getattr(want.nodes, name)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    assert got.histograms is not None and want.histograms is not None
    for name in ("cell", "sector", "ap", "bin", "count"):
        assert np.array_equal(getattr(got.histograms, name), getattr(want.histograms, name)), name


def test_localizing_evaluates_map_gives_evaluates_errors(venue: Path) -> None:
    """The localize path (fit, predict, uncertainty, table) on evaluate's own map and scans gives exactly
    evaluate's predictions and errors, for a fingerprint and a sequence localizer."""
    from rmbuild.config import EvaluateConfig
    from rmbuild.evaluate.localization import evaluate
    from rmbuild.io.map_store import read_map_config
    from rmbuild.localize.apply import localize_query, positions_table
    from rmbuild.stages.mapping import built_positions

    ws = Workspace.open(venue / "ws_all")
    ds, fp = ws.read_dataset(), ws.read_fingerprints()
    mcfg = read_map_config(ws)
    xy, info = built_positions(ws, ds, mcfg)
    cfg = EvaluateConfig(localizers=("knn", "pfl"))
    res = evaluate(ds, fp, xy, cfg, gauge=info["gauge"], map_cfg=mcfg)
    for name in cfg.localizers:
        out = localize_query(res.maps["built"], res.query, name, cfg)
        np.testing.assert_array_equal(out.xy, res.predictions["built"][name])
        table = positions_table(res.query, out, res.query_ref_xy)
        np.testing.assert_allclose(table["error_m"], res.errors["built"][name], equal_nan=True)
        assert np.isfinite(out.uncertainty_m).all() and (out.uncertainty_m > 0).all()


def test_api_example_in_the_docs_runs(venue: Path, tmp_path: Path, capsys) -> None:
    blocks = re.findall(r"```python\n(.*?)```", DOCS_API.read_text(), re.S)
    assert len(blocks) >= 3
    (tmp_path / "ws").symlink_to(venue / "ws_map")
    (tmp_path / "new_walks").symlink_to(venue / "test_in")
    before = sorted(p.name for p in (venue / "ws_map").rglob("*"))
    cwd = os.getcwd()
    os.chdir(tmp_path)
    ns: dict = {}
    try:
        for i, block in enumerate(blocks):
            exec(compile(block, f"{DOCS_API}:block {i + 1}", "exec"), ns)
    finally:
        os.chdir(cwd)
    table = ns["table"]
    assert len(table) == 13 and table["error_m"].notna().all()
    assert table["error_m"].median() < 5.0
    assert set(ns["walks"]["walk_id"]) == {"w000", "w001", "w002", "w003"}
    assert sorted(p.name for p in (venue / "ws_map").rglob("*")) == before  # read-only


def _errors(out: str) -> dict[str, float]:
    m = re.search(r"mean ([\d.]+), median ([\d.]+), p90 ([\d.]+)", out)
    assert m, out
    return {"mean": float(m[1]), "median": float(m[2]), "p90": float(m[3])}


@pytest.mark.parametrize("name", ["knn", "wknn"])
def test_localize_cli_matches_evaluate_on_the_test_walks(venue: Path, tmp_path: Path, capsys, name: str) -> None:
    """`localize` of the test walks against a map of the map walks vs `evaluate` holding them out: the
    same scans are scored, and the errors agree within what a map optimised without the test walks (and
    rasterised in its own frame rather than the truth's) changes."""
    import json

    out = tmp_path / "pos.parquet"
    r = run_cli(capsys, "localize", "-w", venue / "ws_map", venue / "test_in", "-o", out, "--localizer", name)
    assert r.code == 0, r.err
    got = _errors(r.out)
    ev = json.loads((venue / "ws_all" / "evaluate" / "report.json").read_text())["maps"]["built"][name]
    table = pd.read_parquet(out)
    assert table["error_m"].notna().sum() == ev["n"] == 13
    assert abs(got["median"] - ev["median"]) < 1.0 and abs(got["mean"] - ev["mean"]) < 1.0
    assert list(table.columns[:6]) == ["walk_id", "t_s", "x_m", "y_m", "uncertainty_m", "n_aps"]


def test_localize_bare_scans_and_csv(venue: Path, tmp_path: Path, capsys) -> None:
    scans = tmp_path / "scans"
    scans.mkdir()
    wifi = pd.read_csv(venue / "test_in" / "wifi.csv")
    wifi.to_csv(scans / "wifi.csv", index=False)
    truth = pd.read_csv(venue / "test_in" / "truth" / "poses.csv")  # every true pose as a fix: the ground truth
    truth[["walk_id", "t_s", "x_m", "y_m"]].to_csv(scans / "fixes.csv", index=False)
    out = tmp_path / "pos.csv"
    r = run_cli(capsys, "localize", "-w", venue / "ws_map", scans, "-o", out)
    assert r.code == 0, r.err
    assert "13 scans of 1 walk(s) (bare scans: no steps)" in r.out
    table = pd.read_csv(out)
    assert len(table) == wifi.groupby(["walk_id", "t_s"]).ngroups
    assert table["x_m"].notna().all() and table["error_m"].notna().all()
    # the same scans read as a walk localize to the same place (kNN ignores the steps)
    walk = tmp_path / "walk.csv"
    assert run_cli(capsys, "localize", "-w", venue / "ws_map", venue / "test_in", "-o", walk).code == 0
    w = pd.read_csv(walk)
    merged = table.merge(w, on=["walk_id", "t_s"], suffixes=("", "_walk"))
    assert len(merged) >= 0.9 * len(w)
    np.testing.assert_allclose(merged["x_m"], merged["x_m_walk"], atol=1e-3)
    np.testing.assert_allclose(merged["error_m"], merged["error_m_walk"], atol=0.05)


@pytest.mark.parametrize("case", ["suffix", "exists", "no_input", "no_map", "bad_row", "bad_config"])
def test_localize_bad_input_is_one_line_exit_2(venue: Path, tmp_path: Path, capsys, case: str) -> None:
    ws, inp, out = venue / "ws_map", venue / "test_in", tmp_path / "pos.csv"
    extra: list = []
    if case == "suffix":
        out = tmp_path / "pos.txt"
    elif case == "exists":
        out.write_text("mine\n")
    elif case == "no_input":
        inp = tmp_path / "missing"
    elif case == "no_map":
        ws = tmp_path / "ws"
        shutil.copytree(venue / "ws_map", ws, ignore=shutil.ignore_patterns("map"))
    elif case == "bad_row":
        inp = tmp_path / "scans"
        inp.mkdir()
        wifi = pd.read_csv(venue / "test_in" / "wifi.csv")
        wifi.loc[3, "rssi_dbm"] = 20.0
        wifi.to_csv(inp / "wifi.csv", index=False)
    elif case == "bad_config":
        cfg = tmp_path / "c.toml"
        cfg.write_text("[evaluate.knn]\nk = 0\n")
        extra = ["--config", cfg]
    r = run_cli(capsys, "localize", "-w", ws, inp, "-o", out, *extra)
    assert r.code == 2, (r.code, r.err)
    assert r.err.startswith("error: ") and r.err.count("\n") == 1 and "Traceback" not in r.err
    if case == "bad_row":
        assert "wifi.csv:5" in r.err
    if case == "exists":
        assert out.read_text() == "mine\n" and "--force" in r.err
    if case == "no_map":
        assert "export-map" in r.err


def test_diff_map_cli(venue: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "diff.csv"
    r = run_cli(capsys, "diff-map", venue / "ws_all", venue / "ws_map", "-o", out)
    assert r.code == 0, r.err
    table = pd.read_csv(out)
    assert set(table["status"]) <= {"both", "gone", "appeared", "moved"} and (table["status"] == "both").sum() > 20
    assert f"{len(table)} in A" in r.out or "in A" in r.out
    r = run_cli(capsys, "diff-map", venue / "ws_all", tmp_path / "nope")
    assert r.code == 2 and r.err.count("\n") == 1 and "not an rmbuild workspace" in r.err


def test_api_errors_and_walks_table(venue: Path, tmp_path: Path) -> None:
    from rmbuild import api
    from rmbuild.errors import InputError, WorkspaceError

    with pytest.raises(WorkspaceError, match="not an rmbuild workspace"):
        api.open_workspace(tmp_path / "nope")
    ws = api.open_workspace(venue / "ws_all")
    walks = ws.walks()
    assert list(walks.columns[:3]) == ["walk_id", "step", "node"] and (walks["node"] == np.arange(len(walks))).all()
    err = np.hypot(walks["x_m"] - walks["x_true_m"], walks["y_m"] - walks["y_true_m"])
    assert err.notna().all()  # true poses ride along (in the building frame, the estimate in the map's)
    with pytest.raises(InputError, match="unknown walk 'w999'"):
        ws.scans(["w999"])
    q = ws.scans(["w004"], ws.radio_map())
    assert len(q) == 13 and q.steps is not None and len(q.steps["w004"]) > 10
    assert "knn" in api.localizer_names() and "slac" in api.localizer_names()


def test_a_scan_hearing_no_map_ap_gets_no_estimate(venue: Path, tmp_path: Path, capsys) -> None:
    scans = tmp_path / "scans"
    scans.mkdir()
    wifi = pd.read_csv(venue / "test_in" / "wifi.csv")
    stranger = pd.DataFrame({"walk_id": "w004", "t_s": 999.0, "bssid": "02:00:00:00:00:01", "rssi_dbm": -50.0},
                            index=[0])
    pd.concat([wifi[["walk_id", "t_s", "bssid", "rssi_dbm"]], stranger]).to_csv(scans / "wifi.csv", index=False)
    out = tmp_path / "pos.csv"
    r = run_cli(capsys, "localize", "-w", venue / "ws_map", scans, "-o", out)
    assert r.code == 0, r.err
    assert "1 without an estimate" in r.out
    t = pd.read_csv(out).set_index("t_s")
    assert np.isnan(t.loc[999.0, "x_m"]) and t.loc[999.0, "n_aps"] == 0 and t["x_m"].notna().sum() == len(t) - 1


def test_localizing_walks_of_the_map_warns(venue: Path, tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "localize", "-w", venue / "ws_all", venue / "test_in", "-o", tmp_path / "p.csv")
    assert r.code == 0 and "among the map's own walks (w004)" in r.err
    r = run_cli(capsys, "localize", "-w", venue / "ws_map", venue / "test_in", "-o", tmp_path / "q.csv")
    assert r.code == 0 and "own walks" not in r.err


@pytest.mark.parametrize("name", ["knn", "wknn"])
def test_localize_hold_out_gives_evaluates_per_scan_errors(venue: Path, tmp_path: Path, capsys, name: str) -> None:
    """`localize --hold-out` of a workspace's test walks (re-read from their input files) gives the per-scan
    positions and errors `evaluate --test-walks` gives them on the workspace's built map."""
    ws = venue / "ws_all"
    from rmbuild.config import EvaluateConfig
    from rmbuild.evaluate.localization import evaluate
    from rmbuild.io.map_store import read_map_config
    from rmbuild.stages.mapping import built_positions

    w = Workspace.open(ws)
    ds, fp, mcfg = w.read_dataset(), w.read_fingerprints(), read_map_config(w)
    xy, info = built_positions(w, ds, mcfg)
    res = evaluate(ds, fp, xy, EvaluateConfig(localizers=(name,)), test_walks=["w004"], gauge=info["gauge"],
                   map_cfg=mcfg)
    out = tmp_path / "pos.parquet"
    r = run_cli(capsys, "localize", "-w", ws, venue / "test_in", "-o", out, "--localizer", name, "--hold-out")
    assert r.code == 0, r.err
    assert "own walks" not in r.err and "evaluate's built map of the other 4 walks" in r.out
    table = pd.read_parquet(out)
    np.testing.assert_allclose(table["t_s"], res.query.t_s)
    np.testing.assert_allclose(table[["x_m", "y_m"]].to_numpy(), res.predictions["built"][name], atol=1e-9)
    np.testing.assert_allclose(table["error_m"], res.errors["built"][name], atol=1e-9)
    assert table["error_m"].notna().sum() == res.stats["built"][name]["n"] == 13


def test_localize_hold_out_needs_workspace_walks(venue: Path, tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "localize", "-w", venue / "ws_map", venue / "test_in", "-o", tmp_path / "p.csv",
                "--hold-out")
    assert r.code == 2 and r.err.count("\n") == 1 and "input walk 'w004' is not a walk of the workspace" in r.err
