"""`rmbuild optimize --incremental`: walks appended after an optimize placed against its solution; and the
GeoJSON output of `rmbuild localize`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli, split_input

from rmbuild.errors import InputError
from rmbuild.io.workspace import Workspace

pytest.importorskip("gtsam")



@pytest.fixture(scope="module")
def venue(tmp_path_factory) -> dict:
    """The small synthetic venue split 80/20 in walk order: ``base`` (old part optimised, new part appended,
    not optimised again), ``inc`` (a copy optimised with --incremental), ``full`` (a copy optimised in full)."""
    from rmbuild.cli import main
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate

    root = tmp_path_factory.mktemp("incremental")
    simulate.run(root / "all", preset_config("tiny", 5))
    ids = pd.read_csv(root / "all" / "walks.csv", dtype={"walk_id": str})["walk_id"].tolist()
    k = int(len(ids) * 0.8)
    old = split_input(root / "all", root / "old", set(ids[:k]))
    new = split_input(root / "all", root / "new", set(ids[k:]))

    def run(*args) -> None:
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0, args

    base = root / "base"
    run("ingest", old, "-w", base, "-q")
    run("optimize", "-w", base, "-q")
    run("ingest", "--append", new, "-w", base, "-q")
    shutil.copytree(base, root / "inc")
    shutil.copytree(base, root / "full")
    run("optimize", "-w", root / "inc", "--incremental", "-q")
    run("optimize", "-w", root / "full", "--force", "-q")
    return {"root": root, "base": base, "inc": root / "inc", "full": root / "full", "old_ids": ids[:k],
            "new_ids": ids[k:]}


def _report(ws: Path) -> dict:
    return json.loads((ws / "optimize" / "report.json").read_text())


def test_incremental_places_the_new_walks_about_as_well_as_a_full_run(venue: dict) -> None:
    inc, full = _report(venue["inc"]), _report(venue["full"])
    assert inc["incremental"]["new_walks"] == venue["new_ids"]
    assert inc["incremental"]["new_walks_placed"] == len(venue["new_ids"])
    assert inc["linked_walks"] >= full["linked_walks"] - 1
    a_inc, a_full = inc["optimized"]["ate_m"]["rmse"], full["optimized"]["ate_m"]["rmse"]
    assert a_inc < inc["raw"]["ate_m"]["rmse"] / 2  # far better than dead reckoning
    assert a_inc < 1.15 * a_full + 0.2, (a_inc, a_full)
    assert inc["incremental"]["gave_up"] is None  # the new walks agree with the held map here
    walks = Workspace.open(venue["inc"]).read_table("optimize.walks")
    held = walks["placement"].eq("held") | walks["placement"].eq("reference")
    assert set(walks.loc[held, "walk_id"]) <= set(venue["old_ids"])
    assert "incremental" not in full


def test_incremental_keeps_the_old_solution_and_export_map_runs(venue: dict, capsys) -> None:
    before = Workspace.open(venue["base"]).read_table("optimize.poses")
    after = Workspace.open(venue["inc"]).read_table("optimize.poses")
    n_old = len(before)
    held = before["linked"].to_numpy()
    assert np.allclose(after[["x_m", "y_m", "heading_rad"]].to_numpy()[:n_old][held],
                       before[["x_m", "y_m", "heading_rad"]].to_numpy()[held], atol=1e-4)  # held by 1 mm priors
    assert after["linked"].to_numpy()[n_old:].all()
    r = run_cli(capsys, "export-map", "-w", venue["inc"], "-q")
    assert r.code == 0, r.err


def test_incremental_refuses_bad_use(venue: dict, capsys, tmp_path: Path) -> None:
    # nothing appended since the last optimize
    r = run_cli(capsys, "optimize", "-w", venue["inc"], "--incremental", "-q")
    assert r.code == 2 and "nothing to add" in r.err and len(r.err.strip().splitlines()) == 1
    # no optimize at all
    bare = tmp_path / "bare"
    assert run_cli(capsys, "ingest", venue["root"] / "old", "-w", bare, "-q").code == 0
    r = run_cli(capsys, "optimize", "-w", bare, "--incremental", "-q")
    assert r.code == 2 and "needs an earlier optimize" in r.err and "Traceback" not in r.err
    # anchors name a frame: a full run's business
    anchors = tmp_path / "a.csv"
    anchors.write_text("walk_id,t_s,x_m,y_m\n")
    r = run_cli(capsys, "optimize", "-w", venue["base"], "--incremental", "--anchors", anchors, "-q")
    assert r.code == 2 and "--anchors" in r.err


def test_incremental_refuses_a_solution_of_other_walks(venue: dict) -> None:
    from dataclasses import replace

    from rmbuild.config import OptimizeConfig
    from rmbuild.slam import optimize
    from rmbuild.slam.held import HeldMap

    ws = Workspace.open(venue["base"])
    ds, fp = ws.read_dataset(), ws.read_fingerprints()
    state = ws.read_optimize_state()
    xyt = ws.read_table("optimize.poses")[["x_m", "y_m", "heading_rad"]].to_numpy(float)
    other = replace(state, walk_ids=tuple(reversed(state.walk_ids)))
    with pytest.raises(InputError, match="other walks"):
        optimize(ds, fp, OptimizeConfig(), held=HeldMap(other, xyt))
    full = Workspace.open(venue["full"])
    every = HeldMap(full.read_optimize_state(), full.read_table("optimize.poses")[["x_m", "y_m", "heading_rad"]]
                    .to_numpy(float))
    with pytest.raises(InputError, match="no new walks"):
        optimize(ds, fp, OptimizeConfig(), held=every)


def test_the_optimize_state_is_typed_versioned_and_read_by_the_map(venue: dict, tmp_path: Path, capsys) -> None:
    from rmbuild.errors import WorkspaceError
    from rmbuild.types import OptimizeState

    ws = Workspace.open(venue["full"])
    state = ws.read_optimize_state()
    assert OptimizeState.from_json(state.to_json()) == state
    assert state.n_nodes == len(ws.read_table("optimize.poses")) and state.walk_ids[0] in state.linked_walks
    assert state.gauge == _report(venue["full"])["gauge"]
    from rmbuild.io.workspace import parse_optimize_state

    with pytest.raises(WorkspaceError, match="state.json: state version 99"):
        parse_optimize_state({**state.to_json(), "version": 99}, "state.json")
    with pytest.raises(WorkspaceError, match="malformed"):
        parse_optimize_state({**state.to_json(), "rf_model": [1.0]}, "state.json")


def test_the_held_check_gives_up_when_held_walks_would_move_or_placements_are_refuted() -> None:
    from rmbuild.slam.placement import heldcheck
    from rmbuild.slam.placement.model import Placement

    class _Walks:
        n_walks, keep, walk_ids = 6, np.ones(6, bool), list("abcdef")

    fixed = np.array([1, 1, 1, 0, 0, 0], bool)
    pl = Placement(np.zeros((6, 3)), np.zeros(6, np.int64), 0, np.ones(6, bool), np.full(6, "se2", object),
                   fixed=fixed)
    pred = np.array([2.0, 5.0, np.nan, np.nan, np.nan, np.nan])
    ok = heldcheck.check(_Walks(), pl, {0: 1.0, 1: 4.0, 2: 2.9}, pred)  # none beyond max(predicted, 3 m)
    assert ok.reason is None and ok.moved == []
    moved = heldcheck.check(_Walks(), pl, {0: 3.5, 1: 4.0, 2: 2.9}, pred)
    assert moved.moved == [0] and "1 of the 3 held walks" in moved.reason
    pl.refuted = [4]
    pl.component[4] = 1
    refuted = heldcheck.check(_Walks(), pl, {}, pred)
    assert refuted.refuted == 1 and refuted.placed == 3 and "RF check" in refuted.reason


# ---------------------------------------------------------------------------------------- localize GeoJSON
def test_append_warns_when_the_new_walks_hear_other_access_points() -> None:
    from rmbuild.stages.append import shared_aps
    from rmbuild.types import Dataset

    def ds(walks: list[str], bssids: list[str]) -> Dataset:
        wifi = pd.DataFrame({"walk_id": walks, "bssid": bssids})
        return Dataset(walks=pd.DataFrame({"walk_id": sorted(set(walks))}), poses=pd.DataFrame(), wifi=wifi,
                       fixes=pd.DataFrame())

    old = ds(["o"] * 4, ["a", "b", "c", "d"])
    figures, warning = shared_aps(old, ds(["n1", "n1", "n2", "n2"], ["a", "b", "x", "y"]))
    assert figures["readings_known_share"] == 0.5 and figures["walks_below_share"] == 1
    assert warning is not None and "1 of 2 new walk(s) (n2)" in warning and "BSSIDs" in warning
    assert shared_aps(old, ds(["n1", "n1"], ["a", "c"]))[1] is None


def test_the_package_exports_resolve_lazily() -> None:
    import rmbuild.slam as slam
    from rmbuild.slam.pipeline import optimize
    from rmbuild.slam.result import OptimizeResult

    assert slam.optimize is optimize and slam.OptimizeResult is OptimizeResult
    with pytest.raises(AttributeError):
        _ = slam.no_such_name


def test_geojson_features_carry_lonlat_and_the_scan_properties() -> None:
    from rmbuild.floorplan import Georef
    from rmbuild.stages.localize_geojson import feature_collection

    table = pd.DataFrame({"walk_id": ["a", "a", "b"], "t_s": [1.0, 2.0, 3.0], "x_m": [0.0, 100.0, np.nan],
                          "y_m": [0.0, 0.0, np.nan], "uncertainty_m": [2.0, 3.0, np.nan], "n_aps": [5, 6, 0]})
    fc = feature_collection(table, Georef("enu", 2.35, 48.85), "F1")
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == 3
    f0, f1, f2 = fc["features"]
    assert np.allclose(f0["geometry"]["coordinates"], [2.35, 48.85], atol=1e-7)
    # 100 m east at 48.85 N: 100 / (6378137 cos(lat)) rad of longitude, latitude unchanged
    dlon = np.degrees(100.0 / (6378137.0 * np.cos(np.radians(48.85))))
    assert f1["geometry"]["coordinates"][0] - 2.35 == pytest.approx(dlon, rel=0.01)
    assert f1["geometry"]["coordinates"][1] == pytest.approx(48.85, abs=1e-5)
    assert f1["properties"] == {"walk": "a", "time": 2.0, "uncertainty": 3.0, "floor": "F1", "x_m": 100.0, "y_m": 0.0}
    assert f2["geometry"] is None and f2["properties"]["uncertainty"] is None
    json.dumps(fc, allow_nan=False)  # valid JSON: no NaN


def test_localize_geojson_needs_a_georeferenced_map(venue: dict, capsys, tmp_path: Path, monkeypatch) -> None:
    ws = venue["inc"]
    if not (ws / "map").exists():
        assert run_cli(capsys, "export-map", "-w", ws, "-q").code == 0
    out = tmp_path / "pos.geojson"
    r = run_cli(capsys, "localize", venue["root"] / "new", "-w", ws, "-o", out, "-q")
    assert r.code == 2 and "georeferenced" in r.err and len(r.err.strip().splitlines()) == 1
    assert not out.exists()
    # with a georeference (here patched in), the same call writes one point per scan
    from rmbuild.config import EvaluateConfig
    from rmbuild.floorplan import Georef
    from rmbuild.stages import localize, localize_geojson

    monkeypatch.setattr(localize_geojson, "map_georef", lambda ws, rm: (Georef("enu", 2.35, 48.85), "plan"))
    rep = localize.run(ws, [venue["root"] / "new"], out, EvaluateConfig())
    fc = json.loads(out.read_text())
    assert len(fc["features"]) == rep["scans"] > 0
    pts = np.array([f["geometry"]["coordinates"] for f in fc["features"] if f["geometry"]])
    assert np.all(np.abs(pts - [2.35, 48.85]).max(axis=0) < 0.01)  # within a kilometre of the origin
    assert {f["properties"]["floor"] for f in fc["features"]} == {"plan"}
    assert {f["properties"]["walk"] for f in fc["features"]} == set(venue["new_ids"])


def test_the_summary_counts_the_held_walks_among_the_placed() -> None:
    from rmbuild.cli.optimize import _kinds

    line = _kinds({"held": {"walks": 47, "median_predicted_error_m": 21.1},
                   "wifi": {"walks": 8, "median_predicted_error_m": 3.2}, "left out": {"walks": 3}})
    assert "the last optimize (held) 47 walk(s) (median predicted error 21.1 m)" in line
    assert "Wi-Fi fits 8 walk(s)" in line and "left out: 3 walk(s)" in line
