"""The report's per-walk table: how optimize placed each walk, what it predicts, and — where ground truth or
waypoints exist — how far off the walk really is (numpy / pandas only)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from rmbuild.types import BUILDING_FRAME_GAUGES
from rmbuild.viz.align import apply, poses_at_fixes

HEADER = ("walk", "linked", "placed by", "shared path (m)", "predicted error (m)")
#: optimize's placement methods (optimize/walks.parquet: placement) in words
PLACED_BY = {
    "translation": "Wi-Fi fit (shift; rotation from the compass)",
    "se2": "Wi-Fi fit (shift and rotation)",
    "pair": "Wi-Fi pairs with one walk",
    "continuity": "continuity with the recording before/after",
    "merge": "merged component",
    "floorplan": "floor plan",
}


def _placed_by(row: pd.Series) -> str:
    if bool(row.get("reference", False)):
        return "reference walk"
    if not bool(row.get("linked", True)):
        if bool(row.get("anchored", False)):
            return "anchors"
        return "not placed (RF check refuted its fit)" if row.get("placement") == "refuted" else "not placed"
    how = str(row.get("placement") or "")
    return PLACED_BY.get(how, how or "linked")


def _num(v: Any, digits: int = 1) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "—"
    return f"{f:.{digits}f}" if np.isfinite(f) else "—"


def real_errors(opt: pd.DataFrame, ds: Any, rt: Any, gauge: str | None) -> tuple[str, dict[str, float]] | None:
    """(column title, walk -> mean error in m) of the optimised walks in the building frame: against the
    true path at every pose, or else at the walk's waypoints / fixes; None when the map's place in the
    building is unknown (no fit, no building-frame gauge) or there is nothing to compare with."""
    if rt is None and gauge not in BUILDING_FRAME_GAUGES:
        return None
    truth = ds.truth_poses
    walk = opt["walk_id"].astype(str).to_numpy()
    if truth is not None and len(truth) == len(opt):
        xy = apply(rt, opt[["x_m", "y_m"]].to_numpy(dtype=float))
        d = np.hypot(*(xy - truth[["x_m", "y_m"]].to_numpy(dtype=float)).T)
        s = pd.Series(d).groupby(walk, sort=False).mean()
        return "error vs truth (m)", {str(k): float(v) for k, v in s.items()}
    fx = ds.fixes
    if fx is None or len(fx) == 0:
        return None
    est = apply(rt, poses_at_fixes(opt, fx))
    d = np.hypot(*(est - fx[["x_m", "y_m"]].to_numpy(dtype=float)).T)
    s = pd.Series(d).groupby(fx["walk_id"].astype(str).to_numpy(), sort=False).mean()
    return "error at waypoints (m)", {str(k): float(v) for k, v in s.items() if np.isfinite(v)}


def walk_rows(walks: pd.DataFrame, errors: tuple[str, dict[str, float]] | None
              ) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """(header, rows) of the table from ``optimize/walks.parquet``: the linked walks first, the largest
    predicted error first (the walks to doubt on top), then the walks left out, each group in walk order;
    the real error column only with ``errors`` (an unlinked walk's real error is left out: its frame is
    arbitrary); the walk's ``reason`` last when the table has one."""
    why = "reason" in walks  # optimize's sentence on the evidence (workspaces from before it have none)
    header = HEADER + ((errors[0],) if errors else ()) + (("why",) if why else ())
    rows: list[tuple[str, ...]] = []
    for _, r in _doubtful_first(walks).iterrows():
        wid = str(r["walk_id"])
        linked = bool(r.get("linked", True))
        row: tuple[str, ...] = (wid, "yes" if linked else "no", _placed_by(r), _num(r.get("shared_path_m"), 0),
               _num(r.get("predicted_error_m")))
        if errors:
            row += (_num(errors[1].get(wid)) if linked or bool(r.get("anchored", False)) else "—",)
        if why:
            row += (str(r["reason"]),)
        rows.append(row)
    return header, rows


def _doubtful_first(walks: pd.DataFrame) -> pd.DataFrame:
    """The linked walks by predicted error, largest first (a walk without one last among them), then the
    others; ties and each group keep the walks' order."""
    linked = walks["linked"].astype(bool) if "linked" in walks else pd.Series(True, index=walks.index)
    pred = walks["predicted_error_m"].astype(float) if "predicted_error_m" in walks else np.nan
    key = pd.DataFrame({"left_out": ~linked, "pred": pred}, index=walks.index)
    order = key.sort_values(["left_out", "pred"], ascending=[True, False], na_position="last", kind="stable")
    return walks.loc[order.index]
