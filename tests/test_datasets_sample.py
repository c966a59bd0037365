"""The real-data sample shipped in ``datasets/`` reads end to end (sniffing, reader, shared validation).

Runs from a clone alone. Figures are those of the files as published (datasets/*/README.md); tolerances
leave room for changes of the phone PDR's defaults, not for a reader that misreads the format.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rmbuild.config.ingest import IngestConfig
from rmbuild.evaluate.trajectory import interpolate_xy
from rmbuild.geometry import align_se2
from rmbuild.ingest.core import build_dataset
from rmbuild.io.formats import choose_reader, expand_inputs

DATASETS = Path(__file__).resolve().parents[1] / "datasets"
ILC_FLOOR = DATASETS / "msft-ilc20" / "site1" / "F1"
IPIN_LOGS = DATASETS / "ipin2023" / "logs"


def ingest(folder: Path):
    """(reader name, raw input, ingest summary) of a folder passed as a user would pass it."""
    files = expand_inputs([folder])
    reader = choose_reader(files, None)
    raw = reader.read(files, IngestConfig())
    _, _, summary = build_dataset(raw, IngestConfig(), source=reader.name)
    return reader.name, raw, summary


def pdr_vs_fixes(raw, walk_id: str) -> tuple[float, float]:
    """(mean error in m after fitting the walk's PDR rigidly to its fixes, PDR length / fix polyline length)."""
    fixes = raw.fixes[raw.fixes["walk_id"] == walk_id]
    poses = raw.poses[raw.poses["walk_id"] == walk_id]
    est = interpolate_xy(raw.poses, walk_id, fixes["t_s"].to_numpy(dtype=float))
    true = fixes[["x_m", "y_m"]].to_numpy(dtype=float)
    ok = np.isfinite(est).all(axis=1)
    r, t = align_se2(est[ok], true[ok])
    err = np.linalg.norm(est[ok] @ r.T + t - true[ok], axis=1)
    t_s = poses["t_s"].to_numpy()
    inside = (t_s >= fixes["t_s"].min()) & (t_s <= fixes["t_s"].max())
    pdr_len = np.linalg.norm(np.diff(poses[["x_m", "y_m"]].to_numpy()[inside], axis=0), axis=1).sum()
    fix_len = np.linalg.norm(np.diff(true, axis=0), axis=1).sum()
    return float(err.mean()), float(pdr_len / fix_len)


def test_ilc_sample_floor_reads_with_its_plan_files():
    name, raw, summary = ingest(ILC_FLOOR)
    assert name == "msft-ilc"
    assert summary["walks"] == 12 and set(raw.walks["device_id"]) == {"PBCM10"}
    # the floor's plan comes along, in the waypoints' frame (local metres)
    assert any(n.startswith("floor plan: F1") for n in raw.notes) and raw.floorplan["frame"] == "local_m"
    assert len(raw.fixes) == 86                                        # TYPE_WAYPOINT lines of the 12 traces
    assert summary["scans"] == pytest.approx(185, abs=10)
    assert summary["aps"] == pytest.approx(1024, rel=0.05)
    assert len(raw.poses) - 12 == pytest.approx(643, rel=0.1)          # detected steps
    # the waypoints lie on the floor plan shipped beside the traces (floor_info.json: metres)
    info = json.loads((ILC_FLOOR / "floor_info.json").read_text())["map_info"]
    xy = raw.fixes[["x_m", "y_m"]].to_numpy()
    assert (xy >= 0).all() and (xy[:, 0] <= info["width"]).all() and (xy[:, 1] <= info["height"]).all()
    # the floor's image spans the same width and height and comes along (drawn under the walks)
    from rmbuild.io.floor_image import decode

    assert raw.floorplan["image"]["extent_m"] == [0.0, 0.0, info["width"], info["height"]]
    assert decode(raw.floorplan["image"]["png"]).shape[:2] == (588, 800)  # as shipped
    # each walk's phone PDR has the shape of its waypoint path (published floor: ~1 m, length ratio ~1)
    fits = np.array([pdr_vs_fixes(raw, w) for w in raw.walks["walk_id"]])
    assert np.median(fits[:, 0]) < 1.5
    assert np.median(fits[:, 1]) == pytest.approx(1.0, abs=0.15)


def test_ipin_sample_logfiles_read():
    name, raw, summary = ingest(IPIN_LOGS)
    assert name == "ipin"
    assert sorted(raw.walks["device_id"]) == ["samsung SM-A520F", "samsung SM-G930F"]
    assert summary["scans"] > 100 and summary["aps"] == pytest.approx(43, abs=5)
    # one route walked with two phones: twelve POSI marks each, at the same surveyed points
    fixes = raw.fixes.sort_values(["walk_id", "t_s"])
    per_walk = [g[["x_m", "y_m"]].to_numpy() for _, g in fixes.groupby("walk_id")]
    assert [len(p) for p in per_walk] == [12, 12]
    assert np.abs(per_walk[0] - per_walk[1]).max() < 0.01
    assert per_walk[0][0] == pytest.approx([0.0, 0.0], abs=1e-6)     # ENU origin at the first mark
    extent = np.ptp(per_walk[0], axis=0)
    assert extent == pytest.approx([16.1, 10.6], abs=0.3)              # metres, from WGS84 marks
    for walk_id in raw.walks["walk_id"]:
        poses = raw.poses[raw.poses["walk_id"] == walk_id]
        rate = (len(poses) - 1) / np.ptp(poses["t_s"].to_numpy())
        assert 0.3 < rate < 1.2                                        # steps/s, pauses at the marks included


def test_console_lines_on_the_real_sample(tmp_path: Path, capsys) -> None:
    """What a user reads on real data (waypoints, no true paths, one walk unlinked): figures where they
    exist and no "n/a", the map's frame named plainly, the unlinked walk's warning naming the remedies."""
    from cli_util import run_cli

    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", ILC_FLOOR, "-w", ws, "-q").code == 0
    r = run_cli(capsys, "optimize", "-w", ws)
    assert r.code == 0, r.err
    assert "n/a" not in r.out and "gauge" not in r.out
    assert "map frame: that of walk" in r.out and "errors against the waypoints" in r.out
    assert "landmark error mean" in r.out and "no true paths: no ATE" in r.out  # says why there is no ATE
    unlinked = [ln for ln in r.err.splitlines() if "not linked to the reference walk" in ln]
    assert len(unlinked) <= 1
    for ln in unlinked:
        assert "--anchors" in ln and "--floorplan" in ln and "more walks" in ln
    from rmbuild.cli.export_map import _frame

    assert _frame("walk:w7") == "in the frame of walk w7 (not tied to the building)"  # export-map's line
    assert _frame("building") == "in the building frame"
