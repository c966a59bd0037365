"""An MS ILC 2.0 floor's plan and surveyed waypoints from the shared data (real-data tests; skips without it)."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest

from rmbuild.floorplan import FloorPlan, from_ilc
from tests.conftest import SHARED_DATASETS


def ilc_plan_and_waypoints(floor: str, n_files: int) -> tuple[FloorPlan, np.ndarray, dict]:
    """(the plan of ``floor`` (e.g. "site1/F1"), the TYPE_WAYPOINT x, y of its first ``n_files`` traces,
    floor_info's map_info); the test is skipped when the data is not present."""
    root = SHARED_DATASETS / "msft-ilc20" / "data" / floor
    if not root.is_dir():
        pytest.skip("the MS ILC 2.0 data is not present")
    info = json.loads((root / "floor_info.json").read_text())["map_info"]
    plan = from_ilc(json.loads((root / "geojson_map.json").read_text()), info["width"], info["height"], floor)
    pts = []
    for f in sorted((root / "path_data_files").glob("*.txt.gz"))[:n_files]:
        for line in gzip.open(f, "rt"):
            p = line.split("\t")
            if len(p) >= 4 and p[1] == "TYPE_WAYPOINT":
                pts.append((float(p[2]), float(p[3])))
    return plan, np.array(pts), info
