"""Raw phone IMU in rmbuild's own schema: simulate --raw-imu -> ingest runs the PDR -> optimize."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli

from rmbuild.io.workspace import Workspace


@pytest.fixture(scope="module")
def raw_imu_input(tmp_path_factory) -> Path:
    from rmbuild.cli import main

    out = tmp_path_factory.mktemp("rawimu") / "in"
    with pytest.raises(SystemExit) as e:
        main(["simulate", str(out), "--preset", "tiny", "--seed", "3", "--raw-imu", "-q"])
    assert e.value.code == 0
    return out


def test_pdr_recovers_steps_and_distance(raw_imu_input: Path, tmp_path: Path, capsys) -> None:
    assert not (raw_imu_input / "poses.csv").exists() and (raw_imu_input / "imu.csv").exists()
    drawn = pd.read_csv(raw_imu_input / "truth" / "walks.csv")
    assert set(drawn["carry_mode"]) <= {"texting", "calling", "swinging", "pocket"} and drawn["imu_hz"].min() >= 50
    r = run_cli(capsys, "ingest", raw_imu_input, "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    assert "phone PDR:" in r.err
    ws = Workspace.open(tmp_path / "ws")
    ds = ws.read_dataset()
    truth = pd.read_csv(raw_imu_input / "truth" / "poses.csv")
    for wid, g in ds.poses.groupby("walk_id"):
        tg = truth[truth["walk_id"] == wid]
        n_pdr, n_true = len(g) - 1, len(tg) - 1  # steps (row 0 is the start)
        assert abs(n_pdr - n_true) <= max(2, 0.03 * n_true), (wid, n_pdr, n_true)
        d_pdr = np.hypot(np.diff(g["x_m"]), np.diff(g["y_m"])).sum()
        d_true = np.hypot(np.diff(tg["x_m"]), np.diff(tg["y_m"])).sum()
        # one step-length constant, the simulated users' gaits differ: the optimizer refines a scale per walk
        assert 0.7 < d_pdr / d_true < 1.35, (wid, d_pdr, d_true)
    # the per-walk PDR report: in the walks table and in data/report.json
    w = ds.walks.set_index("walk_id")
    assert (w["pdr_steps"] == ds.poses.groupby("walk_id").size() - 1).all()
    assert (w["pdr_quality"] == "ok").all() and (w["pdr_heading"] == "gyro").all()
    assert w["pdr_cadence_hz"].between(1.2, 2.5).all() and (w["pdr_length_m"] > 10).all()
    rep = json.loads((tmp_path / "ws" / "data" / "report.json").read_text())
    assert set(rep["pdr"]) == set(w.index) and all(v["warnings"] == [] for v in rep["pdr"].values())
    # truth is interpolated at the PDR's step times
    assert ds.truth_poses is not None and np.isfinite(ds.truth_poses[["x_m", "y_m"]].to_numpy()).all()
    assert run_cli(capsys, "optimize", "-w", tmp_path / "ws", "-q").code == 0


def test_implausible_pdr_is_flagged(raw_imu_input: Path, tmp_path: Path, capsys) -> None:
    """A walk whose accelerometer shows no gait (a phone lying on a trolley, say) while its Wi-Fi changes
    as the others' do when they walk: no steps, quality "poor", and both reasons in the warnings."""
    import shutil

    folder = tmp_path / "in"
    shutil.copytree(raw_imu_input, folder)
    imu = pd.read_csv(folder / "imu.csv")
    wid = imu.groupby("walk_id").size().idxmax()
    rows = imu["walk_id"] == wid
    rng = np.random.default_rng(0)
    for c, g in (("acc_x_mps2", 0.0), ("acc_y_mps2", 0.0), ("acc_z_mps2", 9.81)):
        imu.loc[rows, c] = g + rng.normal(0, 0.03, int(rows.sum()))
    imu.to_csv(folder / "imu.csv", index=False)
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    walks = Workspace.open(tmp_path / "ws").read_dataset().walks.set_index("walk_id")
    assert walks.loc[wid, "pdr_quality"] == "poor" and walks.loc[wid, "pdr_steps"] == 0
    assert "no steps found" in walks.loc[wid, "pdr_warnings"]
    assert "RSSI changes nearly as much as while walking" in walks.loc[wid, "pdr_warnings"]
    assert f"walk {wid!r}: PDR poor" in r.err
    assert (walks.drop(index=wid)["pdr_quality"] == "ok").all()


def test_walk_with_poses_and_imu_is_an_error(raw_imu_input: Path, tmp_path: Path, capsys) -> None:
    import shutil

    folder = tmp_path / "in"
    shutil.copytree(raw_imu_input, folder)
    imu = pd.read_csv(folder / "imu.csv")
    w0 = imu[imu["walk_id"] == imu["walk_id"].iloc[0]]
    pd.DataFrame({"walk_id": w0["walk_id"].iloc[:3], "t_s": [0.0, 0.5, 1.0], "x_m": 0.0, "y_m": 0.0,
                  "heading_rad": 0.0}).to_csv(folder / "poses.csv", index=False)
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and "has both poses and raw IMU" in r.err and "imu.csv:2" in r.err, r.err
    (folder / "poses.csv").unlink()
    imu.loc[10, "t_s"] = imu.loc[9, "t_s"]
    imu.to_csv(folder / "imu.csv", index=False)
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    assert r.code == 2 and "imu.csv:12: imu: time not increasing" in r.err, r.err
