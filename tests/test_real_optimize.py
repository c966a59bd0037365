"""rmbuild optimize on real crowdsourced phone walks (MS ILC 2.0 site1/F1), when ../shared/datasets exists.

Wi-Fi and phone yaw only; the waypoints are used for scoring, never by the pipeline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gtsam")

from rmbuild.config.ingest import IngestConfig  # noqa: E402
from rmbuild.config.optimize import OptimizeConfig  # noqa: E402
from rmbuild.evaluate.trajectory import align_se2, interpolate_xy  # noqa: E402
from rmbuild.ingest_core import build_dataset  # noqa: E402
from rmbuild.io.formats.msft_ilc import MsftIlcReader  # noqa: E402
from rmbuild.slam import optimize  # noqa: E402

F1 = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "msft-ilc20" / "data" / "site1" / "F1"


def _waypoint_errors(poses, fixes, walk_ids) -> np.ndarray:
    est, tru = [], []
    for wid, g in fixes[fixes["walk_id"].astype(str).isin(walk_ids)].groupby("walk_id"):
        est.append(interpolate_xy(poses, str(wid), g["t_s"].to_numpy(float)))
        tru.append(g[["x_m", "y_m"]].to_numpy(float))
    est, tru = np.vstack(est), np.vstack(tru)
    ok = np.isfinite(est).all(axis=1)
    R, t = align_se2(est[ok], tru[ok])
    return np.linalg.norm(est[ok] @ R.T + t - tru[ok], axis=1)


@pytest.mark.realdata
@pytest.mark.skipif(not F1.is_dir(), reason="../shared/datasets/msft-ilc20 not present")
def test_real_f1_walks_linked_and_placed():
    files = sorted((F1 / "path_data_files").glob("*.txt.gz"))
    raw = MsftIlcReader().read(files, IngestConfig())
    ds, fp, _ = build_dataset(raw, IngestConfig())
    r = optimize(ds, fp, OptimizeConfig())
    linked = set(r.walks.loc[r.walks["linked"], "walk_id"].astype(str))
    # measured: 83 of 106 linked (60 before component merging), 23 % of them by a merge
    assert len(linked) >= 75, len(linked)
    assert (r.walks["placement"] == "merge").sum() >= 10
    opt = _waypoint_errors(r.poses, ds.fixes, linked)
    raw_err = _waypoint_errors(ds.poses, ds.fixes, linked)
    # measured: linked walks' waypoint error median 6.5 m, mean 7.5 m; raw PDR (one SE(2) fit) ~55 m
    assert np.median(opt) < 9.0 and opt.mean() < 10.0, (np.median(opt), opt.mean())
    assert np.median(raw_err) > 4 * np.median(opt)
