"""IPIN / GetSensorData logfile reader: fixtures (phone IMU and IMUI foot IMU), malformed input, sniffing."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from rmbuild.config.ingest import IngestConfig, IpinConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.errors import InputError
from rmbuild.ingest.core import derive_poses
from rmbuild.io.formats.ipin import IpinReader, wgs84_to_enu
from rmbuild.io.formats.msft_ilc import MsftIlcReader

HERE = Path(__file__).resolve().parent / "fixtures" / "ipin"
PHONE = HERE / "tiny_logfile.txt"
FOOT = HERE / "tiny_logfile_imui.txt"


def read(files, options: PdrConfig | None = None, ipin: IpinConfig | None = None):
    """The reader's raw input, with the PDR run on its raw IMU as ingest does."""
    raw = IpinReader().read([Path(f) for f in files], IngestConfig(ipin=ipin or IpinConfig()))
    derive_poses(raw, options or PdrConfig())
    return raw


def write(tmp_path: Path, lines: list[str], name: str = "log.txt") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def first(lines: list[str], tag: str, k: int = 0) -> int:
    return [i for i, ln in enumerate(lines) if ln.startswith(tag + ";")][k]


def test_reader_only_reads():
    raw = IpinReader().read([PHONE], IngestConfig())
    assert len(raw.poses) == 0 and list(raw.imu) == ["tiny_logfile"]
    imu = raw.imu["tiny_logfile"]
    assert len(imu.signals.t_acc_s) == len(imu.lines["acc"]) > 100 and imu.signals.quat_xyzw.shape[1] == 4
    lines = PHONE.read_text(encoding="utf-8").splitlines()
    assert lines[int(imu.lines["acc"][0]) - 1].startswith("ACCE;") and imu.where("gyro", 0).startswith(f"{PHONE}:")


def test_phone_logfile_reads():
    raw = read([PHONE])
    assert raw.walks.to_dict("records") == [{"walk_id": "tiny_logfile", "device_id": "ACME PHONE2",
                                             "user_id": "", "role": "", "source": "ipin"}]
    p = raw.poses
    assert len(p) == 21
    assert p["heading_rad"].iat[-1] == pytest.approx(np.pi / 2, abs=0.05)
    assert p["yaw_abs_rad"].iat[5] == pytest.approx(0.0, abs=0.05)
    # WIFI: the SSID may contain ';'
    assert len(raw.wifi) == 16 and "Cafe;Guest" in set(raw.wifi["ssid"])
    assert raw.wifi["bssid"].iat[0] == "20:23:00:00:00:00" and raw.wifi["freq_mhz"].iat[0] == 2412
    # POSI -> local ENU at the first fix: 5 m east, then 5 m north (fixture uses a spherical approximation)
    np.testing.assert_allclose(raw.fixes[["x_m", "y_m"]].to_numpy(), [[0, 0], [5, 0], [5, 5]], atol=0.05)
    assert list(raw.fixes["floor"]) == ["0"] * 3 and list(raw.fixes["label"]) == ["posi1", "posi2", "posi3"]
    assert raw.skipped == {"MAGN": 300}
    t, hpa = raw.pressure["tiny_logfile"]  # PRES: the barometer, for floor changes (rmbuild/pdr/baro.py)
    assert len(t) == len(hpa) == 24 and 800 < hpa.min() <= hpa.max() < 1100


def test_foot_imu_logfile_uses_imui():
    raw = read([FOOT])
    p = raw.poses
    assert len(p) == 11   # start + 10 distinct packets (one repeated packet skipped)
    assert raw.skipped["IMUI (repeated packet)"] == 1
    # 6 steps east, then a left turn, 4 steps north
    assert p["x_m"].iat[-1] == pytest.approx(4.2) and p["y_m"].iat[-1] == pytest.approx(2.8)
    assert p["heading_rad"].iat[-1] == pytest.approx(np.pi / 2)
    assert p["yaw_abs_rad"].isna().all()
    cov = read([FOOT], ipin=IpinConfig(imui_covariance=True)).poses
    assert cov["odo_sigma_x_m"].iat[1] == pytest.approx(0.01) and cov["odo_sigma_theta_rad"].iat[1] == 0.01
    enu = read([FOOT], ipin=IpinConfig(imui_z_down=False)).poses
    assert enu["y_m"].iat[-1] == pytest.approx(-2.8)


def test_origin_option_and_enu():
    raw = read([PHONE, FOOT], ipin=IpinConfig(origin_lat_deg=49.461316433032,
                                              origin_lon_deg=11.110964442580 - 0.001))
    assert raw.fixes["x_m"].iat[0] == pytest.approx(72.6, abs=0.5)   # 0.001° of longitude at 49.46° N
    e, n = wgs84_to_enu(np.array([0.0, 0.001]), np.array([0.001, 0.0]), 0.0, 0.0)
    np.testing.assert_allclose(e, [111.32, 0.0], atol=0.01)
    np.testing.assert_allclose(n, [0.0, 110.57], atol=0.01)


