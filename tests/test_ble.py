"""BLE beacon readings: the three readers, ingest's checks and attachment, and export-map's BLE radio map."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild.config.ingest import IngestConfig, MsftIlcConfig
from rmbuild.errors import InputError
from rmbuild.ingest.core import build_dataset
from rmbuild.io.formats.ipin import IpinReader
from rmbuild.io.formats.msft_ilc import MsftIlcReader, parse_trace
from rmbuild.io.formats.rmbuild_schema import RmbuildSchemaReader
from rmbuild.io.workspace import Workspace

HERE = Path(__file__).resolve().parent
ILC_TRACE = HERE / "fixtures" / "msft_ilc" / "tiny_trace.txt"
IPIN_LOG = HERE / "fixtures" / "ipin" / "tiny_logfile.txt"
EMBEDDED = HERE.parent / "datasets"
BEACON = "1574559498333\tTYPE_BEACON\tFDA50693-A4E2-4FB1-AFCF-C6EB07647825\t10065\t26049\t-58\t-81\t11.93\t" \
         "DC:0D:30:4E:B8:72\t1574559498333"


def _write(tmp_path: Path, lines: list[str], name: str) -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


# --- MS ILC: TYPE_BEACON --------------------------------------------------------------------------------

def test_ilc_beacon_lines_are_ble_readings():
    raw = MsftIlcReader().read([ILC_TRACE], IngestConfig())
    assert "TYPE_BEACON" not in raw.skipped and raw.skipped["TYPE_BLUE"] == 24  # TYPE_BLUE: still unused
    b = raw.ble
    assert b is not None and len(b) == 1
    row = b.iloc[0]
    assert (row["walk_id"], row["bssid"], row["rssi_dbm"]) == ("tiny_trace", "dc:0d:30:4e:b8:72", -81.0)
    assert row["ssid"] == "FDA50693-A4E2-4FB1-AFCF-C6EB07647825:10065:26049"
    assert row["t_s"] == pytest.approx(1574559498.333)
    line = ILC_TRACE.read_text(encoding="utf-8").splitlines().index(BEACON) + 1
    assert raw.where["ble"](0) == f"{ILC_TRACE}:{line}"


def test_ilc_repeated_beacon_kept_once_and_fast_slow_paths_agree(tmp_path):
    lines = ILC_TRACE.read_text(encoding="utf-8").splitlines()
    i = lines.index(BEACON)
    later = BEACON.replace("1574559498333", "1574559499000").replace("-81", "-77")
    lines[i + 1:i + 1] = [BEACON.replace("-81", "-90"), later]   # the same (time, MAC) again, then a later one
    p = _write(tmp_path, lines, "t.txt")
    tr = parse_trace(p, MsftIlcConfig())
    assert list(tr.ble["rssi_dbm"]) == [-81.0, -77.0] and tr.n_ble_dup == 1
    assert list(tr.ble_lines) == [i + 1, i + 3]
    # a line the fast parser cannot take (a comment in the data) sends the whole file through the slow one
    lines.insert(5, "not a trace line")
    q = _write(tmp_path, lines, "bad.txt")
    with pytest.raises(InputError, match="not a Microsoft ILC trace line"):
        parse_trace(q, MsftIlcConfig())


@pytest.mark.parametrize("edit, message", [
    (lambda s: s.rsplit("\t", 1)[0], "TYPE_BEACON: expected 10 tab-separated fields, got 9"),
    (lambda s: s.replace("\t-81\t", "\tloud\t"), "TYPE_BEACON: non-numeric"),
    (lambda s: s.replace("DC:0D:30:4E:B8:72", " "), "TYPE_BEACON: empty MAC"),
])
def test_ilc_malformed_beacon_line_names_file_and_line(tmp_path, edit, message):
    lines = ILC_TRACE.read_text(encoding="utf-8").splitlines()
    i = lines.index(BEACON)
    lines[i] = edit(lines[i])
    p = _write(tmp_path, lines, "t.txt")
    with pytest.raises(InputError, match=message) as e:
        MsftIlcReader().read([p], IngestConfig())
    assert e.value.where == f"{p}:{i + 1}"


# --- IPIN: BLE4 ---------------------------------------------------------------------------------------

IBEACON = "BLE4;2.2265;iBeacon;BE:AC:20:23:00:02;-79;0;1;2;11111111-1111-BEAC-2023-111111111111"
EDDY = "BLE4;3.5;Eddystone;BE:AC:20:23:00:07;-88;0x12ab;3000;21;100;7"


def _ipin_with(tmp_path: Path, extra: list[str]) -> tuple[Path, int]:
    """The phone fixture with ``extra`` lines after its first WIFI line; (file, line of the first extra)."""
    lines = IPIN_LOG.read_text(encoding="utf-8").splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("WIFI;")) + 1
    lines[i:i] = extra
    return _write(tmp_path, lines, "log.txt"), i + 1


def test_ipin_ble4_lines_are_ble_readings(tmp_path):
    p, line = _ipin_with(tmp_path, [IBEACON, EDDY, IBEACON.replace("2.2265", "2.4").replace("-79", "-73")])
    raw = IpinReader().read([p], IngestConfig())
    assert "BLE4" not in raw.skipped
    b = raw.ble
    assert b is not None and list(b["bssid"]) == ["be:ac:20:23:00:02", "be:ac:20:23:00:02", "be:ac:20:23:00:07"]
    assert list(b["rssi_dbm"]) == [-79.0, -73.0, -88.0]
    assert list(b["ssid"]) == ["11111111-1111-BEAC-2023-111111111111:1:2"] * 2 + [""]
    # app times made absolute with the header's creation time, like every other tag
    assert b["t_s"].iat[1] - b["t_s"].iat[0] == pytest.approx(0.1735)
    assert raw.where["ble"](2) == f"{p}:{line + 1}"


@pytest.mark.parametrize("bad, message", [
    (IBEACON.replace("BE:AC:20:23:00:02", "beacon-2"), "BLE4: MAC 'beacon-2' is not a MAC address"),
    (IBEACON.rsplit(";", 1)[0], "BLE4: an iBeacon line has 9 ';'-separated fields, got 8"),
    (IBEACON.replace("iBeacon", "AltBeacon"), "unknown beacon kind 'AltBeacon'"),
    (IBEACON.replace("-79", "n/a"), "BLE4: non-numeric value 'n/a'"),
])
def test_ipin_malformed_ble4_names_file_and_line(tmp_path, bad, message):
    p, line = _ipin_with(tmp_path, [bad])
    with pytest.raises(InputError, match=message) as e:
        IpinReader().read([p], IngestConfig())
    assert e.value.where == f"{p}:{line}"


# --- rmbuild schema: the ble table, checks and attachment -----------------------------------------------

def _tables_with_ble(rows: list[tuple]) -> dict[str, pd.DataFrame]:
    t = make_input_tables()
    t["ble"] = pd.DataFrame(rows, columns=["walk_id", "t_s", "bssid", "rssi_dbm"])
    return t


def _raw(folder: Path):
    return RmbuildSchemaReader().read(sorted(folder.glob("*.csv")), IngestConfig())


def test_schema_ble_table_is_attached_like_wifi(tmp_path):
    # walk0's poses are at 0.5 s steps from t=0; walk1's from t=100
    rows = [("walk0", 0.7, "b1", -70.0), ("walk0", 0.7, "b2", -80.0), ("walk0", 3.1, "b1", -65.0),
            ("walk1", 100.2, "b1", -75.0), ("walk1", 500.0, "b2", -60.0)]   # the last: long after walk1's poses
    folder = write_tables(_tables_with_ble(rows), tmp_path / "in")
    ds, _, summary = build_dataset(_raw(folder), IngestConfig())
    b = ds.ble
    assert b is not None and list(b.columns) == list(ds.wifi.columns)
    assert list(b["node"]) == [1, 1, 6, 30]   # interval attachment: node k takes t_k <= t < t_k+1
    assert b["rssi_dbm"].dtype == np.float32 and (b["ssid"] == "").all() and b["freq_mhz"].isna().all()
    assert summary["ble"] == {"readings": 4, "beacons": 2, "readings_dropped_outside_walk": 1}
    assert any("1 BLE reading(s) more than 2 s outside" in w for w in summary["warnings"])
    # no ble table: the dataset and summary carry nothing of BLE
    folder2 = write_tables(make_input_tables(), tmp_path / "in2")
    ds2, _, summary2 = build_dataset(_raw(folder2), IngestConfig())
    assert ds2.ble is None and "ble" not in summary2


@pytest.mark.parametrize("rows, message, row", [
    ([("walk0", 1.0, "b1", -70.0), ("walk0", 2.0, "b1", 5.0)], "ble: rssi_dbm 5.0 outside [-120, 0] dBm", 3),
    ([("walk0", 2.0, "b1", -70.0), ("walk0", 1.0, "b1", -60.0)], "ble: time goes backwards in walk 'walk0'", 3),
    ([("walk0", 1.0, "b1", -70.0), ("walk0", 1.0, "b1", -60.0)], "duplicate BLE reading (walk 'walk0'", 3),
    ([("walk0", 1.0, "b1", -70.0), ("walk9", 1.0, "b1", -60.0)], "BLE reading of walk 'walk9', which has no poses",
     3),
])
def test_schema_bad_ble_rows_are_errors_naming_file_and_line(tmp_path, capsys, rows, message, row):
    folder = write_tables(_tables_with_ble(rows), tmp_path / "in")
    with pytest.raises(InputError) as e:
        build_dataset(_raw(folder), IngestConfig())
    assert message in str(e.value) and e.value.where == f"{folder / 'ble.csv'}:{row}"
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and r.err.count("\n") == 1 and f"ble.csv:{row}" in r.err


# --- export-map: the BLE map beside the Wi-Fi one ------------------------------------------------------

def _add_beacons(folder: Path, n: int = 4, seed: int = 0) -> pd.DataFrame:
    """A ble.csv for a simulated input: ``n`` beacons at random true positions, heard every second within
    ~15 m with a steep path loss (-59 dBm at 1 m, exponent 3, 2 dB noise)."""
    rng = np.random.default_rng(seed)
    truth = pd.read_csv(folder / "truth" / "poses.csv")
    at = truth[["x_m", "y_m"]].to_numpy()[rng.choice(len(truth), n, replace=False)]
    rows = []
    for wid, g in truth.groupby("walk_id", sort=False):
        t = np.arange(g["t_s"].min(), g["t_s"].max(), 1.0)
        xy = np.c_[np.interp(t, g["t_s"], g["x_m"]), np.interp(t, g["t_s"], g["y_m"])]
        for j, b in enumerate(at):
            d = np.maximum(np.hypot(*(xy - b).T), 1.0)
            rssi = -59.0 - 30.0 * np.log10(d) + rng.normal(0, 2, len(d))
            for k in np.flatnonzero(rssi > -95):
                rows.append((wid, round(float(t[k]), 3), f"be:ac:00:00:00:{j:02x}", round(float(rssi[k]), 1)))
    ble = pd.DataFrame(rows, columns=["walk_id", "t_s", "bssid", "rssi_dbm"]).sort_values(["walk_id", "t_s"],
                                                                                          kind="stable")
    ble.to_csv(folder / "ble.csv", index=False)
    return ble


@pytest.fixture(scope="module")
def ble_ws(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("ble")
    from rmbuild.cli import main

    with pytest.raises(SystemExit):
        main(["simulate", str(base / "in"), "--preset", "tiny", "--seed", "5", "-q"])
    _add_beacons(base / "in")
    for args in (["ingest", base / "in", "-w", base / "ws", "-q"], ["optimize", "-w", base / "ws", "-q"],
                 ["export-map", "-w", base / "ws", "-q"]):
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0, args
    return base / "ws"


def test_export_map_writes_the_ble_map_on_the_wifi_grid(ble_ws: Path):
    ws = Workspace.open(ble_ws)
    rep = json.loads(ws.report_path("map").read_text())
    assert rep["ble"]["beacons"] == 4 and rep["ble"]["cells"] > 0
    assert sorted(rep["ble"]["files"]) == sorted(
        ["map/radiomap_ble.parquet", "map/cells_ble.parquet", "map/radiomap_ble_uji.csv",
         "map/radiomap_ble_uji_aps.csv", "map/radiomap_ble.json"])
    record = json.loads((ble_ws / "map" / "stage.json").read_text())
    assert set(rep["ble"]["files"]) <= set(record["files"])   # checksummed with the rest of the stage
    wifi_side, ble_side = ws.read_json("map.sidecar"), ws.read_json("map.ble_sidecar")
    assert ble_side["grid"]["origin_xy_m"] == wifi_side["grid"]["origin_xy_m"]
    assert ble_side["grid"]["cell_size_m"] == wifi_side["grid"]["cell_size_m"] and ble_side["modality"] == "ble"
    assert ble_side["aps"] == [f"be:ac:00:00:00:{j:02x}" for j in range(4)]
    cells, wcells = ws.read_table("map.ble_cell_table"), ws.read_table("map.cell_table")
    both = cells.merge(wcells, on=["ix", "iy"], suffixes=("", "_wifi"))
    assert len(both) > 0.5 * len(cells)   # same grid: a shared cell has the same centre
    assert np.allclose(both[["x_m", "y_m"]], both[["x_m_wifi", "y_m_wifi"]].to_numpy())
    long = ws.read_table("map.ble_cells")
    assert set(long.columns) == set(ws.read_table("map.cells").columns)
    assert long["rssi_mean_dbm"].between(-95, -40).all() and (long["count"] >= 1).all()
    wide = pd.read_csv(ws.path("map.ble_wide_csv"))
    assert [c for c in wide.columns if c.startswith("WAP")] == ["WAP001", "WAP002", "WAP003", "WAP004"]
    assert len(wide) == len(cells)


def test_ble_map_strongest_near_its_beacon(ble_ws: Path):
    """Each beacon's strongest cell lies within a few metres of where it is heard loudest in the truth."""
    ws = Workspace.open(ble_ws)
    long = ws.read_table("map.ble_cells")
    long = long[long["count"] >= 2]
    spread = []
    for _, g in long.groupby("bssid"):
        top = g.nlargest(1, "rssi_mean_dbm").iloc[0]
        near = g[g["rssi_mean_dbm"] >= top["rssi_mean_dbm"] - 6.0]
        spread.append(float(np.hypot(near["x_m"] - top["x_m"], near["y_m"] - top["y_m"]).max()))
    # the steep path loss: the cells within 6 dB of a beacon's peak are all within ~10 m of the peak cell
    assert len(spread) == 4 and max(spread) < 12.0


