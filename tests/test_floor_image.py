"""The floor plan's raster image: read and kept with the plan, placed over its extent, drawn under the walks
(report, viewer), kept on append; bad images and extents are one-line errors."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pytest

from tests.cli_util import run_cli


def _png(path: Path, width: int, height: int) -> Path:
    from PIL import Image

    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[: height // 2] = (200, 30, 30)  # top half red: row 0 is the image's top
    Image.fromarray(rgb).save(path)
    return path


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The tiny venue and its plan in local metres."""
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate
    from rmbuild.synthetic.venue import plan_geojson

    root = tmp_path_factory.mktemp("img")
    simulate.run(root / "sim", preset_config("tiny", 1))
    venue = json.loads((root / "sim" / "truth" / "venue.json").read_text())
    (root / "plan.geojson").write_text(json.dumps({**plan_geojson(venue), "frame": "local_m"}))
    return root / "sim", root / "plan.geojson"


def test_the_image_is_kept_with_the_plan_over_its_extent(sim, tmp_path, capsys):
    """Default extent: the plan's bounding box; a given extent is kept as given (metres here); a large image is
    scaled down to 2048 px on its long side, its top stays on top."""
    from rmbuild.floorplan import from_local_geojson
    from rmbuild.io.floor_image import load_image
    from rmbuild.io.workspace import Workspace

    data, plan = sim
    img = _png(tmp_path / "floor.png", 3000, 300)
    ws = tmp_path / "ws"
    r = run_cli(capsys, "ingest", data, "-w", ws, "--floorplan", plan, "--floorplan-image", img)
    assert r.code == 0, r.err
    assert "with its image kept" in r.out
    pixels, extent = load_image(Workspace.open(ws))
    bounds = from_local_geojson(json.loads(plan.read_text())).bounds
    assert extent == pytest.approx(list(bounds))
    assert pixels.shape == (205, 2048, 3)
    assert (pixels[0] == (200, 30, 30)).all() and (pixels[-1] == 0).all()
    ws2 = tmp_path / "ws2"
    r = run_cli(capsys, "ingest", data, "-w", ws2, "-q", "--floorplan", plan, "--floorplan-image", img,
                "--floorplan-image-extent", "-5,-4,75.5,36")
    assert r.code == 0, r.err
    assert load_image(Workspace.open(ws2))[1] == [-5.0, -4.0, 75.5, 36.0]
    assert Workspace.open(ws2).read_report("ingest")["floorplan"]["image_extent_m"] == [-5.0, -4.0, 75.5, 36.0]


def test_a_plan_file_names_its_own_image(sim, tmp_path, capsys):
    """A plan's "image" member (file relative to the plan, optional extent) comes along with --floorplan, and
    with `rmbuild build` (whose input fingerprint covers the image); --floorplan-image replaces it; a malformed
    member is a one-line error naming the plan."""
    from rmbuild.io.floor_image import load_image
    from rmbuild.io.workspace import Workspace
    from rmbuild.stages.build import _plan_files

    data, plan = sim
    doc = json.loads(plan.read_text())
    (tmp_path / "img").mkdir()
    _png(tmp_path / "img" / "floor.png", 60, 30)
    own = tmp_path / "own.geojson"
    own.write_text(json.dumps({**doc, "image": {"file": "img/floor.png", "extent": [-1, -2, 59, 28]}}))
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", data, "-w", ws, "-q", "--floorplan", own).code == 0
    pixels, extent = load_image(Workspace.open(ws))
    assert extent == [-1.0, -2.0, 59.0, 28.0] and pixels.shape == (30, 60, 3)
    assert _plan_files(own) == [own, tmp_path / "img" / "floor.png"] and _plan_files(plan) == [plan]
    r = run_cli(capsys, "ingest", data, "-w", ws, "-q", "--force", "--floorplan", own, "--floorplan-image",
                _png(tmp_path / "other.png", 20, 10))
    assert r.code == 0, r.err
    assert load_image(Workspace.open(ws))[0].shape == (10, 20, 3)
    for member, said in (({"file": "img/none.png"}, "none.png"), ({"path": "img/floor.png"}, '"image" must be'),
                         ({"file": "img/floor.png", "extent": [0, 0, 1]}, "x0 < x1")):
        bad = tmp_path / "bad.geojson"
        bad.write_text(json.dumps({**doc, "image": member}))
        r = run_cli(capsys, "ingest", data, "-w", tmp_path / "ws_bad", "--floorplan", bad)
        assert r.code == 2 and said in r.err and len(r.err.strip().splitlines()) == 1, r.err


