"""export-map's files for evo: the whole map scored at once.

``map/evo/map.txt`` holds every pose of the walks the map is built from, in the map's frame, one TUM file
on one clock (:func:`rmbuild.io.tum.shared_clock`; ``map/evo/clock.csv`` gives each walk's offset). Beside
it, the same poses' truth on the same clock: ``truth.txt`` when the input has true paths (simulated), and
``waypoints.txt`` (each waypoint / position fix of those walks at its time) with ``map_at_waypoints.txt``
(the map's poses interpolated at the same times) when it has waypoints (real floors). Then

    evo_ape tum map/evo/truth.txt map/evo/map.txt -a                  # true paths
    evo_ape tum map/evo/waypoints.txt map/evo/map_at_waypoints.txt -a  # waypoints

scores the placement of every walk with one rigid alignment of the whole map (``-a``; leave it out when
the map is in the building's frame), unlike a per-walk file aligned to itself, which hides where each
walk sits.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.evaluate.trajectory import estimates_at_fixes
from rmbuild.io.tum import shared_clock, tum_text
from rmbuild.types import Dataset

#: the evo files, by the workspace key they are written under
EVO_KEYS = ("map.evo_map", "map.evo_truth", "map.evo_waypoints", "map.evo_map_at_waypoints")


def evo_texts(ds: Dataset, xy: np.ndarray, heading_rad: np.ndarray) -> tuple[dict[str, str], pd.DataFrame]:
    """(workspace key -> TUM text, the clock table walk_id / offset_s) of the map's walks: the nodes with a
    position in ``xy`` (n_nodes, 2; NaN: left out of the map) and their headings (n_nodes,) in the map's
    frame. Empty when no node has a position."""
    walk = ds.poses["walk_id"].astype(str).to_numpy()
    t = ds.poses["t_s"].to_numpy(dtype=float)
    used = np.isfinite(xy).all(axis=1)
    order = [w for w in map(str, ds.walk_ids()) if w in set(walk[used])]
    offsets = shared_clock(t[used], walk[used], order)
    clock = pd.DataFrame({"walk_id": list(offsets), "offset_s": list(offsets.values())})
    if not used.any():
        return {}, clock
    ts = t + pd.Series(walk).map(offsets).to_numpy(dtype=float)
    rows = np.flatnonzero(used)[np.argsort(ts[used], kind="stable")]
    out = {"map.evo_map": tum_text(ts[rows], xy[rows, 0], xy[rows, 1], heading_rad[rows])}
    truth = ds.truth_poses
    if truth is not None and len(truth) == len(ds.poses):
        th = truth["heading_rad"].to_numpy(dtype=float) if "heading_rad" in truth else None
        out["map.evo_truth"] = tum_text(ts[rows], truth["x_m"].to_numpy(float)[rows],
                                        truth["y_m"].to_numpy(float)[rows], None if th is None else th[rows])
    out.update(_waypoint_texts(ds, xy, offsets))
    return out, clock


def _waypoint_texts(ds: Dataset, xy: np.ndarray, offsets: dict[str, float]) -> dict[str, str]:
    """The waypoints of the map's walks and the map at their times, on the shared clock ({} without)."""
    fx = ds.fixes
    if fx is None or not len(fx):
        return {}
    fw = fx["walk_id"].astype(str).to_numpy()
    ft = fx["t_s"].to_numpy(dtype=float)
    placed = ds.poses[["walk_id", "t_s"]].assign(x_m=xy[:, 0], y_m=xy[:, 1])
    est = estimates_at_fixes(placed, fw, ft)
    ok = np.isfinite(est).all(axis=1) & np.isin(fw, list(offsets))
    if not ok.any():
        return {}
    ts = ft + pd.Series(fw).map(offsets).to_numpy(dtype=float)
    rows = np.flatnonzero(ok)[np.argsort(ts[ok], kind="stable")]
    return {"map.evo_waypoints": tum_text(ts[rows], fx["x_m"].to_numpy(float)[rows], fx["y_m"].to_numpy(float)[rows]),
            "map.evo_map_at_waypoints": tum_text(ts[rows], est[rows, 0], est[rows, 1])}


def evo_recipe(frame: str, keys: set[str]) -> list[str]:
    """The evo commands that score the map with what was written (paths relative to the workspace)."""
    align = "" if frame == "building" else " -a"
    out = []
    if "map.evo_truth" in keys:
        out.append(f"evo_ape tum map/evo/truth.txt map/evo/map.txt{align}")
    if "map.evo_waypoints" in keys:
        out.append(f"evo_ape tum map/evo/waypoints.txt map/evo/map_at_waypoints.txt{align}")
    return out
