"""Microsoft ILC 2.0 trace reader: tiny fixture, malformed input, sniffing, and real data when present."""

from __future__ import annotations

import gzip
import time
from pathlib import Path

import numpy as np
import pytest

from rmbuild.config.ingest import IngestConfig, MsftIlcConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.errors import InputError
from rmbuild.ingest.core import derive_poses
from rmbuild.io.formats.ipin import IpinReader
from rmbuild.io.formats.msft_ilc import MsftIlcReader, parse_trace

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "msft_ilc" / "tiny_trace.txt"
DATASETS = Path(__file__).resolve().parents[2] / "shared" / "datasets"
ILC = DATASETS / "msft-ilc20" / "data"


def read(files, options: PdrConfig | None = None, ilc: MsftIlcConfig | None = None):
    """The reader's raw input, with the PDR run on its raw IMU as ingest does."""
    raw = MsftIlcReader().read([Path(f) for f in files], IngestConfig(msft_ilc=ilc or MsftIlcConfig()))
    derive_poses(raw, options or PdrConfig())
    return raw


def fixture_lines() -> list[str]:
    return FIXTURE.read_text(encoding="utf-8").splitlines()


def write(tmp_path: Path, lines: list[str], name: str = "trace.txt") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def line_of(lines: list[str], typ: str, k: int = 0) -> int:
    """0-based index of the k-th line of type ``typ``."""
    return [i for i, ln in enumerate(lines) if ln.split("\t")[1:2] == [typ]][k]


def test_reader_only_reads():
    raw = MsftIlcReader().read([FIXTURE], IngestConfig())
    assert len(raw.poses) == 0 and list(raw.imu) == ["tiny_trace"]
    imu = raw.imu["tiny_trace"]
    lines = fixture_lines()
    for stream, typ in (("acc", "TYPE_ACCELEROMETER"), ("gyro", "TYPE_GYROSCOPE"), ("yaw", "TYPE_ROTATION_VECTOR")):
        assert lines[int(imu.lines[stream][0]) - 1].split("\t")[1] == typ
    assert imu.where("acc", 2) == f"{FIXTURE}:{imu.lines['acc'][2]}"


def test_fixture_reads():
    raw = read([FIXTURE])
    assert list(raw.walks["walk_id"]) == ["tiny_trace"]
    assert raw.walks["device_id"].iat[0] == "PHONE1" and raw.walks["source"].iat[0] == "msft-ilc"
    p = raw.poses
    assert len(p) == 21   # start + 20 steps
    assert (p["x_m"].iat[0], p["y_m"].iat[0], p["heading_rad"].iat[0]) == (0, 0, 0)
    # 10 steps east, then 10 north (a left turn of 90°)
    assert p["heading_rad"].iat[-1] == pytest.approx(np.pi / 2, abs=0.05)
    assert p["x_m"].iat[-1] == pytest.approx(10 * 0.7, rel=0.15)
    assert p["yaw_abs_rad"].iat[3] == pytest.approx(0.0, abs=0.05)            # east in ENU
    assert np.all(np.diff(p["t_s"]) > 0)
    # Wi-Fi: 4 scans x 5 rows, the stale row of each dropped; empty SSID kept
    assert len(raw.wifi) == 16 and raw.wifi["bssid"].str.match(r"^0a(:00){4}:0[0-3]$").all()
    assert (raw.wifi["ssid"] == "").sum() == 4
    assert any("dropped 4 of 20 Wi-Fi rows" in n for n in raw.notes)
    # waypoints are ground truth fixes in the floor frame
    assert list(raw.fixes["x_m"]) == [50.0, 55.0, 55.0] and list(raw.fixes["floor"]) == ["F1"] * 3
    assert raw.skipped == {"TYPE_ACCELEROMETER_UNCALIBRATED": 60, "TYPE_BLUE": 24}   # TYPE_BEACON: BLE readings
    where = raw.where["wifi"](0)
    assert where.startswith(str(FIXTURE)) and int(where.rsplit(":", 1)[1]) > 4


