"""`rmbuild diff-map A B`: what changed between two workspaces' radio maps, AP by AP.

Each map's cells become reference points (:mod:`rmbuild.radiomap.ageing`); A is the reference and B the
later map. Per AP: heard in both, only in A (``gone``) or only in B (``appeared``), the centre of its
strongest cells in each, the shift between them and the median RSSI change at the cells both maps share
(``moved`` beyond ``move_m``), and for a gone AP the appeared ones that could be its replacement. Positions
can only be compared when both maps are in one frame (both in the building frame, or the same walk's);
otherwise only presence is compared and the report says so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.radiomap.ageing import MIN_READINGS, PointMap, classify_aps
from rmbuild.radiomap.build import RadioMap
from rmbuild.stages.common import locked_workspace


def cell_points(rm: RadioMap, bssids: np.ndarray) -> PointMap:
    """The map's cells as RPs over the AP columns ``bssids`` (APs the map lacks: never detected)."""
    col = pd.Index(bssids).get_indexer(rm.bssids.astype(str))
    n = rm.n_cells
    rss = np.full((n, len(bssids)), np.nan, np.float32)
    cnt = np.zeros((n, len(bssids)), np.float64)
    rss[:, col] = rm.mean_dbm
    cnt[:, col] = rm.count
    per_cell = np.maximum(cnt.max(axis=1), 1.0)
    return PointMap(rm.cell_xy, np.zeros(n, np.int64), rss, (cnt / per_cell[:, None]).astype(np.float32),
                    per_cell.astype(np.int64), np.zeros(n, np.int64), bssids)


def diff_maps(a: RadioMap, b: RadioMap, move_m: float = 5.0) -> tuple[pd.DataFrame, dict]:
    """(per-AP table, summary) of the changes from map ``a`` to map ``b``."""
    bssids = np.array(sorted(set(a.bssids.astype(str)) | set(b.bssids.astype(str))), dtype=object)
    same_frame = bool(a.frame) and a.frame == b.frame
    pa, pb = cell_points(a, bssids), cell_points(b, bssids)
    table = classify_aps({0: pa, 1: pb}, gone_after=1, move_m=move_m, min_months=1)
    table = table.drop(columns=["months_heard", "n_months", "first_month", "last_month", "floor_first",
                                "floor_late"])
    table["status"] = table["status"].replace({"transient": "appeared"})
    if not same_frame:
        for c in ("first_x_m", "first_y_m", "late_x_m", "late_y_m", "location_shift_m", "rss_shift_db"):
            table[c] = np.nan
        table["status"] = table["status"].replace({"moved": "both"})
        table["replaced_by"] = ""
    table["status"] = table["status"].replace({"stable": "both"})
    table = table.rename(columns={"first_x_m": "a_x_m", "first_y_m": "a_y_m", "late_x_m": "b_x_m",
                                  "late_y_m": "b_y_m"})
    counts = {k: int(v) for k, v in table["status"].value_counts().items()}
    summary = {"frame_a": a.frame, "frame_b": b.frame, "positions_compared": same_frame, "aps_a": len(a.bssids),
               "aps_b": len(b.bssids), "counts": counts, "move_m": move_m,
               "min_readings": MIN_READINGS}
    if not same_frame:
        summary["note"] = (f"the maps are in different frames ({a.frame or '?'} vs {b.frame or '?'}): only which APs "
                           "each heard is compared")
    return table, summary


def run(a: str | Path, b: str | Path, out: str | Path | None = None, move_m: float = 5.0,
        force: bool = False) -> tuple[pd.DataFrame, dict]:
    """Read both maps, compare them, write the per-AP table to ``out`` (CSV or Parquet) when given."""
    from rmbuild.io.map_store import read_radio_map
    from rmbuild.stages.localize import check_output, write_table

    path = check_output(out, force) if out is not None else None
    with locked_workspace(a, "diff-map", exclusive=False) as wa:
        ma = read_radio_map(wa)
    with locked_workspace(b, "diff-map", exclusive=False) as wb:
        mb = read_radio_map(wb)
    table, summary = diff_maps(ma, mb, move_m)
    if path is not None:
        write_table(table, path)
        summary["output"] = str(path)
    return table, summary
