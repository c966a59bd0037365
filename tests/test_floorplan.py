"""Floor plans (rmbuild/floorplan.py) and the plan as evidence (rmbuild/slam/evidence/floorplan.py)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from rmbuild.floorplan import from_features
from tests.ilc_plans import ilc_plan_and_waypoints


def _rect(x0, y0, x1, y1, **props):
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}}


def test_walkable_space_from_features():
    # an outline with a shop cut out, and the same floor given as walkable corridors instead
    cut = from_features([_rect(0, 0, 20, 10, type="floor"), _rect(5, 2, 15, 8, kind="shop")], lambda a: a)
    assert cut.area_m2 == pytest.approx(200 - 60) and cut.bounds == (0, 0, 20, 10)
    corr = from_features([_rect(0, 0, 20, 10, type="floor"), _rect(0, 0, 20, 2, walkable=True),
                          _rect(0, 8, 20, 10, walkable=True), _rect(8, 0, 10, 10, walkable=True),
                          _rect(8.5, 4, 9.5, 6, kind="pillar")], lambda a: a)
    assert corr.area_m2 == pytest.approx(40 + 40 + 12 - 2)
    d = corr.distance(np.array([[9.0, 1.0], [5.0, 5.0], [9.0, 5.0], [30.0, 5.0]]))
    assert d[0] < 0 and d[1] == pytest.approx(3.0, abs=0.5) and d[2] > 0 and d[3] > 9
    assert list(corr.inside(np.array([[9.0, 1.0], [5.0, 5.0]]))) == [True, False]
    with pytest.raises(ValueError):
        from_features([{"type": "Feature", "geometry": {"type": "Point", "coordinates": [0, 0]}}], lambda a: a)


@pytest.mark.realdata
@pytest.mark.parametrize("floor", ["site1/F1", "site2/B1"])
def test_ilc_plan_puts_the_waypoints_in_walkable_space(floor):
    plan, pts, info = ilc_plan_and_waypoints(floor, 15)
    d = plan.distance(np.array(pts))
    assert len(pts) > 50 and np.mean(d <= 0.5) > 0.99  # measured: every waypoint of every floor inside
    lonlat = plan.georef.to_lonlat(np.array([[0.0, 0.0], [info["width"], info["height"]]]))
    assert np.allclose(lonlat[0], plan.georef.bbox[:2], atol=1e-7) and np.allclose(lonlat[1], plan.georef.bbox[2:])


def test_the_map_lands_in_the_plans_frame():
    """With the synthetic venue's plan the map is built in the venue's frame: no fit to truth needed."""
    pytest.importorskip("gtsam")
    from rmbuild.config import IngestConfig
    from rmbuild.config.optimize import OptimizeConfig
    from rmbuild.evaluate.trajectory import trajectory_metrics
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.slam import optimize
    from rmbuild.synthetic import preset_config, simulate
    from rmbuild.synthetic.venue import plan_geojson

    sd = simulate(preset_config("default", 3))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps)
    ds, fp, _ = build_dataset(raw, IngestConfig())
    plan = from_features(plan_geojson(sd.venue)["features"], lambda a: a)
    r = optimize(ds, fp, OptimizeConfig(), floorplan=plan)
    assert r.stats["frame"] == "floorplan" and r.stats["evidence"]["floorplan"]["inside"] > 0.8
    # measured 0.95 m in the plan's frame (0.71 m after a fit to truth without the plan)
    assert trajectory_metrics(r.poses, ds, align=False)["landmark_error_m"]["mean"] < 2.0


def test_user_plan_in_lonlat_and_metres(tmp_path):
    """A user's plan in WGS84 lon/lat is projected to metres about its south-west corner; one in local metres
    is taken as it is; anything else is a one-line error naming the file."""
    from rmbuild.errors import InputError
    from rmbuild.io.floorplan import check_plan_frame, read_user_plan

    lon0, lat0 = 11.0, 48.0
    dlon, dlat = 40.0 / (111_320 * np.cos(np.radians(lat0))), 20.0 / 110_570  # ~40 m x 20 m
    ring = [[lon0, lat0], [lon0 + dlon, lat0], [lon0 + dlon, lat0 + dlat], [lon0, lat0 + dlat], [lon0, lat0]]
    geo = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"type": "floor"}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]}
    (tmp_path / "geo.geojson").write_text(json.dumps(geo))
    doc = read_user_plan(tmp_path / "geo.geojson")
    b = from_features(doc["features"], lambda a: a).bounds
    assert b[0] == pytest.approx(0, abs=0.01) and b[2] == pytest.approx(40, rel=0.01)
    assert b[3] == pytest.approx(20, rel=0.01)
    check = check_plan_frame(doc, np.array([[5.0, 5.0], [39.0, 19.0], [60.0, 5.0], [20.0, -10.0]]))
    assert check["fixes_inside"] == 0.5 and check["wrong_frame"] and "geo.geojson" in check["warning"]

    local = {"type": "FeatureCollection", "frame": "local_m", "features": [_rect(0, 0, 30, 10, type="floor")]}
    (tmp_path / "local.geojson").write_text(json.dumps(local))
    assert from_features(read_user_plan(tmp_path / "local.geojson")["features"], lambda a: a).area_m2 == 300

    (tmp_path / "metres_unsaid.geojson").write_text(json.dumps({**local, "frame": None}))
    (tmp_path / "broken.geojson").write_text("{")
    for name in ("metres_unsaid.geojson", "broken.geojson", "missing.geojson"):
        with pytest.raises(InputError) as e:
            read_user_plan(tmp_path / name)
        assert name in str(e.value)


def test_ingest_keeps_the_plan_and_optimize_uses_it_unless_told_not_to(tmp_path, capsys):
    pytest.importorskip("gtsam")
    from rmbuild.synthetic.venue import plan_geojson
    from tests.cli_util import run_cli

    sim = tmp_path / "sim"
    assert run_cli(capsys, "simulate", sim, "--preset", "tiny", "--seed", "1", "-q").code == 0
    plan = {**plan_geojson(json.loads((sim / "truth" / "venue.json").read_text())), "frame": "local_m"}
    (tmp_path / "plan.geojson").write_text(json.dumps(plan))
    ws = tmp_path / "ws"
    res = run_cli(capsys, "ingest", sim, "-w", ws, "--floorplan", tmp_path / "plan.geojson")
    assert res.code == 0, res.err
    assert (ws / "data" / "floorplan.local.json").is_file() and "floor plan" in res.out
    res = run_cli(capsys, "optimize", "-w", ws, "-q")
    assert res.code == 0, res.err
    report = json.loads((ws / "optimize" / "report.json").read_text())
    assert report["gauge"] == "floorplan" and report["evidence"]["floorplan"]["used"] is True
    off = tmp_path / "off.toml"
    off.write_text("[optimize.floorplan]\nuse = false\n")
    res = run_cli(capsys, "optimize", "-w", ws, "-q", "--force", "--config", off)
    assert res.code == 0, res.err
    report = json.loads((ws / "optimize" / "report.json").read_text())
    assert report["gauge"] == "se2" and "floorplan" not in (report.get("evidence") or {})
    # a workspace without a plan: nothing to use, the map stays in a walk's frame
    bare = tmp_path / "bare"
    assert run_cli(capsys, "ingest", sim, "-w", bare, "-q").code == 0
    res = run_cli(capsys, "optimize", "-w", bare, "-q")
    assert res.code == 0, res.err
    assert json.loads((bare / "optimize" / "report.json").read_text())["gauge"] == "se2"


def test_export_map_writes_the_cells_in_wgs84_when_the_plan_has_lon_lat(tmp_path, capsys):
    """A plan given in WGS84 puts the map on the globe: export-map writes map/cells.geojson, one lon/lat square
    per cell whose centre is the cell's centre through the plan's georeference; a map without one does not."""
    pytest.importorskip("gtsam")
    from rmbuild.floorplan import Georef
    from rmbuild.synthetic.venue import plan_geojson
    from tests.cli_util import run_cli

    sim = tmp_path / "sim"
    assert run_cli(capsys, "simulate", sim, "--preset", "tiny", "--seed", "1", "-q").code == 0
    plan = plan_geojson(json.loads((sim / "truth" / "venue.json").read_text()))  # metres from (0, 0)
    georef = Georef("enu", 11.0, 48.0)

    def on_globe(coords):
        return [on_globe(c) for c in coords] if isinstance(coords[0], list) else \
            [round(float(v), 10) for v in georef.to_lonlat(np.array([coords]))[0]]

    for f in plan["features"]:
        f["geometry"]["coordinates"] = on_globe(f["geometry"]["coordinates"])
    (tmp_path / "plan.geojson").write_text(json.dumps(plan))
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", sim, "-w", ws, "-q", "--floorplan", tmp_path / "plan.geojson").code == 0
    assert run_cli(capsys, "optimize", "-w", ws, "-q").code == 0
    assert json.loads((ws / "optimize" / "report.json").read_text())["gauge"] == "floorplan"
    assert run_cli(capsys, "export-map", "-w", ws, "-q").code == 0
    cells = pd.read_parquet(ws / "map" / "cells.parquet")
    fc = json.loads((ws / "map" / "cells.geojson").read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == len(cells)
    ring = np.array(fc["features"][0]["geometry"]["coordinates"][0])
    assert len(ring) == 5 and (ring[0] == ring[-1]).all()
    centre = ring[:4].mean(axis=0)
    props = fc["features"][0]["properties"]
    expected = georef.to_lonlat(np.array([[props["x_m"], props["y_m"]]]))[0]
    assert np.abs(centre - expected).max() < 1e-7  # about a centimetre
    assert props["n_aps"] > 0 and props["strongest_rssi_dbm"] < 0
    report = json.loads((ws / "map" / "report.json").read_text())
    assert report["cells_geojson"] == "map/cells.geojson" and report["uji_coordinates"] == "EPSG:3857"
    # the UJI-layout CSV: LONGITUDE, LATITUDE in Web Mercator metres, as UJIIndoorLoc's
    from pyproj import Transformer

    uji = pd.read_csv(ws / "map" / "radiomap_uji.csv")
    table = pd.read_parquet(ws / "map" / "cells.parquet")
    lonlat = georef.to_lonlat(table[["x_m", "y_m"]].to_numpy())
    mx, my = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
    assert np.abs(uji["LONGITUDE"] - mx).max() < 0.01 and np.abs(uji["LATITUDE"] - my).max() < 0.01
    # the same data without the plan: a walk's frame, no GeoJSON
    bare = tmp_path / "bare"
    assert run_cli(capsys, "ingest", sim, "-w", bare, "-q").code == 0
    assert run_cli(capsys, "optimize", "-w", bare, "-q").code == 0
    assert run_cli(capsys, "export-map", "-w", bare, "-q").code == 0
    assert not (bare / "map" / "cells.geojson").exists()
    assert json.loads((bare / "map" / "report.json").read_text())["cells_geojson"] is None
    uji = pd.read_csv(bare / "map" / "radiomap_uji.csv")
    table = pd.read_parquet(bare / "map" / "cells.parquet")
    assert (uji["LONGITUDE"] == table["x_m"]).all() and (uji["LATITUDE"] == table["y_m"]).all()


def _rfc7946_problems(doc: dict) -> list[str]:
    """What keeps ``doc`` from being RFC 7946 GeoJSON as far as a GIS reads it: a FeatureCollection without
    the removed "crs" member, positions WGS84 lon/lat."""
    out = []
    if doc.get("type") != "FeatureCollection":
        out.append("not a FeatureCollection")
    if "crs" in doc:
        out.append("has a crs member (removed by RFC 7946)")
    for f in doc.get("features", []):
        for lon, lat in (p[:2] for p in _positions(f.get("geometry", {}).get("coordinates", []))):
            if not (-180 <= lon <= 180 and -90 <= lat <= 90):
                return out + [f"position {lon}, {lat} is not lon/lat"]
    return out


def _positions(c):
    if c and isinstance(c[0], (int, float)):
        return [c]
    return [p for sub in c for p in _positions(sub)]


def test_every_geojson_a_workspace_holds_is_rfc7946(tmp_path, capsys):
    """The plan in local metres is kept as data/floorplan.local.json (GeoJSON-shaped, metres: not GeoJSON);
    every *.geojson the stages write has WGS84 positions. A workspace written before, with the plan in
    data/floorplan.geojson, is still read."""
    pytest.importorskip("gtsam")
    import shutil

    from rmbuild.io.workspace import Workspace
    from rmbuild.synthetic.venue import plan_geojson
    from tests.cli_util import run_cli

    sim = tmp_path / "sim"
    assert run_cli(capsys, "simulate", sim, "--preset", "tiny", "--seed", "1", "-q").code == 0
    plan = {**plan_geojson(json.loads((sim / "truth" / "venue.json").read_text())), "frame": "local_m"}
    (tmp_path / "plan.geojson").write_text(json.dumps(plan))
    ws = tmp_path / "ws"
    for args in (["ingest", sim, "-w", ws, "--floorplan", tmp_path / "plan.geojson"], ["optimize", "-w", ws],
                 ["export-map", "-w", ws]):
        assert run_cli(capsys, *args, "-q").code == 0
    local = json.loads((ws / "data" / "floorplan.local.json").read_text())
    assert local["frame"] == "local_m" and not list((ws / "data").glob("*.geojson"))  # metres: not .geojson
    assert _rfc7946_problems({**local, "features": [{"geometry": {"coordinates": [[500.0, 300.0]]}}]})
    for p in ws.rglob("*.geojson"):
        assert _rfc7946_problems(json.loads(p.read_text())) == [], p
    # a workspace an earlier rmbuild wrote: the plan under its old name, recorded so in the ingest record
    old = tmp_path / "old"
    shutil.copytree(ws, old)
    (old / "data" / "floorplan.local.json").rename(old / "data" / "floorplan.geojson")
    record = old / "data" / "stage.json"
    rec = json.loads(record.read_text())
    rec["files"]["data/floorplan.geojson"] = rec["files"].pop("data/floorplan.local.json")
    record.write_text(json.dumps(rec))
    assert Workspace.open(old).read_json("data.floorplan")["features"] == local["features"]