def test_an_extent_in_lon_lat_for_a_plan_in_wgs84():
    """A WGS84 plan's image extent is given in degrees (west, south, east, north) and lands in the plan's
    metres: the south-west corner of the plan is (0, 0)."""
    from rmbuild.floorplan import from_user_geojson, image_extent_m

    lon0, lat0 = 11.0, 48.0
    dlon, dlat = 40.0 / (111_320 * np.cos(np.radians(lat0))), 20.0 / 110_570  # ~40 m x 20 m
    ring = [[lon0, lat0], [lon0 + dlon, lat0], [lon0 + dlon, lat0 + dlat], [lon0, lat0 + dlat], [lon0, lat0]]
    plan = from_user_geojson({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"type": "floor"}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]})
    assert image_extent_m(plan, (lon0, lat0, lon0 + dlon, lat0 + dlat)) == pytest.approx([0, 0, 40, 20], abs=0.5)
    assert image_extent_m(plan) == pytest.approx(list(plan.bounds))


def test_drawn_under_the_walks_in_the_report_and_the_viewer(sim, tmp_path, capsys):
    pytest.importorskip("gtsam")
    from rmbuild.io.floor_image import load_image
    from rmbuild.io.workspace import Workspace
    from rmbuild.viz import figures

    data, plan = sim
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", data, "-w", ws, "-q", "--floorplan", plan, "--floorplan-image",
                   _png(tmp_path / "f.png", 80, 40)).code == 0
    assert run_cli(capsys, "optimize", "-w", ws, "-q").code == 0
    assert run_cli(capsys, "export-map", "-w", ws, "-q").code == 0
    r = run_cli(capsys, "report", "-w", ws)
    assert r.code == 0, r.err
    page = html.unescape((ws / "report.html").read_text())
    assert page.count("underneath: the plan's image") == 2  # the walks and the radio map
    cov = Workspace.open(ws).read_report("map")["plan_coverage"]
    assert 0.2 < cov["share"] <= 1.0 and cov["covered_m2"] <= cov["walkable_m2"]
    # every key figure the report lists is in its stage's report (a misspelt key would drop its row)
    from rmbuild.viz.report import KEY_FIGURES, _get

    reports = {s: Workspace.open(ws).read_report(s) for s in ("ingest", "optimize", "map")}
    absent = [k for s, k, _ in KEY_FIGURES if s in reports and _get(reports[s], k) is None]
    optional = {"ble.readings", "ble.beacons", "ble.cells",  # no BLE in this input
                "optimized.landmark_error_unlinked_at_raw_m.mean"}  # every walk linked
    assert set(absent) <= optional, absent
    assert "radio map cells" in page and "walkable space the map" in page
    w = Workspace.open(ws)
    image = load_image(w)
    fig = figures.coverage_figure(w.read_table("map.cell_table"), image=image)
    assert len(fig.axes[0].images) == 2  # the plan's image under the cells'
    assert fig.axes[0].images[0].get_extent() == pytest.approx([image[1][0], image[1][2], image[1][1], image[1][3]])
    fig = figures.walks_figure([("a", w.read_dataset().poses)], w.read_dataset().walk_ids(), image=image)
    (im,) = fig.axes[0].images
    assert im.get_extent() == pytest.approx([image[1][0], image[1][2], image[1][1], image[1][3]])
    pytest.importorskip("rerun")
    from rmbuild.stages.view import log_workspace
    from rmbuild.viz import ViewTarget
    from rmbuild.viz.rerun_bridge import RerunViewer

    with RerunViewer(ViewTarget("save", tmp_path / "v.rrd")) as v:
        log_workspace(w, v)
        assert v.counts.get("plan_image") == 1