def test_gzip_and_wifi_age_option(tmp_path):
    gz = tmp_path / "tiny_trace.txt.gz"
    gz.write_bytes(gzip.compress(FIXTURE.read_bytes()))
    a, b = read([FIXTURE]), read([gz])
    assert a.poses.drop(columns="walk_id").equals(b.poses.drop(columns="walk_id"))
    assert list(b.walks["walk_id"]) == ["tiny_trace"]
    keep_all = read([gz], ilc=MsftIlcConfig(max_wifi_age_s=60.0))
    assert len(keep_all.wifi) == 20


def test_out_of_order_lines_are_sorted(tmp_path):
    lines = fixture_lines()
    body = lines[4:-1]
    shuffled = lines[:4] + body[::-1] + lines[-1:]
    a, b = read([FIXTURE]), read([write(tmp_path, shuffled, "tiny_trace.txt")])
    np.testing.assert_allclose(a.poses["x_m"], b.poses["x_m"])
    assert a.wifi[["t_s", "bssid"]].sort_values(["t_s", "bssid"]).to_numpy().tolist() == \
        b.wifi[["t_s", "bssid"]].sort_values(["t_s", "bssid"]).to_numpy().tolist()


@pytest.mark.parametrize("mutate, message", [
    (lambda ls, i: ls.__setitem__(i, ls[i].rsplit("\t", 2)[0]), "expected 6 tab-separated fields, got 4"),
    (lambda ls, i: ls.__setitem__(i, ls[i] + "\t7"), "expected 6 tab-separated fields, got 7"),
    (lambda ls, i: ls.__setitem__(i, ls[i].replace("\t3", "\tabc", 1) if ls[i].endswith("\t3") else ls[i]),
     "non-numeric"),
    (lambda ls, i: ls.__setitem__(i, ls[i].split("\t")[0]), "truncated line"),
    (lambda ls, i: ls.__setitem__(i, "garbage line"), "not a Microsoft ILC trace line"),
    (lambda ls, i: ls.__setitem__(i, ls[i].replace("TYPE_ACCELEROMETER\t", "TYPE_ACCELEROMETER\tnan\t", 1)
                                  .rsplit("\t", 1)[0]), "non-finite"),
])
def test_malformed_accelerometer_line_names_file_and_line(tmp_path, mutate, message):
    lines = fixture_lines()
    i = line_of(lines, "TYPE_ACCELEROMETER", 7)
    mutate(lines, i)
    p = write(tmp_path, lines)
    with pytest.raises(InputError) as e:
        read([p])
    assert message in str(e.value)
    assert e.value.where == f"{p}:{i + 1}"
    assert "\n" not in str(e.value)


def test_malformed_wifi_and_waypoint_lines(tmp_path):
    lines = fixture_lines()
    i = line_of(lines, "TYPE_WIFI", 2)
    f = lines[i].split("\t")
    f[4] = "loud"
    lines[i] = "\t".join(f)
    p = write(tmp_path, lines)
    with pytest.raises(InputError, match="TYPE_WIFI: non-numeric") as e:
        read([p])
    assert e.value.where == f"{p}:{i + 1}"
    lines = fixture_lines()
    j = line_of(lines, "TYPE_WAYPOINT", 1)
    lines[j] = lines[j] + "\t3.0"
    p = write(tmp_path, lines)
    with pytest.raises(InputError, match="TYPE_WAYPOINT: expected 4") as e:
        read([p])
    assert e.value.where == f"{p}:{j + 1}"


def test_bad_rotation_vector(tmp_path):
    lines = fixture_lines()
    i = line_of(lines, "TYPE_ROTATION_VECTOR", 5)
    f = lines[i].split("\t")
    f[2:5] = ["0.9", "0.9", "0.9"]
    lines[i] = "\t".join(f)
    p = write(tmp_path, lines)
    with pytest.raises(InputError, match="not a rotation vector") as e:
        read([p])
    assert e.value.where == f"{p}:{i + 1}"


