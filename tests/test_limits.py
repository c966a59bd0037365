"""Extreme but well-formed input (issue 40): values far beyond any real data are refused where they enter,
with one error line naming the file, the line and the limit (rmbuild/limits.py), before anything of their
size is allocated; what stays accepted fits in bounded memory."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from capped import run_capped
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild import limits

ILC_FIXTURE = Path(__file__).resolve().parent / "fixtures" / "msft_ilc" / "tiny_trace.txt"


def one_error(r, pattern: str) -> str:
    """The single error line of a failed run (exit 2), matched against ``pattern``."""
    assert r.code == 2, (r.code, r.err)
    lines = [ln for ln in r.err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.err
    assert re.search(pattern, lines[0]), lines[0]
    return lines[0]


# ------------------------------------------------------------------------------ positions and walks
@pytest.mark.parametrize("value", ["1e308", "-2e5", "100000.5"])
def test_a_pose_far_beyond_any_building_is_refused_at_ingest(value: str, tmp_path: Path, capsys) -> None:
    """A pose x of 1e308 passed ingest and crashed optimize (`arange: cannot compute length`)."""
    t = make_input_tables()
    t["poses"]["x_m"] = t["poses"]["x_m"].astype(object)
    t["poses"].loc[7, "x_m"] = value
    folder = write_tables(t, tmp_path / "in")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    one_error(r, rf"{re.escape(str(folder / 'poses.csv'))}:9: poses: x_m .* more than 100000 m from the origin")
    assert not (tmp_path / "ws").exists()


def test_a_fix_far_away_is_refused(tmp_path: Path, capsys) -> None:
    t = make_input_tables()
    t["fixes"].loc[1, "y_m"] = -3e9
    folder = write_tables(t, tmp_path / "in")
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"fixes.csv:3: fixes: y_m -3000000000 is more than 100000 m")


def test_an_ilc_waypoint_of_1e30_names_its_line(tmp_path: Path, capsys) -> None:
    """An MS ILC waypoint x of 1e30 ended in `IndexError: index -9223372036854775808` (issue 40)."""
    lines = ILC_FIXTURE.read_text().split("\n")
    i = next(k for k, ln in enumerate(lines) if "\tTYPE_WAYPOINT\t" in ln)
    lines[i] = lines[i].replace("50.0000", "1e30", 1)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_text("\n".join(lines))
    one_error(run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws"),
              rf"trace.txt:{i + 1}: fixes: x_m 1e\+30 is more than")


def test_a_fingerprint_table_over_the_limit_is_refused(tmp_path: Path, capsys, monkeypatch) -> None:
    import rmbuild.ingest.core as core

    folder = write_tables(make_input_tables(n_steps=40), tmp_path / "in")
    monkeypatch.setattr(core, "MAX_FINGERPRINT_CELLS", 20)  # 10 + 10 nodes with readings x 5 APs
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"wifi.csv: 20 poses with Wi-Fi readings of 5 distinct BSSIDs: a fingerprint table of 100 cells, at "
              r"most 20")


def test_a_walk_longer_than_the_limits_is_refused(tmp_path: Path, capsys, monkeypatch) -> None:
    import rmbuild.ingest.core as core

    folder = write_tables(make_input_tables(n_steps=30), tmp_path / "in")
    monkeypatch.setattr(core, "MAX_WALK_POSES", 25)
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"poses.csv:27: walk 'walk0' has 30 poses: at most 25 in one walk")
    monkeypatch.setattr(core, "MAX_WALK_POSES", 1000)
    monkeypatch.setattr(core, "MAX_WALK_PATH_M", 10.0)  # 0.7 m steps: the 16th pose is 10.5 m on
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"poses.csv:17: walk 'walk0': its steps add up to more than 10 m by this pose")


def test_a_million_distinct_bssids_is_a_clean_error_in_bounded_memory(tmp_path: Path) -> None:
    """1e6 readings of 1e6 distinct BSSIDs (~30 MB of CSV) asked for a dense 615,000,000-cell table
    (MemoryError at 2.1 GB); now one line naming the file and the limit, well under 1 GB."""
    t = make_input_tables(n_walks=2, n_steps=400)
    n = 1_000_000
    rng = np.random.default_rng(0)
    poses = t["poses"]
    k = rng.integers(0, len(poses), n)
    wifi = pd.DataFrame({"walk_id": poses["walk_id"].to_numpy()[k], "t_s": poses["t_s"].to_numpy()[k] + 0.1,
                         "bssid": np.char.mod("%012x", np.arange(n)), "rssi_dbm": -60.0})
    t["wifi"] = wifi.sort_values(["walk_id", "t_s"], kind="stable")
    folder = write_tables(t, tmp_path / "in")
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q")
    one_error(r, rf"{re.escape(str(folder / 'wifi.csv'))}: 1,000,000 distinct BSSIDs in the Wi-Fi readings of one "
                 rf"floor: at most {limits.MAX_APS:,}")
    assert r.peak_rss_mb < 1024, r.peak_rss_mb


# ------------------------------------------------------------------------------ floor plans
def _rect(x0: float, y0: float, x1: float, y1: float, **props) -> dict:
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}}


def _local_plan(*features: dict) -> str:
    import json

    return json.dumps({"type": "FeatureCollection", "frame": "local_m", "features": list(features)})


PLANS = {
    # issue 40: RecursionError, GEOSException (NaN/Inf), OverflowError (1e308), MemoryError (1.16 TiB, 11.4 PiB)
    "nested": ('{"type": "FeatureCollection", "frame": "local_m", "features": ' + "[" * 100_000 + "]" * 100_000
               + "}", r"invalid JSON: nested deeper than 64 levels"),
    "nan": (_local_plan(_rect(0, 0, 10, 10, type="floor")).replace("10, 10", "NaN, 10", 1),
            r"invalid JSON: NaN is not a number JSON allows"),
    "inf": (_local_plan(_rect(0, 0, 10, 10, type="floor")).replace("10, 10", "-Infinity, 10", 1),
            r"invalid JSON: -Infinity is not a number"),
    "e400": (_local_plan(_rect(0, 0, 10, 10, type="floor")).replace("10, 10", "1e400, 10", 1),
             r"invalid JSON: number 1e400 is beyond the float range"),
    "e308": (_local_plan(_rect(-1e308, -1e308, 1e308, 1e308, type="floor")),
             r"vertex \(-1e\+308, -1e\+308\) lies more than 100000 m from the plan's origin"),
    "e5": (_local_plan(_rect(-1e5, -1e5, 1e5, 1e5, type="floor")),
           r"the plan spans 200000 x 200000 m: at most 2000 m on a side"),
    "e7": (_local_plan(_rect(-1e7, -1e7, 1e7, 1e7, type="floor")), r"lies more than 100000 m"),
    "degenerate": (_local_plan(_rect(0, 0, 0, 0, type="floor")), r"the plan has no walkable area"),
    "lonlat_nan": ('{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, "geometry": '
                   '{"type": "Polygon", "coordinates": [[[11, 48], [NaN, 48], [11, 48.001], [11, 48]]]}}]}',
                   r"NaN is not a number"),
    "passwd": (_local_plan(_rect(0, 0, 10, 10, type="floor"))[:-1] + ', "image": {"file": "../../../../etc/passwd"}}',
               r"\"image\" \"file\" '\.\./\.\./\.\./\.\./etc/passwd' lies outside the plan's folder"),
    "hostname": (_local_plan(_rect(0, 0, 10, 10, type="floor"))[:-1] + ', "image": {"file": "/etc/hostname"}}',
                 r"'/etc/hostname' lies outside the plan's folder"),
}


@pytest.mark.parametrize("name", list(PLANS))
def test_hostile_floor_plans_are_one_line_errors(name: str, tmp_path: Path, capsys) -> None:
    text, pattern = PLANS[name]
    plan = tmp_path / "plan.geojson"
    plan.write_text(text)
    folder = write_tables(make_input_tables(), tmp_path / "in")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws", "--floorplan", plan)
    one_error(r, rf"^error: {re.escape(str(plan))}: .*{pattern}")
    assert not (tmp_path / "ws").exists()


def test_a_plan_image_reached_through_a_link_out_of_its_folder_is_refused(tmp_path: Path, capsys) -> None:
    (tmp_path / "plans").mkdir()
    (tmp_path / "plans" / "floor.png").symlink_to("/etc/hostname")
    plan = tmp_path / "plans" / "plan.geojson"
    plan.write_text(_local_plan(_rect(0, 0, 10, 10, type="floor"))[:-1] + ', "image": {"file": "floor.png"}}')
    folder = write_tables(make_input_tables(), tmp_path / "in")
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws", "--floorplan", plan),
              r"'floor.png' lies outside the plan's folder")


def test_a_plan_over_the_vertex_limit_is_refused_and_one_under_it_fits_in_memory(tmp_path: Path) -> None:
    """A plan of 1e6 vertices took 2.08 GB; the limit is 100,000 (the ILC floors' plans have 1,000-6,000)."""
    import json

    def circle(n: int) -> Path:
        a = 2 * np.pi * np.arange(n) / n
        ring = np.c_[10 + 8 * np.cos(a), 10 + 8 * np.sin(a)].round(4).tolist()
        f = tmp_path / f"plan{n}.geojson"
        f.write_text(json.dumps({"type": "FeatureCollection", "frame": "local_m", "features": [
            {"type": "Feature", "properties": {"type": "floor"},
             "geometry": {"type": "Polygon", "coordinates": [ring + ring[:1]]}}]}))
        return f

    folder = write_tables(make_input_tables(), tmp_path / "in")
    big = circle(limits.MAX_PLAN_VERTICES + 1)
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q", "--floorplan", big)
    one_error(r, rf"{re.escape(str(big))}: not a usable GeoJSON floor plan: 100,002 vertices: at most 100,000")
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q", "--floorplan", circle(limits.MAX_PLAN_VERTICES - 1))
    assert r.code == 0 and r.peak_rss_mb < 1024, (r.err, r.peak_rss_mb)
    r = run_capped("export-map", "-w", tmp_path / "ws", "-q")  # reads the workspace's copy (outline + walkable)
    assert r.code == 2 and "no optimize outputs" in r.err, r.err


@pytest.mark.parametrize("info, pattern", [
    ('{"map_info": {"height": 1e400, "width": 100}}', r"floor_info.json: invalid JSON: number 1e400 is beyond"),
    ('{"map_info": {"height": 100, "width": -5}}', r'floor_info.json: map_info "width" must be a number of metres '
                                                   r"in \(0, 2000\], got -5"),
    ('{"map_info": {"height": 0, "width": 0}}', r'map_info "width" must be .* got 0'),
    ('{"map_info": {"height": 1e7, "width": 1e7}}', r'map_info "width" must be'),
    ('{"map_info": {"height": true, "width": 10}}', r'map_info "height" must be'),
    ('{"map_info": []}', r'no "map_info" object'),
    ("[" * 50_000 + "]" * 50_000, r"nested deeper than 64 levels"),
])
def test_hostile_floor_info_is_a_one_line_error(info: str, pattern: str, tmp_path: Path, capsys) -> None:
    """height 1e400 / width -5 gave a GEOSException, 0 x 0 `no Polygon or MultiPolygon features` (issue 40)."""
    folder = tmp_path / "F1"
    (folder / "path_data_files").mkdir(parents=True)
    (folder / "path_data_files" / "trace.txt").write_text(ILC_FIXTURE.read_text())
    (folder / "geojson_map.json").write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, "geometry": {"type": '
        '"Polygon", "coordinates": [[[116.0, 39.0], [116.001, 39.0], [116.001, 39.001], [116.0, 39.0]]]}}]}')
    (folder / "floor_info.json").write_text(info)
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"), pattern)


def test_the_distance_field_of_the_largest_plan_stays_small() -> None:
    from rmbuild.floorplan import FIELD_MAX_CELLS, frame_correction, from_features

    plan = from_features([_rect(0, 0, limits.MAX_PLAN_SIZE_M, limits.MAX_PLAN_SIZE_M, type="floor")], lambda a: a)
    grid, _, res = plan.distance_field()
    assert grid.size <= FIELD_MAX_CELLS * 1.01 and res > 0.5
    # fixes spread over 100 km are not searched for a correction (their raster would be 1e10 cells)
    c = frame_correction(plan, np.array([[0.0, 0.0], [1e5, 1e5], [-1e5, 0.0]]))
    assert c["searched"] is False and c["best_inside"] == c["inside"]


def test_workspace_files_nested_100000_deep_are_not_internal_errors(tmp_path: Path, capsys) -> None:
    folder = write_tables(make_input_tables(), tmp_path / "in")
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", folder, "-w", ws, "-q").code == 0
    (ws / "build_state.json").write_text("[" * 100_000 + "]" * 100_000)
    (ws / "data" / "stage.json").write_text("[" * 100_000 + "]" * 100_000)
    one_error(run_cli(capsys, "optimize", "-w", ws, "-q"), r"has no ingest outputs")
    (ws / "manifest.json").write_text("[" * 100_000 + "]" * 100_000)
    one_error(run_cli(capsys, "optimize", "-w", ws, "-q"), r"is not an rmbuild workspace")


# ------------------------------------------------------------------------------ compressed and large inputs
def _gzip_bomb(path: Path, head: bytes, filler: bytes, total: int) -> Path:
    """``head`` then ``filler`` repeated to ``total`` bytes, gzip'd: one member per MB of filler (a gzip
    file may be a sequence of members), compressed once (a few MB on disk, written in a moment)."""
    import gzip

    block = gzip.compress(filler * max(1, (1 << 20) // len(filler)), compresslevel=9)
    with path.open("wb") as fh:
        fh.write(gzip.compress(head))
        for _ in range(total >> 20):
            fh.write(block)
    return path


@pytest.mark.parametrize("filler", [b"#" + b"x" * 1000 + b"\n", b"\n", b"x"])
def test_a_gzip_bomb_trace_is_refused_at_the_limit(filler: bytes, tmp_path: Path) -> None:
    """A 3 MB MS ILC .txt.gz expanding to 3 GB ran out of memory at 2.5 GB; decompression now stops past the
    limit, in bounded memory."""
    (tmp_path / "in").mkdir()
    f = _gzip_bomb(tmp_path / "in" / "trace.txt.gz", ILC_FIXTURE.read_bytes(), filler, 3 << 30)
    assert f.stat().st_size < 20 << 20
    r = run_capped("ingest", tmp_path / "in", "-w", tmp_path / "ws", "-q", "--format", "msft-ilc")
    one_error(r, rf"{re.escape(str(f))}: trace decompresses to more than 96 MB: at most 96 MB in one trace")
    assert r.peak_rss_mb < 1024, r.peak_rss_mb


@pytest.mark.parametrize("filler", [b"walk0,0.1,00:11:22:33:44:00,-50.0,2437.0,net0\n", b"\n", b"x"])
def test_a_gzip_bomb_table_is_refused_at_the_limit(filler: bytes, tmp_path: Path) -> None:
    t = make_input_tables()
    folder = write_tables({k: v for k, v in t.items() if k != "wifi"}, tmp_path / "in")
    f = _gzip_bomb(folder / "wifi.csv.gz", t["wifi"].to_csv(index=False).encode(), filler, 3 << 30)
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q")
    one_error(r, rf"{re.escape(str(f))}: gzip data expands to more than 128 MB \(the limit of a compressed input")
    assert r.peak_rss_mb < 1024, r.peak_rss_mb


def test_ipin_gzip_bomb_and_oversized_logfiles_are_refused(tmp_path: Path, capsys) -> None:
    src = Path(__file__).resolve().parent / "fixtures" / "ipin" / "tiny_logfile.txt"
    (tmp_path / "a").mkdir()
    f = _gzip_bomb(tmp_path / "a" / "logfile.txt.gz", src.read_bytes(), b"\n", 1 << 30)
    one_error(run_cli(capsys, "ingest", tmp_path / "a", "-w", tmp_path / "ws", "--format", "ipin"),
              rf"{re.escape(str(f))}: logfile decompresses to more than 96 MB")
    (tmp_path / "b").mkdir()
    big = tmp_path / "b" / "logfile.txt"
    with big.open("wb") as fh:
        fh.write(src.read_bytes())
        fh.truncate(limits.MAX_TRACE_BYTES + 1)  # a sparse file: no disk used
    one_error(run_cli(capsys, "ingest", tmp_path / "b", "-w", tmp_path / "ws", "--format", "ipin"),
              rf"{re.escape(str(big))}: logfile of 100,663,297 bytes: at most 96 MB \(100,663,296 bytes\) in one "
              r"logfile")


def test_a_parquet_table_decoding_to_gbs_is_refused_before_it_is_decoded(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = make_input_tables()
    folder = write_tables({k: v for k, v in t.items() if k != "wifi"}, tmp_path / "in")
    n = 40_000_000  # one constant, run-length encoded: ~100 KB on disk, 1.3 GB decoded
    pq.write_table(pa.table({c: pa.repeat(v, n) for c, v in
                             (("walk_id", "walk0"), ("t_s", 0.1), ("bssid", "ab"), ("rssi_dbm", -50.0))}),
                   folder / "wifi.parquet", row_group_size=n // 4)
    assert (folder / "wifi.parquet").stat().st_size < 5 << 20
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q")
    one_error(r, r"wifi.parquet: 40,000,000 rows x 4 columns: at most 32,000,000 cells in a Parquet input table")
    assert r.peak_rss_mb < 1024, r.peak_rss_mb


def test_an_ilc_trace_of_a_million_wifi_lines_fits_in_memory(tmp_path: Path) -> None:
    """1e6 TYPE_WIFI lines (~70 MB) took 2.26 GB (the fast parser's index arrays: 8 bytes per byte of the
    file); now the parser works a block of lines at a time."""
    lines = [ln for ln in ILC_FIXTURE.read_text().split("\n") if "TYPE_WIFI" not in ln and ln]
    times = [int(ln.split("\t")[0]) for ln in lines if ln[0].isdigit()]
    t0, t1 = min(times), max(times)
    (tmp_path / "in").mkdir()
    with (tmp_path / "in" / "trace.txt").open("w") as fh:
        fh.write("\n".join(lines) + "\n")
        for s in range(10_000):
            t = t0 + (t1 - t0) * s // 10_000
            fh.write("".join(f"{t}\tTYPE_WIFI\tNet{a}\t0a:00:00:00:00:{a:02x}\t{-40 - a % 50}\t2412\t{t}\n"
                             for a in range(100)))
    r = run_capped("ingest", tmp_path / "in", "-w", tmp_path / "ws", "-q")
    assert r.code == 0, r.err
    assert r.peak_rss_mb < 1024, r.peak_rss_mb


def test_an_ilc_trace_that_is_not_utf8_names_its_line(tmp_path: Path, capsys) -> None:
    """The error named a byte offset of the file, not a line (issue 40)."""
    data = ILC_FIXTURE.read_bytes().split(b"\n")
    data[300] = data[300][:20] + b"\xff\xfe" + data[300][20:]
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_bytes(b"\n".join(data))
    one_error(run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws"),
              r"trace.txt:301: not UTF-8 text \(byte 21 of the line: invalid start byte\)")


# ------------------------------------------------------------------------------ maps, anchors, localize
def test_a_map_spread_over_kilometres_is_refused_before_its_raster_is_allocated() -> None:
    from rmbuild.config import MapConfig
    from rmbuild.errors import InputError
    from rmbuild.radiomap import build_radio_map

    xy = np.array([[0.0, 0.0], [30_000.0, 30_000.0]])
    wifi = pd.DataFrame({"node": [0, 1], "bssid": ["a", "a"], "rssi_dbm": [-50.0, -60.0], "t_s": [0.0, 1.0]})
    with pytest.raises(InputError, match=r"the map's nodes span 30,000 x 30,000 m: at cell_size_m = 2 m a raster "
                                         r"of 225,030,001 cells, at most 4,000,000"):
        build_radio_map(wifi, xy, np.array(["w", "w"]), MapConfig())
    # 1 km apart at 1 m: accepted; the fill looks at the cells' neighbourhoods, not their bounding box
    # (which asked for a (1000 + 2r) x (1000 + 2r) grid of candidates and a Python set of it)
    rm = build_radio_map(wifi, xy / 30.0, np.array(["w", "w"]),
                         MapConfig(cell_size_m=1.0, fill=MapConfig().fill.__class__(method="idw", max_distance_m=3.0)))
    assert rm.cells["interpolated"].sum() == 2 * 28  # the 29 cells within 3 m of each visited one, less itself


def test_the_fill_refuses_more_candidates_than_a_map_holds(monkeypatch) -> None:
    import rmbuild.radiomap.fill as fill
    from rmbuild.config import MapConfig
    from rmbuild.config.radiomap import FillConfig
    from rmbuild.errors import InputError
    from rmbuild.radiomap import build_radio_map

    monkeypatch.setattr(fill, "MAX_MAP_CELLS", 100)
    xy = np.array([[0.0, 0.0], [40.0, 0.0]])
    wifi = pd.DataFrame({"node": [0, 1], "bssid": ["a", "b"], "rssi_dbm": [-50.0, -60.0], "t_s": [0.0, 1.0]})
    with pytest.raises(InputError, match=r"fill: 631 unvisited cells within fill.max_distance_m = 20 m of the 2 "
                                         r"visited ones, x 2 APs: more than the 100 entries"):
        build_radio_map(wifi, xy, np.array(["w", "w"]), MapConfig(fill=FillConfig(method="idw", max_distance_m=20.0)))


def test_an_anchors_file_of_more_than_the_limit_is_refused(tmp_path: Path) -> None:
    from rmbuild.errors import InputError
    from rmbuild.io.anchors import read_anchors

    n = limits.MAX_ANCHORS + 1
    f = tmp_path / "anchors.csv"
    pd.DataFrame({"walk_id": "walk0", "t_s": np.arange(n) * 0.01, "x_m": 1.0, "y_m": 2.0}).to_csv(f, index=False)
    with pytest.raises(InputError, match=rf"^{re.escape(str(f))}:100002: 100,001 anchors: at most 100,000 in one "
                                         "file"):
        read_anchors(f)


@pytest.fixture(scope="module")
def mapped(tmp_path_factory) -> Path:
    """A workspace of the tiny input tables with its radio map."""
    from rmbuild.config import IngestConfig, MapConfig, OptimizeConfig
    from rmbuild.stages import export_map, ingest, optimize

    root = tmp_path_factory.mktemp("mapped")
    inp = write_tables(make_input_tables(n_walks=3, n_steps=40), root / "in")
    ingest.run([inp], root / "ws", IngestConfig())
    optimize.run(root / "ws", OptimizeConfig())
    export_map.run(root / "ws", MapConfig())
    return root / "ws"


def test_localize_of_a_million_one_reading_scans_is_refused_in_bounded_memory(mapped: Path, tmp_path: Path) -> None:
    """`localize` of 1e6 rows took 1.53 GB (a dense 1e6 x APs table of float64 sums and counts)."""
    n = 1_000_000
    (tmp_path / "q").mkdir()
    pd.DataFrame({"walk_id": "q", "t_s": np.arange(n) * 2.0, "bssid": "00:11:22:33:44:01",
                  "rssi_dbm": -60.0}).to_csv(tmp_path / "q" / "wifi.csv", index=False)
    r = run_capped("localize", tmp_path / "q", "-w", mapped, "-o", tmp_path / "out.csv", "-q")
    one_error(r, rf"{re.escape(str(tmp_path / 'q'))}: 1,000,000 scans: at most 250,000 in one run")
    assert r.peak_rss_mb < 1024 and not (tmp_path / "out.csv").exists(), r.peak_rss_mb


def test_localize_at_the_query_limit_fits_in_memory(mapped: Path, tmp_path: Path) -> None:
    n = limits.MAX_QUERIES
    (tmp_path / "q").mkdir()
    pd.DataFrame({"walk_id": "q", "t_s": np.arange(n) * 2.0, "bssid": "00:11:22:33:44:01",
                  "rssi_dbm": -60.0}).to_csv(tmp_path / "q" / "wifi.csv", index=False)
    r = run_capped("localize", tmp_path / "q", "-w", mapped, "-o", tmp_path / "out.csv", "-q")
    assert r.code == 0 and r.peak_rss_mb < 1024, (r.err, r.peak_rss_mb)
    assert len(pd.read_csv(tmp_path / "out.csv")) == n


def test_an_error_of_a_stage_without_a_place_names_the_workspace(mapped: Path, tmp_path: Path, capsys,
                                                                  monkeypatch) -> None:
    """make fuzz case extreme/11000833: true paths stretched 1000-fold made evaluate's surveyed map too large to
    raster; the error was clean but named no file."""
    import shutil

    import rmbuild.radiomap.build as build

    ws = tmp_path / "ws"
    shutil.copytree(mapped, ws)
    monkeypatch.setattr(build, "MAX_MAP_RASTER_CELLS", 10)
    one_error(run_cli(capsys, "export-map", "-w", ws, "--force"),
              rf"^error: {re.escape(str(ws))}: the map's nodes span .* at most 10 ")
    # evaluate's own: its walks carry too few fixes to score the map
    one_error(run_cli(capsys, "evaluate", "-w", ws, "--force"), rf"^error: {re.escape(str(ws))}: cannot align the map")


# ------------------------------------------------------------------------------ devices named as files
def _ilc_floor(folder: Path) -> Path:
    (folder / "path_data_files").mkdir(parents=True)
    (folder / "path_data_files" / "trace.txt").write_text(ILC_FIXTURE.read_text())
    (folder / "geojson_map.json").write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, "geometry": {"type": '
        '"Polygon", "coordinates": [[[116.0, 39.0], [116.001, 39.0], [116.001, 39.001], [116.0, 39.0]]]}}]}')
    (folder / "floor_info.json").write_text('{"map_info": {"height": 100, "width": 100}}')
    return folder


@pytest.mark.parametrize("where", ["plan", "config", "venues", "floor_info", "trace"])
def test_a_device_given_as_a_file_is_refused_unread(where: str, tmp_path: Path) -> None:
    """A floor plan, config, venues file, floor_info.json or trace that is /dev/zero (or a link to it) has no
    size in its metadata: a floor plan read it whole until memory ran out (MemoryError, exit 1)."""
    folder = _ilc_floor(tmp_path / "F1")
    ws = tmp_path / "ws"
    args: list[str | Path] = ["ingest", folder, "-w", ws, "-q"]
    named = Path("/dev/zero")
    if where == "plan":
        args += ["--floorplan", "/dev/zero"]
    elif where == "config":
        args += ["--config", "/dev/zero"]
    elif where == "venues":
        args = ["build", "--venues", "/dev/zero", "-o", tmp_path / "out", "--scheduler", "serial"]
    else:
        named = folder / ("floor_info.json" if where == "floor_info" else "path_data_files/trace.txt")
        named.unlink()
        named.symlink_to("/dev/zero")
    r = run_capped(*args, timeout_s=60)
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.peak_rss_mb < 1024, r.peak_rss_mb
    if where in ("floor_info", "trace"):  # a folder's entries that are no regular files are not input files
        assert r.code in (0, 2) and "Traceback" not in r.err and "internal error" not in r.err, r.err
        return
    assert r.code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {named}"), r.err
    assert re.search(r"not a regular file", lines[0]) and not ws.exists(), lines[0]


def test_limits_on_what_a_file_may_hold_live_in_limits_py() -> None:
    """One place for the limits a user meets (docs/reliability.md lists them): no module of rmbuild defines
    a MAX_..._BYTES of input, or passes a literal byte count to the JSON reader."""
    root = Path(limits.__file__).parent
    bad = []
    for f in sorted(root.rglob("*.py")):
        if f.name == "limits.py":
            continue
        for i, line in enumerate(f.read_text().splitlines(), 1):
            if re.match(r"^MAX_\w*(BYTES|VENUES|PIXELS)\w*\s*[:=]", line) and "MARKER" not in line:
                bad.append(f"{f.relative_to(root)}:{i}: {line.strip()}")
            if re.search(r"read_json_file\([^,]+,\s*\d", line):
                bad.append(f"{f.relative_to(root)}:{i}: {line.strip()}")
    assert bad == []
