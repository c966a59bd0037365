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