def test_file_without_wifi_or_imu(tmp_path):
    lines = fixture_lines()
    no_wifi = write(tmp_path, [ln for ln in lines if "\tTYPE_WIFI\t" not in ln], "nowifi.txt")
    ok = read([no_wifi])  # kept as a walk without radio evidence; the note names the file
    assert len(ok.wifi) == 0 and len(ok.poses) == 21
    assert f"{no_wifi}: no usable Wi-Fi readings (no TYPE_WIFI lines)" in ok.notes
    no_acc = write(tmp_path, [ln for ln in lines if "\tTYPE_ACCELEROMETER\t" not in ln], "noacc.txt")
    with pytest.raises(InputError, match="no TYPE_ACCELEROMETER") as e:
        read([no_acc])
    assert e.value.where == str(no_acc)
    no_rot = write(tmp_path, [ln for ln in lines if "\tTYPE_ROTATION_VECTOR\t" not in ln], "norot.txt")
    with pytest.raises(InputError, match="no rotation-vector / AHRS samples"):
        read([no_rot], PdrConfig(heading_source="rotation_vector"))
    header_only = write(tmp_path, [ln for ln in lines if ln.startswith("#")], "header.txt")
    with pytest.raises(InputError, match="no data lines"):
        read([header_only])


def test_bad_gzip(tmp_path):
    bad = tmp_path / "bad.txt.gz"
    bad.write_bytes(b"this is not gzip data at all")
    with pytest.raises(InputError, match="gzip") as e:
        read([bad])
    assert e.value.where == str(bad)
    cut = tmp_path / "cut.txt.gz"
    cut.write_bytes(gzip.compress(FIXTURE.read_bytes())[:3000])
    with pytest.raises(InputError, match="truncated"):
        read([cut])


def test_sniff_is_specific(tmp_path):
    assert MsftIlcReader.sniff([FIXTURE])
    ipin = Path(__file__).resolve().parent / "fixtures" / "ipin" / "tiny_logfile.txt"
    assert not MsftIlcReader.sniff([ipin]) and not MsftIlcReader.sniff([FIXTURE, ipin])
    assert not IpinReader.sniff([FIXTURE])
    for name in ("poses.csv", "wifi.csv", "walks.csv", "fixes.csv"):
        f = tmp_path / name
        f.write_text("walk_id,t_s\nw,1.0\n")
        assert not MsftIlcReader.sniff([f]) and not IpinReader.sniff([f])
    # companion files of the published layout are ignored, anything else is an error
    (tmp_path / "floor_info.json").write_text("{}")
    assert MsftIlcReader.sniff([FIXTURE, tmp_path / "floor_info.json"])
    raw = read([FIXTURE, tmp_path / "floor_info.json"])
    assert any("companion" in n for n in raw.notes)
    with pytest.raises(InputError, match="mixed formats"):
        read([FIXTURE, ipin])


def test_a_trace_without_wifi_among_others_is_kept_and_named(tmp_path, capsys):
    from cli_util import run_cli

    lines = fixture_lines()
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "with_wifi.txt").write_text("\n".join(lines))
    (tmp_path / "in" / "no_wifi.txt").write_text("\n".join(ln for ln in lines if "\tTYPE_WIFI\t" not in ln))
    r = run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    assert "1 walk(s) without Wi-Fi readings kept without radio evidence" in r.err and "no_wifi" in r.err


def test_duplicate_walk_ids(tmp_path):
    gz = tmp_path / "tiny_trace.txt.gz"
    gz.write_bytes(gzip.compress(FIXTURE.read_bytes()))
    with pytest.raises(InputError, match="duplicate trace id"):
        read([FIXTURE, gz])


def test_parse_trace_fast_and_slow_paths_agree(tmp_path):
    from rmbuild.io.formats import msft_ilc

    raw = FIXTURE.read_bytes()
    fast = msft_ilc._rows_fast(raw)
    assert fast is not None
    slow = msft_ilc._rows_slow(raw.decode(), FIXTURE)
    assert fast[1] == slow[1]
    for k in fast[0]:
        np.testing.assert_array_equal(fast[0][k].t_ms, slow[0][k].t_ms)
        np.testing.assert_array_equal(fast[0][k].line, slow[0][k].line)
        np.testing.assert_allclose(fast[0][k].num, slow[0][k].num)


