"""`rmbuild ingest --append`: new walks after the old ones, as if ingested together; ids must be new."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli, split_input

from rmbuild.io.workspace import Workspace


@pytest.fixture(scope="module")
def parts(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("append")
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate

    simulate.run(base / "all", preset_config("tiny", 5))
    ids = pd.read_csv(base / "all" / "walks.csv", dtype={"walk_id": str})["walk_id"].tolist()
    k = int(len(ids) * 0.8)
    return {"all": base / "all", "old": split_input(base / "all", base / "old", set(ids[:k])),
            "new": split_input(base / "all", base / "new", set(ids[k:])), "base": base}


def test_append_equals_ingesting_all_at_once(parts: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    base = parts["base"]
    assert run_cli(capsys, "ingest", parts["all"], "-w", base / "ws_all", "-q").code == 0
    assert run_cli(capsys, "ingest", parts["old"], "-w", base / "ws", "-q").code == 0
    assert run_cli(capsys, "optimize", "-w", base / "ws", "-q").code == 0
    r = run_cli(capsys, "ingest", "--append", parts["new"], "-w", base / "ws")
    assert r.code == 0, r.err
    assert "appended" in r.out
    a, b = Workspace.open(base / "ws").read_dataset(), Workspace.open(base / "ws_all").read_dataset()
    for name in ("walks", "poses", "wifi", "fixes", "truth_poses"):
        x, y = getattr(a, name), getattr(b, name)
        cols = [c for c in y.columns if not c.startswith("pdr_")]
        pd.testing.assert_frame_equal(x[cols], y[cols], check_dtype=False, obj=name)
    fa, fb = Workspace.open(base / "ws").read_fingerprints(), Workspace.open(base / "ws_all").read_fingerprints()
    assert np.array_equal(fa.node, fb.node) and list(fa.bssids) == list(fb.bssids)
    assert np.array_equal(fa.rss_dbm, fb.rss_dbm, equal_nan=True)
    # the optimize run before the append is stale now: view leaves it out and says why, export-map refuses
    # it until optimize runs again
    r = run_cli(capsys, "view", "-w", base / "ws", "--save", base / "v.rrd")
    assert r.code == 0, r.err
    assert "stale" in r.err and "optimize" in r.err
    r = run_cli(capsys, "export-map", "-w", base / "ws", "-q")
    assert r.code == 2 and "optimize" in r.err
    assert run_cli(capsys, "optimize", "-w", base / "ws", "-q", "--force").code == 0
    assert run_cli(capsys, "export-map", "-w", base / "ws", "-q").code == 0


def test_append_keeps_the_floor_plan(parts: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The workspace's floor plan stays through an append (it once vanished, and optimize then lost the
    building frame), checked again against all the fixes."""
    import json

    from rmbuild.synthetic.venue import plan_geojson

    venue = json.loads((parts["all"] / "truth" / "venue.json").read_text())
    (tmp_path / "plan.geojson").write_text(json.dumps({**plan_geojson(venue), "frame": "local_m"}))
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", parts["old"], "-w", ws, "-q", "--floorplan", tmp_path / "plan.geojson").code == 0
    before = (ws / "data" / "floorplan.local.json").read_text()
    r = run_cli(capsys, "ingest", "--append", parts["new"], "-w", ws, "-q")
    assert r.code == 0, r.err
    assert (ws / "data" / "floorplan.local.json").read_text() == before
    report = Workspace.open(ws).read_report("ingest")
    assert report["floorplan"]["frame_check"]["fixes"] == len(Workspace.open(ws).read_dataset().fixes)


def test_append_refuses_known_walks_and_leaves_the_workspace(parts: dict[str, Path], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture) -> None:
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", parts["old"], "-w", ws, "-q").code == 0
    before = (ws / "data" / "stage.json").read_bytes()
    r = run_cli(capsys, "ingest", "--append", parts["old"], "-w", ws)
    assert r.code == 2 and "already in the workspace" in r.err and len(r.err.strip().splitlines()) == 1
    assert (ws / "data" / "stage.json").read_bytes() == before
    r = run_cli(capsys, "ingest", "--append", parts["new"], "-w", ws, "--force")
    assert r.code == 2 and "--force" in r.err
    r = run_cli(capsys, "ingest", "--append", parts["new"], "-w", tmp_path / "nothing")
    assert r.code == 2 and "Traceback" not in r.err


def test_appended_ipin_fixes_share_the_first_ingest_frame(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """IPIN fixes are WGS84, put into a local frame at the first fix ingest reads; an appended logfile's fixes
    must land in the workspace's frame, not one of their own (they were 57 m off on IPIN −2)."""
    import gzip

    logs = sorted((Path(__file__).resolve().parents[1] / "datasets" / "ipin2023" / "logs").glob("*.txt.gz"))
    assert len(logs) == 2
    # the second logfile without its first 5 fixes: its own first fix is then 9 m from the first one's
    lines = gzip.decompress(logs[1].read_bytes()).decode().splitlines(keepends=True)
    posi = [i for i, line in enumerate(lines) if line.startswith("POSI;")]
    second = tmp_path / "in" / logs[1].name
    second.parent.mkdir()
    second.write_bytes(gzip.compress("".join(x for i, x in enumerate(lines) if i not in posi[:5]).encode()))
    assert run_cli(capsys, "ingest", logs[0], second, "-w", tmp_path / "all", "-q").code == 0
    assert run_cli(capsys, "ingest", logs[0], "-w", tmp_path / "ws", "-q").code == 0
    assert "\norigin_lat_deg = " in (tmp_path / "ws" / "data" / "config.toml").read_text()
    assert run_cli(capsys, "ingest", "--append", second, "-w", tmp_path / "ws", "-q").code == 0
    a, b = Workspace.open(tmp_path / "ws").read_dataset().fixes, Workspace.open(tmp_path / "all").read_dataset().fixes
    assert len(a) == len(b) > 0
    assert np.abs(a[["x_m", "y_m"]].to_numpy() - b[["x_m", "y_m"]].to_numpy()).max() < 1e-6


def test_appending_ipin_to_a_workspace_without_its_origin_warns(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A workspace ingested before ingest recorded the fixes' origin: appending IPIN logfiles says that their
    fixes get a frame of their own (instead of silently mixing frames)."""
    from rmbuild.stages import ingest

    logs = sorted((Path(__file__).resolve().parents[1] / "datasets" / "ipin2023" / "logs").glob("*.txt.gz"))
    with monkeypatch.context() as m:
        m.setattr(ingest, "pinned_origin", lambda cfg, raw: cfg)  # as ingest wrote workspaces before
        assert run_cli(capsys, "ingest", logs[0], "-w", tmp_path / "old", "-q").code == 0
    r = run_cli(capsys, "ingest", "--append", logs[1], "-w", tmp_path / "old")
    assert r.code == 0 and "does not record the WGS84 origin" in r.err
    assert run_cli(capsys, "ingest", logs[0], "-w", tmp_path / "new", "-q").code == 0
    r = run_cli(capsys, "ingest", "--append", logs[1], "-w", tmp_path / "new")
    assert r.code == 0 and "WGS84 origin" not in r.err
