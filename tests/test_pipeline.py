"""End to end through the real CLI on the tiny venue: every stage, its outputs, reports and bad input."""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild.io.workspace import Workspace


@pytest.fixture(scope="module")
def tiny_ws(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("pipe")
    from rmbuild.cli import main

    for args in (["simulate", base / "in", "--preset", "tiny", "--seed", "5", "-q"],
                 ["ingest", base / "in", "-w", base / "ws", "-q"],
                 ["optimize", "-w", base / "ws", "-q", "--rerun", base / "opt.rrd"],
                 ["export-map", "-w", base / "ws", "-q"],
                 ["evaluate", "-w", base / "ws", "-q"]):
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0, args
    return base


def test_every_stage_wrote_its_outputs(tiny_ws: Path) -> None:
    ws = Workspace.open(tiny_ws / "ws")
    for stage in ("ingest", "optimize", "map", "evaluate"):
        assert ws.has(stage) and ws.report_path(stage).exists(), stage
    opt = json.loads(ws.report_path("optimize").read_text())
    assert set(opt) >= {"factors", "walks", "poses", "time_s", "raw", "optimized"}
    assert set(opt["factors"]) >= {"odometry", "vicinity", "prior"}
    assert opt["factors"]["odometry"] == opt["poses"] - opt["walks"]
    assert opt["poses_solved"] <= opt["poses"]
    assert opt["metrics_alignment"] == {"fitted_on": "linked walks", "walks": opt["linked_walks"]}
    assert set(opt["raw"]) == {"ate_m", "landmark_error_m", "heading_alignment_error_deg"}
    assert set(opt["optimized"]) == set(opt["raw"]) | {"landmark_error_fitted_walks_m",
                                                       "landmark_error_unlinked_at_raw_m"}
    # the optimised walks are far better placed than the raw ones on the synthetic venue
    assert opt["optimized"]["ate_m"]["rmse"] < 0.2 * opt["raw"]["ate_m"]["rmse"]
    tum = sorted((tiny_ws / "ws" / "optimize" / "tum").glob("*.txt"))
    assert len(tum) == opt["walks"] and len(tum[0].read_text().splitlines()[0].split()) == 8
    assert (tiny_ws / "opt.rrd").stat().st_size > 0


def test_map_outputs(tiny_ws: Path) -> None:
    ws = Workspace.open(tiny_ws / "ws")
    cells = ws.read_table("map.cells")
    assert len(cells) > 0 and (cells["count"] >= 1).all()
    wide = pd.read_csv(ws.path("map.wide_csv"))
    assert "LONGITUDE" in wide.columns and "LATITUDE" in wide.columns
    waps = [c for c in wide.columns if c.startswith("WAP")]
    assert waps and ((wide[waps] == 100) | (wide[waps] <= 0)).all().all()
    side = ws.read_json("map.sidecar")
    assert side["frame"].startswith("walk:") and side["grid"]["cell_size_m"] == 2.0
    aps = pd.read_csv(ws.path("map.wide_csv_aps"), dtype=str)  # WAPnnn -> BSSID beside the CSV
    assert list(aps["column"]) == waps and aps["bssid"].str.len().min() > 0
    assert dict(zip(aps["column"], aps["bssid"], strict=True)) == side["ap_columns"]
    assert set(wide["FLOOR"]) == {0} and set(wide["BUILDINGID"]) == {0}
    for key in ("map.coverage_png", "map.heatmaps_png"):
        assert ws.path(key).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    hist = ws.read_table("map.histograms")  # the RSS-histogram layer, by walking direction
    assert hist["count"].sum() >= cells["count"].sum() and set(hist["sector"]) <= {-1, 0, 1, 2, 3}
    assert side["histograms"]["bin_db"] == 2.0 and side["histograms"]["n_directions"] == 4


def test_evaluate_report_shape(tiny_ws: Path) -> None:
    ws = Workspace.open(tiny_ws / "ws")
    rep = json.loads(ws.report_path("evaluate").read_text())
    assert rep["gauge"] == "se2" and rep["test_walks"]
    assert set(rep["maps"]) == {"built", "surveyed", "raw"}
    keys = {"mean", "median", "p75", "p90", "rmse", "max", "p_lt_5m", "p_lt_10m", "n"}
    for m in rep["maps"].values():
        for s in m.values():
            assert set(s) >= keys
    # on the tiny venue the built map localizes better than raw walks and near the surveyed map (means:
    # the tiny venue has ~13 test scans, too few for a stable median)
    built, raw, surveyed = (rep["maps"][m]["knn"]["mean"] for m in ("built", "raw", "surveyed"))
    assert built < 0.8 * raw and built < 1.5 * surveyed, (built, raw, surveyed)
    assert ws.path("evaluate.cdf_png").exists()


def test_stage_order_is_enforced(tmp_path: Path, capsys) -> None:
    write_tables(make_input_tables(), tmp_path / "in")
    assert run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws", "-q").code == 0
    for cmd in ("export-map", "evaluate"):
        r = run_cli(capsys, cmd, "-w", tmp_path / "ws")
        assert r.code == 2 and "run `rmbuild optimize" in r.err, r.err
    assert not (tmp_path / "ws" / "map").exists()


def test_bad_cell_size_writes_nothing(tiny_ws: Path, capsys) -> None:
    before = sorted(p.name for p in (tiny_ws / "ws" / "map").iterdir())
    r = run_cli(capsys, "export-map", "-w", tiny_ws / "ws", "--cell-size", "0")
    assert r.code == 2 and "cell_size_m" in r.err and len(r.err.strip().splitlines()) == 1
    assert sorted(p.name for p in (tiny_ws / "ws" / "map").iterdir()) == before


def test_cost_history_says_which_solve_each_iteration_belongs_to(tiny_ws: Path) -> None:
    ws = Workspace.open(tiny_ws / "ws")
    h = ws.read_table("optimize.history")
    rep = json.loads(ws.report_path("optimize").read_text())
    assert h["solve"].iloc[0] == 0 and (np.diff(h["solve"].to_numpy()) >= 0).all()
    assert h["solve"].max() + 1 == rep["solves"] and len(h) == len(rep["cost_history"])


def test_true_paths_are_written_as_tum_beside_the_estimates(tiny_ws: Path) -> None:
    """For `evo_ape tum optimize/tum/truth/<walk>.txt optimize/tum/<walk>.txt -a`: same file names, same
    timestamps (true poses are at the walks' step times)."""
    ws = Workspace.open(tiny_ws / "ws")
    est = pd.read_csv(ws.path("optimize.tum_index"), dtype={"walk_id": str})
    tru = pd.read_csv(ws.path("optimize.tum_truth_index"), dtype={"walk_id": str})
    assert list(tru["walk_id"]) == list(est["walk_id"]) and list(tru["file"]) == list(est["file"])
    for f in est["file"]:
        a = np.loadtxt(ws.path("optimize.tum_dir") / f)
        b = np.loadtxt(ws.path("optimize.tum_truth_dir") / f)
        assert a.shape == b.shape and a.shape[1] == 8 and np.array_equal(a[:, 0], b[:, 0])
        assert np.allclose(np.hypot(b[:, 6], b[:, 7]), 1.0)  # unit quaternions (qz, qw)


def test_the_whole_map_is_one_tum_file_on_a_shared_clock(tiny_ws: Path) -> None:
    """map/evo/: every walk of the map in one file, the walks one after another on one clock, its truth on
    the same clock; one rigid fit of the whole map (evo_ape ... -a) gives optimize's ATE, and the map at
    the waypoints gives its landmark error."""
    from rmbuild.evaluate.trajectory import align_se2
    from rmbuild.io.tum import GAP_S, read_tum

    ws = Workspace.open(tiny_ws / "ws")
    rep, opt = ws.read_report("map"), ws.read_report("optimize")
    est, tru = read_tum(ws.read_text("map.evo_map")), read_tum(ws.read_text("map.evo_truth"))
    assert est.shape == tru.shape and np.array_equal(est[:, 0], tru[:, 0]) and (np.diff(est[:, 0]) > 0).all()
    clock = pd.read_csv(ws.path("map.evo_clock"), dtype={"walk_id": str})
    poses = ws.read_table("optimize.poses")
    assert len(est) == len(poses) and opt["linked_walks"] == opt["walks"] == len(clock)  # every walk in the map
    spans = poses.groupby("walk_id", sort=False)["t_s"].agg(["min", "max"]).loc[clock["walk_id"]]
    off = clock["offset_s"].to_numpy()
    starts, ends = spans["min"].to_numpy() + off, spans["max"].to_numpy() + off
    assert starts[0] == 0.0 and np.allclose(starts[1:] - ends[:-1], GAP_S)  # end to end, never overlapping
    r, t = align_se2(est[:, 1:3], tru[:, 1:3])
    res = np.hypot(*(est[:, 1:3] @ r.T + t - tru[:, 1:3]).T)
    assert np.sqrt((res ** 2).mean()) == pytest.approx(opt["optimized"]["ate_m"]["rmse"], rel=1e-5)
    wp, at = read_tum(ws.read_text("map.evo_waypoints")), read_tum(ws.read_text("map.evo_map_at_waypoints"))
    assert np.array_equal(wp[:, 0], at[:, 0]) and len(wp) == opt["optimized"]["landmark_error_m"]["n"]
    assert rep["evo"]["commands"] == ["evo_ape tum map/evo/truth.txt map/evo/map.txt -a",
                                      "evo_ape tum map/evo/waypoints.txt map/evo/map_at_waypoints.txt -a"]


def test_unknown_localizer_and_test_walk(tiny_ws: Path, capsys) -> None:
    r = run_cli(capsys, "evaluate", "-w", tiny_ws / "ws", "--localizer", "magic")
    assert r.code == 2 and "magic" in r.err
    r = run_cli(capsys, "evaluate", "-w", tiny_ws / "ws", "--test-walks", "nope")
    assert r.code == 2 and "unknown walk 'nope'" in r.err


def test_quiet_keeps_only_warnings_and_errors(tiny_ws: Path, tmp_path: Path, capsys) -> None:
    shutil.copytree(tiny_ws / "ws", tmp_path / "ws")
    for args in (["optimize", "--force"], ["export-map", "--force"], ["evaluate", "--force"],
                 ["report", "--force"]):
        r = run_cli(capsys, *args, "-w", tmp_path / "ws", "-q")
        assert r.code == 0, r.err
        assert r.out == "" and all(ln.startswith("WARNING: ") for ln in r.err.splitlines() if ln.strip()), args


def test_verbose_adds_counts_on_every_stage(tiny_ws: Path, tmp_path: Path, capsys) -> None:
    """-v: each stage logs what it did, with counts (files read, scans searched, LM iterations, scans
    localized per localizer); without it, no such line."""
    shutil.copytree(tiny_ws / "ws", tmp_path / "ws")
    expect = {"ingest": r"reading rmbuild: done in [0-9.]+ s; \d+/\d+ files",
              "optimize": r"Levenberg-Marquardt: done in [0-9.]+ s; \d+ iterations",
              "export-map": r"rasterising: done in",
              "evaluate": r"evaluate: built map, knn: \d+ scans in [0-9.]+ s",
              "report": r"report: walks\.png", "view": r"optimize: done in"}
    for stage, pattern in expect.items():
        args = ([stage, tiny_ws / "in", "-w", tmp_path / "ws2"] if stage == "ingest"
                else [stage, "-w", tmp_path / "ws"])
        args += ["--force"] if stage != "view" else ["--save", tmp_path / "v.rrd", "--force"]
        loud = run_cli(capsys, *args, "-v")
        assert loud.code == 0 and re.search(pattern, loud.err), (stage, loud.err)
        if stage in ("optimize", "evaluate"):  # the default run of the same command has none of it
            plain = run_cli(capsys, *args)
            assert plain.code == 0 and not re.search(pattern, plain.err), stage
            assert len(loud.err.splitlines()) > len(plain.err.splitlines()), stage


def test_list_options_are_repeatable_and_comma_separated(tiny_ws: Path, tmp_path: Path, capsys) -> None:
    shutil.copytree(tiny_ws / "ws", tmp_path / "ws")
    walks = sorted(Workspace.open(tmp_path / "ws").read_table("data.walks")["walk_id"].astype(str))
    r = run_cli(capsys, "evaluate", "-w", tmp_path / "ws", "--force", "-q", "--localizer", "knn,nb",
                "--localizer", "knn", "--test-walks", walks[0], "--test-walks", f"{walks[1]},{walks[0]}")
    assert r.code == 0, r.err
    rep = json.loads(Workspace.open(tmp_path / "ws").report_path("evaluate").read_text())
    assert rep["test_walks"] == walks[:2]
    assert all(set(m) == {"knn", "nb"} for m in rep["maps"].values())
    # a paper baseline runs from `evaluate --localizer`, configured by its [evaluate.baselines.<name>] table
    (tmp_path / "nb.toml").write_text("[evaluate.baselines.nb]\nk = 1\n")
    r = run_cli(capsys, "evaluate", "-w", tmp_path / "ws", "--force", "-q", "--localizer", "nb",
                "--config", tmp_path / "nb.toml")
    assert r.code == 0, r.err
    written = tomllib.loads(Workspace.open(tmp_path / "ws").read_config_text("evaluate") or "")
    assert written["evaluate"]["baselines"]["nb"]["k"] == 1
    r = run_cli(capsys, "evaluate", "-w", tmp_path / "ws", "--force", "--localizer", "knn,magic")
    assert r.code == 2 and "'magic' is not one of" in r.err and len(r.err.strip().splitlines()) == 1


def test_evaluate_without_ground_truth(tmp_path: Path, capsys) -> None:
    tables = make_input_tables(n_walks=3, n_steps=60)
    tables.pop("fixes")
    write_tables(tables, tmp_path / "in")
    for args in (["ingest", tmp_path / "in", "-w", tmp_path / "ws", "-q"], ["optimize", "-w", tmp_path / "ws", "-q"]):
        assert run_cli(capsys, *args).code == 0
    r = run_cli(capsys, "evaluate", "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    assert "not computed" in r.out
    rep = json.loads((tmp_path / "ws" / "evaluate" / "report.json").read_text())
    assert rep["maps"] == {} and "errors" in rep["unavailable"]


def test_rerunning_a_stage_needs_force(tiny_ws: Path, capsys) -> None:
    ws = tiny_ws / "ws"
    before = (ws / "map" / "radiomap.parquet").read_bytes()
    r = run_cli(capsys, "export-map", "-w", ws, "--cell-size", "3")
    assert r.code == 2 and "pass --force" in r.err
    assert (ws / "map" / "radiomap.parquet").read_bytes() == before
    assert run_cli(capsys, "export-map", "-w", ws, "--force", "-q").code == 0


def _optimize_copy(tiny_ws: Path, tmp_path: Path, capsys, grep: str):
    """A copy of the tiny workspace and a function that re-optimizes it (extra CLI args) and returns
    (summary lines containing ``grep``, optimize report, walks table, pairs table)."""
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(tiny_ws / "ws", ws)

    def run(*extra):
        r = run_cli(capsys, "optimize", "-w", ws, "--force", *extra)
        assert r.code == 0, r.err
        rep = json.loads((ws / "optimize" / "report.json").read_text())
        walks = pd.read_parquet(ws / "optimize" / "walks.parquet")
        pairs = pd.read_parquet(ws / "optimize" / "pairs.parquet")
        return [ln for ln in r.out.splitlines() if grep in ln], rep, walks, pairs

    return run


def test_optimize_summary_names_the_fitted_scales(tiny_ws: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    run = _optimize_copy(tiny_ws, tmp_path, capsys, "step-length scale")
    # the tiny venue's walks span less than the default 60 m: nothing fitted, nothing printed
    line, rep, walks, _ = run()
    assert rep["scale"]["estimated"] and rep["scale"]["fitted_walks"] == 0
    assert not walks["scale_fitted"].any() and (walks["scale"] == 1.0).all() and line == []
    # with a 10 m span some are, and the summary gives their range
    from rmbuild.slam import scale

    monkeypatch.setattr(scale, "SCALE_MIN_SPAN_M", 10.0)
    line, rep, walks, _ = run()
    fitted = walks.loc[walks["scale_fitted"], "scale"]
    assert len(fitted) > 0 and rep["scale"]["fitted_walks"] == len(fitted)
    assert line == [f"  step-length scale fitted on {len(fitted)} walk(s): {fitted.min():.3f}-{fitted.max():.3f} "
                    "(optimize/walks.parquet: scale)"]


def test_optimize_summary_names_the_anisotropic_pairs(tiny_ws: Path, tmp_path: Path, capsys) -> None:
    run = _optimize_copy(tiny_ws, tmp_path, capsys, "anisotropic pairs")
    # a fixed ratio: every (anti)parallel pair of the final solve is anisotropic and the summary says so
    cfg = tmp_path / "aniso.toml"
    cfg.write_text("[optimize.wifi]\nacross_ratio = 0.4\n")
    line, rep, _, pairs = run("--config", cfg)
    n = int(pairs["anisotropic"].sum())
    assert n > 0 and rep["vicinity"]["anisotropic_pairs"] == n
    assert rep["vicinity"]["across_ratio"] == 0.4 and not rep["vicinity"]["estimated"]
    assert line == [f"  anisotropic pairs: {n} of {rep['factors']['vicinity']}, sigma across/along 0.40 "
                    "(set; optimize/pairs.parquet: anisotropic)"]
    # isotropic: none, and no line
    cfg.write_text("[optimize.wifi]\nacross_ratio = 1.0\n")
    line, rep, _, pairs = run("--config", cfg)
    assert line == [] and not pairs["anisotropic"].any() and rep["vicinity"]["anisotropic_pairs"] == 0


def test_optimize_with_anchors_file(tiny_ws: Path, tmp_path: Path, capsys) -> None:
    """`optimize --anchors`: true positions at both ends of every walk fix the map in the building frame."""
    run = _optimize_copy(tiny_ws, tmp_path, capsys, "anchor")
    truth = Workspace.open(tiny_ws / "ws").read_dataset().truth_poses
    assert truth is not None
    ends = truth.groupby("walk_id", sort=False).nth([0, -1])[["walk_id", "t_s", "x_m", "y_m"]]
    f = tmp_path / "anchors.csv"
    ends.to_csv(f, index=False)
    _, rep, _, _ = run("--anchors", f)
    # the tiny venue's walks land within a metre or two of the truth (median 0.5 m, rmse 1.1 m)
    assert rep["gauge"] == "anchors" and rep["optimized"]["ate_m"]["median"] < 1.0, rep["optimized"]["ate_m"]
    assert len(Workspace.open(tmp_path / "ws").read_table("optimize.anchors")) == len(ends)


def test_tum_text_is_one_line_per_pose_with_six_decimals() -> None:
    """t x y z qx qy qz qw per pose, each "%.6f" (as f"{v:.6f}"): planar, so z = qx = qy = 0 and the
    quaternion is the heading's half-angle."""
    from rmbuild.io.tum import tum_texts

    poses = pd.DataFrame({"t_s": [1.5, 1234567.0000004, 3.0], "x_m": [-0.0, 2.25, 1.0], "y_m": [1e-7, -3.0, 0.0],
                          "heading_rad": [0.0, np.pi, 0.0]})
    texts = tum_texts(poses, pd.Series(["a", "a", "b"]))
    assert texts["a"] == ("1.500000 -0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 1.000000\n"
                          "1234567.000000 2.250000 -3.000000 0.000000 0.000000 0.000000 1.000000 0.000000\n")
    assert texts["b"].startswith("3.000000 1.000000") and tum_texts(poses.iloc[:0], pd.Series([], dtype=str)) == {}
