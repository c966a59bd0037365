"""Phones' offsets in the radio map: readings and queries in the reference phone's scale."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli, split_input

from rmbuild.io.workspace import Workspace
from rmbuild.radiomap import devices
from rmbuild.types import Dataset


def _dataset() -> Dataset:
    walks = pd.DataFrame({"walk_id": ["a", "b", "c"], "device_id": ["P1", "P2", None]})
    wifi = pd.DataFrame({"walk_id": ["a", "b", "b", "c"], "node": [0, 1, 1, 2], "t_s": [0.0, 1.0, 1.0, 2.0],
                         "bssid": ["x", "x", "y", "x"], "rssi_dbm": [-60.0, -50.0, -70.0, -65.0]})
    poses = pd.DataFrame({"walk_id": ["a", "b", "c"], "step": [0, 0, 0], "t_s": [0.0, 1.0, 2.0],
                          "x_m": [0.0] * 3, "y_m": [0.0] * 3, "heading_rad": [0.0] * 3})
    return Dataset(walks=walks, poses=poses, wifi=wifi, fixes=None)


def test_corrected_takes_each_devices_offset_off_its_readings() -> None:
    ds = _dataset()
    out = devices.corrected(ds, {"P2": 4.5, "P1": 0.0, "gone": 3.0})
    np.testing.assert_allclose(out.wifi["rssi_dbm"], [-60.0, -54.5, -74.5, -65.0])
    assert ds.wifi["rssi_dbm"].tolist() == [-60.0, -50.0, -70.0, -65.0]  # the input is left alone
    assert devices.corrected(ds, {"P1": 0.0}) is ds and devices.corrected(ds, None) is ds
    assert devices.nonzero({"P1": 0.0, "P2": "x", "P3": float("nan"), "P4": -2}) == {"P4": -2.0}


@pytest.fixture(scope="module")
def two_phones(tmp_path_factory) -> Path:
    """The tiny venue whose test walk comes from a phone reading 8 dB high."""
    base = tmp_path_factory.mktemp("phones")
    cfg = base / "sim.toml"
    cfg.write_text("[simulate.devices]\nk_sd = 0.0\nb_sd_db = 0.0\ntest_device = [1.0, 8.0]\n")
    from rmbuild.cli import main

    def run(*args) -> None:
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0, args

    run("simulate", base / "in", "--preset", "tiny", "--seed", "5", "--config", cfg, "-q")
    run("ingest", base / "in", "-w", base / "ws", "-q")
    return base


def _surveyed_knn_median(capsys, ws: Path, *config) -> float:
    for stage in ("optimize", "export-map", "evaluate"):
        extra = list(config) if stage == "optimize" else []
        assert run_cli(capsys, stage, "-w", ws, "-q", "--force", *extra).code == 0, stage
    return float(json.loads((ws / "evaluate" / "report.json").read_text())["maps"]["surveyed"]["knn"]["median"])


def test_the_map_and_its_queries_are_in_the_reference_phones_scale(two_phones: Path, capsys, tmp_path) -> None:
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(two_phones / "ws", ws)
    corrected = _surveyed_knn_median(capsys, ws)
    side = json.loads((ws / "map" / "radiomap.json").read_text())
    assert side["device_offsets_db"] == pytest.approx({"dtest": 8.0}, abs=1.0)
    from rmbuild.io.map_store import read_radio_map

    assert read_radio_map(Workspace.open(ws)).device_offsets_db == side["device_offsets_db"]
    # localize corrects the test phone's scans as evaluate does: the same per-scan errors
    test_in = split_input(two_phones / "in", tmp_path / "test_in", {"w004"})
    out = tmp_path / "pos.parquet"
    assert run_cli(capsys, "localize", "-w", ws, test_in, "-o", out, "--localizer", "knn", "--hold-out").code == 0
    tracks = pd.read_parquet(ws / "evaluate" / "tracks.parquet").query("map == 'built' and localizer == 'knn'")
    np.testing.assert_allclose(pd.read_parquet(out)["error_m"], tracks["error_m"], atol=1e-9)
    # the same data with the offsets left in (optimize estimates none): the test phone's scans match worse
    nocal = tmp_path / "nocal.toml"
    nocal.write_text("[optimize.wifi]\ncalibrate_devices = false\n")
    as_heard = _surveyed_knn_median(capsys, ws, "--config", nocal)
    assert json.loads((ws / "map" / "radiomap.json").read_text())["device_offsets_db"] == {}
    assert corrected < 0.95 * as_heard
