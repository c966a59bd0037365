"""Buildings: inputs of several floors become one workspace per floor; every stage runs per floor exactly as
on a single-floor workspace; evaluate classifies the floor of each test scan."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import SHARED_DATASETS, make_input_tables, write_tables

from rmbuild.config import EvaluateConfig, IngestConfig, MapConfig, OptimizeConfig
from rmbuild.config.simulate import preset_config
from rmbuild.errors import InputError
from rmbuild.ingest.floors import floor_level, split_floors
from rmbuild.io.formats import choose_reader, expand_inputs
from rmbuild.io.workspace import building_floors, building_report_path
from rmbuild.stages import evaluate, export_map, ingest, optimize, simulate


def test_floor_levels() -> None:
    assert [floor_level(n) for n in ("B2", "B1", "F1", "1F", "L3", "G", "-2", "4", "mezzanine")] == \
        [-2, -1, 0, 0, 2, 0, -2, 4, None]


def _raw(tables: dict[str, pd.DataFrame], tmp: Path):
    files = expand_inputs([write_tables(tables, tmp)])
    return choose_reader(files, None).read(files, IngestConfig())


def test_walk_floors_split_by_walk(tmp_path: Path) -> None:
    t = make_input_tables(n_walks=3)
    t["walks"]["floor"] = ["F1", "F2", "F1"]
    parts = split_floors(_raw(t, tmp_path))
    assert parts is not None and list(parts) == ["F1", "F2"]
    assert list(parts["F1"].walks["walk_id"]) == ["walk0", "walk2"]
    assert set(parts["F2"].wifi["walk_id"]) == {"walk1"} and "floor" not in parts["F2"].walks
    assert len(parts["F1"].poses) + len(parts["F2"].poses) == len(t["poses"])
    # error messages still name the input's rows
    assert parts["F2"].where["wifi"](0).endswith(f":{1 + int(np.flatnonzero(t['wifi']['walk_id'] == 'walk1')[0]) + 1}")


def test_pose_floors_cut_a_walk_at_each_change(tmp_path: Path) -> None:
    t = make_input_tables(n_walks=2, n_steps=30)
    t["poses"]["floor"] = "F1"
    w0 = np.flatnonzero(t["poses"]["walk_id"] == "walk0")
    t["poses"].loc[w0[10:20], "floor"] = "F2"  # walk0: F1, F2, F1 again
    parts = split_floors(_raw(t, tmp_path))
    assert parts is not None
    assert list(parts["F1"].walks["walk_id"]) == ["walk0@F1", "walk0@F1#2", "walk1"]
    assert list(parts["F2"].walks["walk_id"]) == ["walk0@F2"]
    f2 = parts["F2"]
    t0, t1 = t["poses"]["t_s"].iloc[w0[10]], t["poses"]["t_s"].iloc[w0[20]]
    assert len(f2.poses) == 10 and f2.wifi["t_s"].between(t0, t1, inclusive="left").all()
    n_w0 = (t["wifi"]["walk_id"] == "walk0").sum()
    assert sum((p.wifi["walk_id"].str.startswith("walk0")).sum() for p in parts.values()) == n_w0


def test_single_floor_or_no_floor_stays_flat(tmp_path: Path) -> None:
    t = make_input_tables()
    assert split_floors(_raw(t, tmp_path / "a")) is None
    t["walks"]["floor"] = "F3"
    raw = _raw(t, tmp_path / "b")
    assert split_floors(raw) is None and "floor" not in raw.walks


def test_a_walk_without_floor_among_floors_is_an_error(tmp_path: Path) -> None:
    t = make_input_tables(n_walks=3)
    t["walks"]["floor"] = ["F1", "F2", ""]
    t["walks"] = t["walks"].astype(object)
    t["poses"]["floor"] = np.where(t["poses"]["walk_id"] == "walk0", "F1", "")
    with pytest.raises(InputError, match="without a floor"):
        split_floors(_raw(t, tmp_path))


# ---------------------------------------------------------------- a synthetic building of two floors
def _two_floor_input(base: Path) -> dict[str, Path]:
    """A simulated building of two tiny floors (each floor's APs heard on the other through the floor; no walk
    changes floor, so each floor's part of the files is its walks'), and each floor's part of its files alone."""
    cfg = preset_config("tiny", 5)
    cfg = replace(cfg, building=replace(cfg.building, floors=2, floor_change_walks=0))
    simulate.run(base / "both", cfg)
    out = {"both": base / "both"}
    tables = {str(f.relative_to(base / "both")): pd.read_csv(f, dtype={"walk_id": str, "floor": str})
              for f in sorted((base / "both").rglob("*.csv"))}
    for name in ("F1", "F2"):
        walks = set(tables["walks.csv"].loc[tables["walks.csv"]["floor"] == name, "walk_id"])
        out[name] = base / name
        for rel, df in tables.items():
            if "floor" in df and rel != "walks.csv":
                df = df[df["floor"] == name].drop(columns=["floor"])
            elif "walk_id" in df:
                df = df[df["walk_id"].isin(walks)]
            (out[name] / rel).parent.mkdir(parents=True, exist_ok=True)
            df.to_csv(out[name] / rel, index=False)
        shutil.copy(base / "both" / "truth" / "venue.json", out[name] / "truth" / "venue.json")
    return out