def test_workspace_without_ble_writes_no_ble_files(tmp_path, capsys):
    folder = write_tables(make_input_tables(n_walks=3), tmp_path / "in")
    assert run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws", "-q").code == 0
    assert not (tmp_path / "ws" / "data" / "ble.parquet").exists()
    assert "ble" not in json.loads((tmp_path / "ws" / "data" / "report.json").read_text())


# --- real data ------------------------------------------------------------------------------------------

def test_embedded_ilc_floor_has_beacons(tmp_path, capsys):
    floor = EMBEDDED / "msft-ilc20" / "site1" / "F1"
    if not floor.is_dir():
        pytest.skip("datasets/msft-ilc20 not present")
    r = run_cli(capsys, "ingest", floor, "-w", tmp_path / "ws")
    assert r.code == 0 and "BLE readings of" in r.out
    rep = json.loads((tmp_path / "ws" / "data" / "report.json").read_text())
    ws = Workspace.open(tmp_path / "ws")
    ble = ws.read_dataset().ble
    assert ble is not None and rep["ble"]["readings"] == len(ble) > 1000
    assert ble["bssid"].str.fullmatch(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}").all()
    assert ble["rssi_dbm"].between(-110, -30).all() and (ble["node"] >= 0).all()
    # the mall's beacons share one iBeacon identity: the MAC is what tells them apart
    per_ident = ble.groupby("ssid")["bssid"].nunique()
    assert per_ident.max() > 20