@pytest.mark.parametrize("tag, k, edit, message", [
    ("ACCE", 3, lambda s: s.rsplit(";", 2)[0], "ACCE: expected 7 ';'-separated fields, got 5"),
    ("ACCE", 4, lambda s: s + ";1;2", "ACCE: expected 7"),
    ("GYRO", 2, lambda s: s.replace(";3", ";x", 1) if s.endswith(";3") else s + "x", "GYRO: non-numeric"),
    ("POSI", 1, lambda s: ";".join(s.split(";")[:3] + ["91.5"] + s.split(";")[4:]), "latitude 91.5 outside"),
    ("POSI", 2, lambda s: ";".join(s.split(";")[:4] + ["-181"] + s.split(";")[5:]),
     "longitude -181.0 outside"),
    ("WIFI", 0, lambda s: "WIFI;1.5;65001.5;SSID", "WIFI: expected 7"),
    ("WIFI", 1, lambda s: s.replace("20:23:00:00:00", "zz:23:00:00:00"), "not a MAC address"),
    ("AHRS", 0, lambda s: s[:20], "AHRS: expected 10"),
    ("ACCE", 9, lambda s: "ACC3 1.0 2.0", "not a GetSensorData line"),
])
def test_malformed_lines_name_file_and_line(tmp_path, tag, k, edit, message):
    lines = PHONE.read_text(encoding="utf-8").splitlines()
    i = first(lines, tag, k)
    lines[i] = edit(lines[i])
    p = write(tmp_path, lines)
    with pytest.raises(InputError) as e:
        read([p])
    assert message in str(e.value)
    assert e.value.where == f"{p}:{i + 1}"


def test_malformed_imui(tmp_path):
    lines = FOOT.read_text(encoding="utf-8").splitlines()
    i = first(lines, "IMUI", 2)
    lines[i] = ";".join(lines[i].split(";")[:10])
    p = write(tmp_path, lines)
    with pytest.raises(InputError, match="IMUI: expected 18") as e:
        read([p])
    assert e.value.where == f"{p}:{i + 1}"


def test_file_without_wifi_or_imu(tmp_path):
    lines = PHONE.read_text(encoding="utf-8").splitlines()
    p = write(tmp_path, [ln for ln in lines if not ln.startswith("WIFI;")], "nowifi.txt")
    raw = read([p])  # kept as a walk without radio evidence; the note names the file
    assert len(raw.wifi) == 0 and len(raw.poses) > 0 and f"{p}: no WIFI lines" in raw.notes
    p = write(tmp_path, [ln for ln in lines if not ln.startswith(("ACCE;", "GYRO;", "AHRS;"))], "noimu.txt")
    with pytest.raises(InputError, match="no ACCE"):
        read([p])
    p = write(tmp_path, [ln for ln in lines if not ln.startswith("AHRS;")], "noahrs.txt")
    with pytest.raises(InputError, match="no rotation-vector / AHRS samples") as e:
        read([p], PdrConfig(heading_source="rotation_vector"))
    assert e.value.where == str(p)
    assert read([p]).walks["walk_id"].tolist() == ["noahrs"]   # "auto": the gyroscope
    p = write(tmp_path, [ln for ln in lines if ln.startswith("%")], "header.txt")
    with pytest.raises(InputError, match="no data lines"):
        read([p])


def test_gzip_and_bad_gzip(tmp_path):
    gz = tmp_path / "tiny_logfile.txt.gz"
    gz.write_bytes(gzip.compress(PHONE.read_bytes()))
    assert IpinReader.sniff([gz])
    assert len(read([gz]).poses) == 21
    bad = tmp_path / "bad.txt.gz"
    bad.write_bytes(b"\x1f\x8bnot really")
    with pytest.raises(InputError) as e:
        read([bad])
    assert e.value.where == str(bad)


def test_sniff_and_mixed_formats(tmp_path):
    assert IpinReader.sniff([PHONE, FOOT])
    ilc = Path(__file__).resolve().parent / "fixtures" / "msft_ilc" / "tiny_trace.txt"
    assert not IpinReader.sniff([PHONE, ilc]) and not MsftIlcReader.sniff([PHONE])
    with pytest.raises(InputError, match="mixed formats") as e:
        read([PHONE, ilc])
    assert e.value.where == f"{ilc}:1"
    schema = tmp_path / "poses.csv"
    schema.write_text("walk_id,t_s,x_m,y_m,heading_rad\n")
    assert not IpinReader.sniff([schema])
    with pytest.raises(InputError, match="mixed formats"):
        read([PHONE, schema])


def test_bssid_twice_in_one_scan_is_merged_through_ingest(tmp_path, capsys):
    from cli_util import run_cli

    lines = (HERE / "tiny_logfile.txt").read_text().splitlines(keepends=True)
    i = next(k for k, ln in enumerate(lines) if ln.startswith("WIFI;"))
    lines.insert(i + 1, lines[i])  # the same BSSID again in the same scan
    (tmp_path / "log.txt").write_text("".join(lines))
    r = run_cli(capsys, "ingest", tmp_path / "log.txt", "-w", tmp_path / "ws", "--format", "ipin")
    assert r.code == 0, r.err
    assert "merged 1 Wi-Fi readings repeating a BSSID" in r.err


def test_stray_acce_time_is_dropped_naming_its_line(tmp_path):
    from capped import run_capped

    lines = PHONE.read_text(encoding="utf-8").splitlines()
    i = first(lines, "ACCE", 11)
    parts = lines[i].split(";")
    lines[i] = ";".join(parts[:1] + ["1e9"] + parts[2:])   # 31 years after the others
    p = write(tmp_path, lines)
    r = run_capped("ingest", p, "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    assert f"{p}:{i + 1}: acc: 1 sample(s) at t = 1e+09 s" in r.err and r.peak_rss_mb < 1000
    lines.insert(i + 1, "WIFI;" + "x" * 10_000)
    with pytest.raises(InputError, match="line of 10,005 characters") as e:
        read([write(tmp_path, lines, "long.txt")])
    assert e.value.where == f"{tmp_path / 'long.txt'}:{i + 2}"