def test_append_keeps_the_image(sim, tmp_path, capsys):
    from tests.cli_util import split_input

    data, plan = sim
    walks = sorted({ln.split(",")[0] for ln in (data / "walks.csv").read_text().splitlines()[1:]})
    old = split_input(data, tmp_path / "old", set(walks[:-2]))
    new = split_input(data, tmp_path / "new", set(walks[-2:]))
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", old, "-w", ws, "-q", "--floorplan", plan, "--floorplan-image",
                   _png(tmp_path / "f.png", 80, 40)).code == 0
    before = (ws / "data" / "floor_image.png").read_bytes()
    r = run_cli(capsys, "ingest", "--append", new, "-w", ws, "-q")
    assert r.code == 0, r.err
    assert (ws / "data" / "floor_image.png").read_bytes() == before
    r = run_cli(capsys, "ingest", "--append", new, "-w", ws, "--floorplan-image", tmp_path / "f.png")
    assert r.code == 2 and "--floorplan-image" in r.err


@pytest.mark.parametrize(("args", "said"), [
    (["--floorplan-image", "{text}"], "not an image"),
    (["--floorplan-image", "{missing}"], "missing.png"),
    (["--floorplan-image", "{png}", "--nofloorplan"], "needs a floor plan"),
    (["--floorplan-image", "{png}", "--floorplan-image-extent", "1,2,3"], "four comma-separated numbers"),
    (["--floorplan-image", "{png}", "--floorplan-image-extent", "10,0,0,5"], "x0 < x1"),
    (["--floorplan-image-extent", "0,0,1,1"], "--floorplan-image"),
])
def test_bad_images_and_extents_are_one_line_errors(sim, tmp_path, capsys, args, said):
    data, plan = sim
    (tmp_path / "notes.png").write_text("not a picture\n")
    files = {"text": tmp_path / "notes.png", "missing": tmp_path / "missing.png",
             "png": _png(tmp_path / "f.png", 8, 8)}
    given = [a.format(**files) for a in args if a != "--nofloorplan"]
    plan_args = [] if "--nofloorplan" in args else ["--floorplan", str(plan)]
    r = run_cli(capsys, "ingest", data, "-w", tmp_path / "ws", *plan_args, *given)
    assert r.code == 2 and said in r.err and "Traceback" not in r.err
    assert len(r.err.strip().splitlines()) <= 2  # click's usage errors add a "Usage:" line
    assert not (tmp_path / "ws").exists()


def test_an_image_over_the_pixel_bound_is_refused_before_decoding(tmp_path, monkeypatch):
    from rmbuild.errors import InputError
    from rmbuild.io import floor_image

    monkeypatch.setattr(floor_image, "MAX_IMAGE_PIXELS", 50 * 40 - 1)
    with pytest.raises(InputError, match="50 x 40 pixels") as e:
        floor_image.read_image(_png(tmp_path / "f.png", 50, 40))
    assert "f.png" in str(e.value)
    monkeypatch.setattr(floor_image, "MAX_IMAGE_PIXELS", 50 * 40)
    assert floor_image.decode(floor_image.read_image(tmp_path / "f.png")).shape == (40, 50, 3)


def test_covered_share_of_the_walkable_space():
    from rmbuild.floorplan import covered_share, from_features

    plan = from_features([{"type": "Feature", "properties": {"type": "floor"}, "geometry": {
        "type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]]}}], lambda a: a)
    # two 2 m cells inside, one half outside the floor, one overlapping the first: 4 + 4 + 2 m² of 200
    c = covered_share(plan, np.array([[1.0, 1.0], [5.0, 5.0], [20.0, 5.0], [1.0, 1.0]]), 2.0)
    assert c == {"walkable_m2": 200.0, "covered_m2": 10.0, "share": 0.05}
    assert covered_share(plan, np.zeros((0, 2)), 2.0)["covered_m2"] == 0.0