def test_real_ipin_logfiles_have_six_beacons(shared_datasets: Path):
    logs = sorted((shared_datasets / "ipin2023" / "logs").glob("*.txt.gz"))[:4]
    raw = IpinReader().read(logs, IngestConfig())
    assert raw.ble is not None and len(raw.ble) > 1000
    ids = raw.ble.groupby("bssid")["ssid"].unique()
    assert len(ids) <= 6 and all(len(v) == 1 for v in ids)   # one iBeacon identity per MAC
    assert set(raw.ble["bssid"].str[:15]) == {"be:ac:20:23:00:"}


def test_real_ilc_site_split_keeps_ble_per_floor(shared_datasets: Path, tmp_path):
    site = shared_datasets / "msft-ilc20" / "data" / "site2"
    files = [f for fl in ("F4", "B1") for f in sorted((site / fl / "path_data_files").glob("*.txt.gz"))[:3]]
    from rmbuild.ingest.floors import split_floors

    raw = MsftIlcReader().read(files, IngestConfig())
    floors = split_floors(raw)
    assert floors is not None and set(floors) == {"F4", "B1"}
    n = sum(len(f.ble) for f in floors.values() if f.ble is not None)
    assert raw.ble is not None and n == len(raw.ble) > 0
    for f in floors.values():
        if f.ble is not None and len(f.ble):
            assert set(f.ble["walk_id"]) <= set(f.walks["walk_id"])


