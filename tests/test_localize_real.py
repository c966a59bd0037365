"""`rmbuild localize --hold-out` reproduces `rmbuild evaluate` on real phone walks (MS ILC 2.0 site1/F1), when
../shared/datasets exists. Eight of the floor's walks keep it to seconds; every 5th from the third is a test
walk, as evaluate's default split picks them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_util import run_cli
from conftest import SHARED_DATASETS

from rmbuild.io.workspace import Workspace

pytest.importorskip("gtsam")

F1 = SHARED_DATASETS / "msft-ilc20" / "data" / "site1" / "F1" / "path_data_files"
N_WALKS = 8


@pytest.mark.realdata
@pytest.mark.skipif(not F1.is_dir(), reason="../shared/datasets/msft-ilc20 not present")
def test_localize_hold_out_reproduces_evaluate_on_ilc_f1(tmp_path: Path, capsys) -> None:
    files = sorted(F1.glob("*.txt.gz"))[:N_WALKS]
    every, test = tmp_path / "all", tmp_path / "test"
    every.mkdir()
    test.mkdir()
    for i, f in enumerate(files):
        (every / f.name).symlink_to(f)
        if i % 5 == 2:
            (test / f.name).symlink_to(f)
    ws = tmp_path / "ws"
    for args in (("ingest", every, "-w", ws, "--format", "msft-ilc"), ("optimize", "-w", ws),
                 ("evaluate", "-w", ws, "--localizer", "knn")):
        r = run_cli(capsys, *args, "-q")
        assert r.code == 0, (args[0], r.err)
    out = tmp_path / "pos.parquet"
    r = run_cli(capsys, "localize", "-w", ws, test, "-o", out, "--localizer", "knn", "--hold-out")
    assert r.code == 0, r.err
    assert f"evaluate's built map of the other {N_WALKS - 2} walks" in r.out
    tracks = Workspace.open(ws).read_table("evaluate.tracks")
    ev = tracks[(tracks["map"] == "built") & (tracks["localizer"] == "knn")].reset_index(drop=True)
    got = pd.read_parquet(out)
    assert len(got) == len(ev) > 20 and (got["walk_id"].to_numpy() == ev["walk_id"].to_numpy()).all()
    np.testing.assert_allclose(got["t_s"], ev["t_s"])
    np.testing.assert_allclose(got["error_m"], ev["error_m"], atol=1e-6)
    assert got["error_m"].notna().sum() > 20
