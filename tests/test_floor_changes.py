"""Simulated walks that change floor (stairs, lift) with a barometer, and our schema's pressure column."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from rmbuild.config import IngestConfig
from rmbuild.config.simulate import preset_config
from rmbuild.errors import InputError
from rmbuild.io.formats.rmbuild_schema import RmbuildSchemaReader
from rmbuild.pdr.baro import floor_changes
from rmbuild.synthetic.building import simulate_building


@pytest.fixture(scope="module")
def building():
    cfg = preset_config("tiny", 3)
    return simulate_building(dataclasses.replace(cfg, building=dataclasses.replace(cfg.building, floors=3)))


def test_walks_change_floor_by_stairs_and_lift_and_the_barometer_finds_each(building) -> None:
    ch = building.truth_floor_changes
    assert set(ch["kind"]) == {"stairs", "lift"} and len(ch) >= 4
    poses = building.poses
    for w, g in poses.groupby("walk_id"):
        t = g["t_s"].to_numpy(float)
        found = floor_changes(t, g["pressure_hpa"].to_numpy(float))
        true = ch[ch["walk_id"] == w]
        assert len(found) == len(true), w
        if len(true):
            row = true.iloc[0]
            assert abs(int(np.searchsorted(t, found[0].t_mid_s)) - int(row["step"])) <= 2, w
            assert g["floor"].iloc[int(row["step"])] == row["to_floor"]
            assert g["floor"].iloc[int(row["step"]) - 1] == row["from_floor"]
            assert found[0].dh_m == pytest.approx(3.5 * np.sign(found[0].dh_m), abs=0.6)


def test_a_glued_walk_is_continuous(building) -> None:
    """Its dead-reckoned steps stay steps (no jump at the climb) and its times increase."""
    for w in building.truth_floor_changes["walk_id"]:
        g = building.poses[building.poses["walk_id"] == w]
        assert (np.diff(g["t_s"].to_numpy(float)) > 0).all()
        assert np.hypot(np.diff(g["x_m"]), np.diff(g["y_m"])).max() < 3.0
        wifi = building.wifi[building.wifi["walk_id"] == w]
        assert len(wifi) and wifi["t_s"].max() <= g["t_s"].max() + 5.0


def _write(tmp_path, pressure) -> list:
    tmp_path.mkdir(exist_ok=True)
    pd.DataFrame({"walk_id": "w", "t_s": [0.0, 0.5, 1.0], "x_m": [0.0, 0.7, 1.4], "y_m": 0.0, "heading_rad": 0.0,
                  "pressure_hpa": pressure}).to_csv(tmp_path / "poses.csv", index=False)
    pd.DataFrame({"walk_id": "w", "t_s": [0.5], "bssid": ["a"], "rssi_dbm": [-50.0]}).to_csv(tmp_path / "wifi.csv",
                                                                                            index=False)
    return [tmp_path / "poses.csv", tmp_path / "wifi.csv"]


def test_our_schema_reads_pressure_and_rejects_other_units(tmp_path) -> None:
    raw = RmbuildSchemaReader().read(_write(tmp_path / "a", [1000.1, np.nan, 1000.3]), IngestConfig())
    t, p = raw.pressure["w"]
    assert list(t) == [0.0, 1.0] and list(p) == [1000.1, 1000.3] and "pressure_hpa" not in raw.poses
    with pytest.raises(InputError, match=r"poses.csv:3: pressure_hpa 100011 outside"):
        RmbuildSchemaReader().read(_write(tmp_path / "b", [1000.0, 100011.0, 100012.0]), IngestConfig())
