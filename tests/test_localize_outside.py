"""`localize` of scans taken where the map has no walks: flagged outside the map, with a warning."""

from __future__ import annotations

import numpy as np
import pytest

from rmbuild.config import IngestConfig
from rmbuild.config.simulate import preset_config
from rmbuild.io.workspace import Workspace
from rmbuild.localize.apply import localize_query, match_distances, outside_threshold
from rmbuild.localize.base import Query
from rmbuild.radiomap import build_radio_map
from rmbuild.stages import ingest, simulate
from rmbuild.stages.localize import _outside_warning


@pytest.fixture(scope="module")
def venue(tmp_path_factory: pytest.TempPathFactory):
    """The default synthetic venue; a map of the west half from the true positions of all but one walk."""
    root = tmp_path_factory.mktemp("outside")
    simulate.run(root / "in", preset_config("default", 7))
    ingest.run([root / "in"], root / "ws", IngestConfig())
    ds = Workspace.open(root / "ws").read_dataset()
    xy = ds.truth_poses[["x_m", "y_m"]].to_numpy(float)
    walk = ds.poses["walk_id"].astype(str).to_numpy()
    split, held = float(np.median(xy[:, 0])), sorted(set(walk))[-1]
    in_map = (xy[:, 0] < split) & (walk != held)
    rm = build_radio_map(ds.wifi, np.where(in_map[:, None], xy, np.nan), walk)
    q = Query.from_dataset(ds, sorted(set(walk)), rm.bssids, unit="scan")
    x = xy[q.node, 0]
    east = x > split + 20                                               # 20 m and more past the map's edge
    west = (x < split - 5) & (q.walk_id.astype(str) == held)           # inside it, a walk the map never saw
    return rm, q, east, west


def test_scans_far_outside_the_map_match_it_worse_than_its_own(venue) -> None:
    rm, q, east, west = venue
    limit = outside_threshold(rm)
    d = match_distances(rm, q)
    assert limit is not None and east.sum() > 100 and west.sum() > 20
    assert (d[east] > limit).mean() > 0.6       # most scans far outside are flagged
    assert (d[west] > limit).mean() < 0.05      # scans inside, of a walk not in the map, almost never


def test_localize_flags_and_warns_about_scans_outside_the_map(venue) -> None:
    rm, q, east, _ = venue
    res = localize_query(rm, q, "knn")
    assert res.outside_map.dtype == bool and res.outside_map[east].mean() > 0.6
    warning = _outside_warning(res)
    assert warning is not None and f"{int(res.outside_map.sum())} of" in warning and "outside the area" in warning


def test_the_output_table_carries_the_flag(venue) -> None:
    """The output table carries outside_map; a map with too few nodes to tell flags nothing."""
    import pandas as pd

    from rmbuild.localize.apply import positions_table

    rm, q, _, _ = venue
    res = localize_query(rm, q, "knn")
    table = positions_table(q, res)
    assert table["outside_map"].tolist() == res.outside_map.tolist()
    small = build_radio_map(pd.DataFrame({"node": [0, 1], "bssid": ["a", "a"], "rssi_dbm": [-50.0, -60.0]}),
                            np.array([[0.0, 0.0], [5.0, 0.0]]), np.array(["w", "w"]))
    assert outside_threshold(small) is None