# --- simulate: beacons of their own ---------------------------------------------------------------------

def test_simulated_beacons_peak_where_they_are(tmp_path, capsys):
    """`simulate` with [simulate.ble] n_beacons writes ble.csv and truth/beacons.csv without changing any
    other table; a map of the ingested readings at the true positions peaks within a cell or two of each
    beacon."""
    from rmbuild.radiomap import build_radio_map

    (tmp_path / "ble.toml").write_text("[simulate.ble]\nn_beacons = 5\n")
    for out, extra in (("plain", []), ("ble", ["--config", tmp_path / "ble.toml"])):
        r = run_cli(capsys, "simulate", tmp_path / out, "--preset", "tiny", "--seed", "3", "-q", *extra)
        assert r.code == 0, r.err
    for name in ("wifi.csv", "poses.csv", "fixes.csv", "walks.csv", "truth/poses.csv", "truth/aps.csv"):
        assert (tmp_path / "plain" / name).read_bytes() == (tmp_path / "ble" / name).read_bytes(), name
    assert not (tmp_path / "plain" / "ble.csv").exists()
    assert run_cli(capsys, "ingest", tmp_path / "ble", "-w", tmp_path / "ws", "-q").code == 0
    ds = Workspace.open(tmp_path / "ws").read_dataset()
    beacons = ds.extra["truth"]["beacons"]
    assert ds.ble is not None and len(beacons) == 5 and set(ds.ble["bssid"]) <= set(beacons["bssid"])
    truth_xy = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    rm = build_radio_map(ds.ble, truth_xy, ds.poses["walk_id"].astype(str).to_numpy())
    long = rm.long_table()
    long = long[long["count"] >= 2]
    for _, b in beacons.iterrows():
        g = long[long["bssid"] == b["bssid"]]
        d = np.hypot(g["x_m"] - b["x_m"], g["y_m"] - b["y_m"]).to_numpy()
        top = int(np.argmax(g["rssi_mean_dbm"].to_numpy()))
        # the loudest cell is (nearly) the nearest cell the walks passed through
        assert d[top] < d.min() + 3.0, (b["bssid"], d[top], d.min())
        expect = -59.0 - 30.0 * np.log10(max(d[top], 1.0))
        assert abs(g["rssi_mean_dbm"].iat[top] - expect) < 8.0