@pytest.mark.realdata
@pytest.mark.skipif(not ILC.is_dir(), reason="../shared/datasets/msft-ilc20 not present")
def test_real_site2_f4_pdr_against_waypoints():
    files = sorted((ILC / "site2" / "F4" / "path_data_files").glob("*.txt.gz"))
    assert len(files) == 26
    t = time.perf_counter()
    raw = read(files)
    assert time.perf_counter() - t < 40
    assert raw.walks["device_id"].eq("PBCM10").all()
    assert len(raw.fixes) == 193
    assert "TYPE_BEACON" not in raw.skipped and raw.ble is not None and len(raw.ble) > 0
    # walked distance / waypoint path length between the first and last waypoint, per walk
    ratios = []
    for wid, fx in raw.fixes.groupby("walk_id"):
        p = raw.poses[raw.poses["walk_id"] == wid]
        inside = (p["t_s"] > fx["t_s"].min()) & (p["t_s"] <= fx["t_s"].max())
        walked = inside.sum() * PdrConfig().step_length_m
        path = np.hypot(np.diff(fx["x_m"]), np.diff(fx["y_m"])).sum()
        ratios.append(walked / path)
    assert 0.9 < np.median(ratios) < 1.15
    assert np.percentile(ratios, 10) > 0.75 and np.percentile(ratios, 90) < 1.35
    # stale rows: the filter drops roughly half
    tr = parse_trace(files[0], MsftIlcConfig())
    assert tr.n_wifi_stale > 0


# --- hostile timestamps and lines: bounded memory, the line named (run capped in a child process) ---

def _set_time(line: str, t_ms: int | str) -> str:
    return f"{t_ms}{line[line.index(chr(9)):]}"


def test_stray_imu_timestamp_is_dropped_naming_its_line(tmp_path):
    from capped import run_capped

    lines = fixture_lines()
    i = line_of(lines, "TYPE_ACCELEROMETER", 7)
    lines[i] = _set_time(lines[i], 1)   # 1 ms after 1970: a 50-year gap before the rest
    p = write(tmp_path, lines)
    r = run_capped("ingest", p, "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    assert f"{p}:{i + 1}: acc: 1 sample(s) at t = 0.001 s" in r.err and "dropped (bad timestamp)" in r.err
    assert r.peak_rss_mb < 1000


def test_clock_jump_is_an_error_naming_the_line(tmp_path):
    from capped import run_capped

    lines = fixture_lines()
    acc = [k for k, ln in enumerate(lines) if "\tTYPE_ACCELEROMETER\t" in ln]
    day30 = 30 * 86400 * 1000
    for k in acc[len(acc) // 2:]:   # the second half of the accelerometer jumps 30 days ahead
        lines[k] = _set_time(lines[k], int(lines[k].split("\t")[0]) + day30)
    p = write(tmp_path, lines)
    r = run_capped("ingest", p, "-w", tmp_path / "ws")
    assert r.code == 2, r.err
    assert r.err.startswith(f"error: {p}:{acc[len(acc) // 2] + 1}: walk 'trace': acc time jumps by 2.592e+06 s")
    assert r.err.count("\n") == 0 and r.peak_rss_mb < 1000


def test_overlong_line_and_huge_time_are_errors_naming_the_line(tmp_path):
    from capped import run_capped

    lines = fixture_lines()
    i = line_of(lines, "TYPE_WIFI", 2)
    parts = lines[i].split("\t")
    lines[i] = "\t".join(parts[:2] + ["x" * 2_000_000] + parts[3:])   # a 2 MB SSID
    p = write(tmp_path, lines)
    r = run_capped("ingest", p, "-w", tmp_path / "ws", timeout_s=60)
    assert r.code == 2 and r.err.startswith(f"error: {p}:{i + 1}: line of 2,000,"), r.err
    assert r.peak_rss_mb < 1000
    lines = fixture_lines()
    i = line_of(lines, "TYPE_GYROSCOPE", 3)
    lines[i] = _set_time(lines[i], "9" * 20)
    with pytest.raises(InputError, match="has 20 digits") as e:
        read([write(tmp_path, lines, "t20.txt")])
    assert e.value.where == f"{tmp_path / 't20.txt'}:{i + 1}"


def test_traces_of_two_sites_are_noted(tmp_path):
    text = FIXTURE.read_text()
    (tmp_path / "a.txt").write_text(text)
    (tmp_path / "b.txt").write_text(text.replace("SiteID:site0", "SiteID:site9"))
    raw = MsftIlcReader().read([tmp_path / "a.txt", tmp_path / "b.txt"], IngestConfig())
    note = [n for n in raw.notes if "sites" in n]
    assert len(note) == 1 and "site0: 1" in note[0] and "site9: 1" in note[0]
    raw = MsftIlcReader().read([tmp_path / "a.txt"], IngestConfig())
    assert not [n for n in raw.notes if "sites" in n]