@pytest.fixture(scope="module")
def building(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("floors")
    inputs = _two_floor_input(base)
    out = {}
    for key, d in inputs.items():
        ws = base / f"ws_{key}"
        ingest.run([d], ws, IngestConfig())
        optimize.run(ws, OptimizeConfig())
        export_map.run(ws, MapConfig())
        evaluate.run(ws, EvaluateConfig())
        out[key] = ws
    return out


def test_building_workspace_has_one_workspace_per_floor(building: dict[str, Path]) -> None:
    floors = building_floors(building["both"])
    assert floors is not None and list(floors) == ["F1", "F2"]
    assert building_floors(building["F1"]) is None
    rep = json.loads(building_report_path(building["both"], "ingest").read_text())
    single = {f: json.loads((building[f] / "data" / "report.json").read_text()) for f in ("F1", "F2")}
    assert rep["building"]["walks"] == sum(s["walks"] for s in single.values())
    for f in ("F1", "F2"):
        assert rep["floors"][f]["walks"] == single[f]["walks"]
        assert rep["floors"][f]["scans"] == single[f]["scans"]


def test_every_floor_equals_its_single_floor_run(building: dict[str, Path]) -> None:
    floors = building_floors(building["both"]) or {}
    for f in ("F1", "F2"):
        for stage_dir, keys in (("optimize", ("optimized", "raw", "factors")), ("map", ("cells", "aps")),
                                ("evaluate", ("maps", "test_walks"))):
            a = json.loads((floors[f] / stage_dir / "report.json").read_text())
            b = json.loads((building[f] / stage_dir / "report.json").read_text())
            for k in keys:
                assert a[k] == b[k], (f, stage_dir, k)


def test_evaluate_classifies_floors(building: dict[str, Path]) -> None:
    rep = json.loads(building_report_path(building["both"], "evaluate").read_text())
    b = rep["building"]
    fc = b["floor_classification"]
    assert fc["hit_rate"] >= 0.99 and fc["n"] == sum(r["n_queries"] for r in rep["floors"].values())
    assert set(fc["per_floor"]) == {"F1", "F2"} and b["floor_penalty_m"] == 15.0
    s = b["maps"]["built"]["knn"]
    assert s["combined"]["mean"] >= s["xy_correct_floor"]["mean"] - 1.0  # the penalty only adds
    assert s["xy_all_scans"]["n"] == fc["n"]


def test_floor_option_runs_one_floor(building: dict[str, Path]) -> None:
    before = json.loads((building["both"] / "floors" / "F1" / "map" / "report.json").read_text())
    r = export_map.run(building["both"], MapConfig(), force=True, floor="F2")
    assert r["ran_floors"] == ["F2"] and set(r["floors"]) == {"F1", "F2"}
    assert json.loads((building["both"] / "floors" / "F1" / "map" / "report.json").read_text()) == before
    with pytest.raises(InputError, match="no floor 'F9'"):
        export_map.run(building["both"], MapConfig(), force=True, floor="F9")
    with pytest.raises(InputError, match="single-floor"):
        export_map.run(building["F1"], MapConfig(), force=True, floor="F1")


def test_cli_on_a_building(building: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ws = building["both"]
    r = run_cli(capsys, "report", "-w", ws, "--out", tmp_path / "b.html")
    assert r.code == 0, r.err
    page = (tmp_path / "b.html").read_text()
    assert "floor F1" in page and "floor F2" in page and "Floor hit rate" in page
    # the per-floor table evaluate prints, with its figures, and each floor's page beside the building's
    rep = json.loads(building_report_path(ws, "evaluate").read_text())
    median = rep["floors"]["F2"]["maps"]["built"]["knn"]["median"]
    assert "Localization per floor" in page and f"<td class=\"num\">{median:.2f}</td>" in page
    assert 'href="b_floors/F2.html"' in page and (tmp_path / "b_floors" / "F2.html").is_file()
    assert (tmp_path / "b_floors" / "F2_figures" / "walks.png").is_file()
    assert not (ws / "floors" / "F2" / "report.html").exists() and not (ws / "report.html").exists()
    r = run_cli(capsys, "evaluate", "-w", ws, "--floor", "F1", "--force")
    assert r.code == 0, r.err
    assert "floor F1:" in r.out and "floor hit rate" in r.out and "floor F2:" not in r.out
    r = run_cli(capsys, "optimize", "-w", ws, "--rerun", tmp_path / "x.rrd", "--force")
    assert r.code == 2 and "--floor" in r.err


def _building_with_walks(base: Path, keep_on_f2: int) -> Path:
    """The simulated two-floor building with only ``keep_on_f2`` of floor F2's walks kept."""
    cfg = preset_config("tiny", 5)
    simulate.run(base / "sim", replace(cfg, building=replace(cfg.building, floors=2, floor_change_walks=0)))
    walks = pd.read_csv(base / "sim" / "walks.csv", dtype={"walk_id": str, "floor": str})
    drop = set(walks.loc[walks["floor"] == "F2", "walk_id"].iloc[keep_on_f2:])
    for f in sorted((base / "sim").rglob("*.csv")):
        df = pd.read_csv(f, dtype={"walk_id": str, "floor": str})
        if "walk_id" in df:
            df[~df["walk_id"].isin(drop)].to_csv(f, index=False)
    return base / "sim"


def test_evaluate_of_a_building_scores_the_floors_it_can(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A floor with a single walk cannot be split into map and test walks: the building's evaluate scores
    the other floor and names the skipped one, instead of failing whole."""
    ws = tmp_path / "ws"
    inp = _building_with_walks(tmp_path, keep_on_f2=1)
    for args in (["ingest", inp, "-w", ws], ["optimize", "-w", ws], ["export-map", "-w", ws]):
        assert run_cli(capsys, *args, "-q").code == 0
    r = run_cli(capsys, "evaluate", "-w", ws)
    assert r.code == 0, r.err
    assert "floor F1:" in r.out and "floor F2 skipped: evaluation needs at least 2 walks" in r.out
    b = json.loads(building_report_path(ws, "evaluate").read_text())["building"]
    assert list(b["skipped_floors"]) == ["F2"] and b["floor_classification"]["per_floor"].keys() == {"F1"}
    assert run_cli(capsys, "report", "-w", ws, "--out", tmp_path / "b.html").code == 0
    assert "Floors not evaluated" in (tmp_path / "b.html").read_text()
    with pytest.raises(InputError, match="no floor could be evaluated: F2: evaluation needs at least 2 walks"):
        evaluate.run(ws, EvaluateConfig(), floor="F2", force=True)


def test_uji_csv_of_a_floor_carries_its_level(building: dict[str, Path]) -> None:
    from rmbuild.io.workspace import floor_levels

    levels = floor_levels(building["both"])
    assert levels["F2"] != levels["F1"] and levels["F2"] is not None
    for f in ("F1", "F2"):
        csv = pd.read_csv(building["both"] / "floors" / f / "map" / "radiomap_uji.csv")
        assert (csv["FLOOR"] == levels[f]).all()
    # one numbering: the floor ingested alone (its input names it F2) is the same FLOOR as in its building
    assert json.loads((building["F2"] / "data" / "report.json").read_text())["floor"] == "F2"
    assert (pd.read_csv(building["F2"] / "map" / "radiomap_uji.csv")["FLOOR"] == levels["F2"]).all()


def test_localize_on_a_building_takes_one_floor(building: dict[str, Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture) -> None:
    ws, new = building["both"], building["F2"].parent / "F2"
    r = run_cli(capsys, "localize", new, "-w", ws, "-o", tmp_path / "a.csv")
    assert r.code == 2 and "--floor" in r.err and not (tmp_path / "a.csv").exists()
    r = run_cli(capsys, "localize", new, "-w", ws, "-o", tmp_path / "a.csv", "--floor", "F2")
    assert r.code == 0, r.err
    ref = run_cli(capsys, "localize", new, "-w", building["F2"], "-o", tmp_path / "b.csv")
    assert ref.code == 0, ref.err
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()


# ---------------------------------------------------------------- real data: a site at once = its floors
def _ilc_subset(base: Path, site: str, per_floor: int = 2) -> dict[str, Path]:
    """The first ``per_floor`` traces of each floor of an ILC site (with the floor's companion files)."""
    src = SHARED_DATASETS / "msft-ilc20" / "data" / site
    out = {}
    for floor in sorted(p.name for p in src.iterdir() if p.is_dir()):
        d = base / site / floor / "path_data_files"
        d.mkdir(parents=True)
        for f in sorted((src / floor / "path_data_files").iterdir())[:per_floor]:
            shutil.copy(f, d / f.name)
        for f in ("floor_info.json", "geojson_map.json"):
            shutil.copy(src / floor / f, base / site / floor / f)
        out[floor] = base / site / floor
    return out


@pytest.mark.parametrize("site", ["site1", "site2"])
def test_ilc_site_ingest_equals_floor_by_floor(shared_datasets: Path, tmp_path: Path, site: str) -> None:
    floors = _ilc_subset(tmp_path / "in", site)
    rep = ingest.run([tmp_path / "in" / site], tmp_path / "site", IngestConfig(), fmt="msft-ilc")
    assert list(rep["floors"]) == list(floors)
    for name, d in floors.items():
        one = ingest.run([d], tmp_path / name, IngestConfig(), fmt="msft-ilc")
        got = rep["floors"][name]
        for k in ("walks", "poses", "readings", "scans", "aps", "nodes_with_fingerprint"):
            assert got[k] == one[k], (name, k)
        assert got["floorplan"]["name"] == name


def test_simulated_building_hears_other_floors_through_the_floor() -> None:
    from rmbuild.synthetic.building import simulate_building

    cfg = preset_config("tiny", 3)
    d = simulate_building(replace(cfg, building=replace(cfg.building, floors=2, floor_attenuation_db=15.0)))
    assert set(d.walks["floor"]) == {"F1", "F2"} and d.walks["walk_id"].is_unique
    ap_floor = d.truth_aps.set_index("bssid")["floor"]
    w = pd.merge_asof(d.wifi.sort_values("t_s"), d.poses[["walk_id", "t_s", "floor"]].sort_values("t_s"), on="t_s",
                      by="walk_id", direction="nearest")  # the floor of the step nearest each reading
    w = w.assign(ap=w["bssid"].map(ap_floor), at=w["floor"])
    own, other = w[w["ap"] == w["at"]], w[w["ap"] != w["at"]]
    assert len(other) > 0.05 * len(own)  # the floor damps, it does not silence
    assert other["rssi_dbm"].median() < own["rssi_dbm"].median() - 5.0


def test_floor_filter_smooths_an_outlier_and_follows_a_change() -> None:
    from rmbuild.localize.floor import classify_floors

    rng = np.random.default_rng(1)
    n_ap = 12  # APs 0-5 loud on floor 0, 6-11 on floor 1; each floor hears the other's 15 dB lower

    def scans(floor: int, n: int) -> np.ndarray:
        mean = np.where((np.arange(n_ap) < 6) == (floor == 0), -60.0, -75.0)
        return mean + rng.normal(0.0, 3.0, (n, n_ap))

    refs = [scans(0, 40), scans(1, 40)]
    q = np.vstack([scans(0, 10), scans(1, 1), scans(0, 9), scans(1, 10)])  # an outlier scan, then a change
    truth = np.r_[np.zeros(10), 1, np.zeros(9), np.ones(10)].astype(int)
    pred, alone = classify_floors(refs, q, np.zeros(len(q), dtype=object), np.arange(len(q), dtype=float))
    assert (alone == truth).all()  # each scan alone is clear
    assert pred[10] == 0 and (pred[:20] == 0).all()  # one scan does not move the walk to another floor
    assert (pred[22:] == 1).all()  # a lasting change is followed within two scans


def test_ilc_site_ingest_by_floor_folder_tasks_writes_the_same_workspace(shared_datasets: Path,
                                                                          tmp_path: Path) -> None:
    """`build` reads a site's floor folders as one task each (here on the in-process runner): every file of the
    workspace is the same as one read of the whole site gives, the reports (and their digests) but for their
    times."""
    import json

    from rmbuild.config.build import parse_scheduler
    from rmbuild.stages.dask_run import executor

    _ilc_subset(tmp_path / "in", "site2")
    whole = ingest.run([tmp_path / "in" / "site2"], tmp_path / "whole", IngestConfig(), fmt="msft-ilc")
    with executor(parse_scheduler("serial"), None) as runner:
        tasks = ingest.run([tmp_path / "in" / "site2"], tmp_path / "tasks", IngestConfig(), fmt="msft-ilc",
                           runner=runner)
    assert list(tasks["floors"]) == list(whole["floors"]) and len(whole["floors"]) > 1
    assert tasks["notes"] == whole["notes"] and tasks["skipped"] == whole["skipped"]

    def timeless(o):
        if isinstance(o, dict):
            return {k: timeless(v) for k, v in o.items()
                    if k not in ("time_s", "created_utc", "completed_utc") and not k.endswith("report.json")}
        return [timeless(v) for v in o] if isinstance(o, list) else o

    files = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "tasks") for p in (tmp_path / "tasks").rglob("*") if p.is_file())
    for f in files:
        a, b = (tmp_path / "whole" / f).read_bytes(), (tmp_path / "tasks" / f).read_bytes()
        if a != b:
            assert f.suffix == ".json" and timeless(json.loads(a)) == timeless(json.loads(b)), f