def test_append_keeps_ble_readings_on_their_nodes(tmp_path, capsys):
    """Ingesting walk0 then appending walk1 gives the BLE table of ingesting both at once."""
    rows = [("walk0", 0.7, "b1", -70.0), ("walk0", 3.1, "b2", -65.0), ("walk1", 100.2, "b1", -75.0),
            ("walk1", 104.0, "b2", -61.0)]
    tables = _tables_with_ble(rows)
    parts = {}
    for w in ("walk0", "walk1"):
        parts[w] = write_tables({k: v[v["walk_id"] == w] for k, v in tables.items()}, tmp_path / w)
    assert run_cli(capsys, "ingest", parts["walk0"], "-w", tmp_path / "ws", "-q").code == 0
    assert run_cli(capsys, "ingest", parts["walk1"], "-w", tmp_path / "ws", "--append", "-q").code == 0
    assert run_cli(capsys, "ingest", write_tables(tables, tmp_path / "all"), "-w", tmp_path / "ws_all", "-q").code == 0
    appended = Workspace.open(tmp_path / "ws").read_dataset().ble
    whole = Workspace.open(tmp_path / "ws_all").read_dataset().ble
    assert appended is not None and whole is not None
    pd.testing.assert_frame_equal(appended, whole)
    assert json.loads((tmp_path / "ws" / "data" / "report.json").read_text())["ble"]["readings"] == 4
