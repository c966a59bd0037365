"""The tables and figures :func:`rmbuild.slam.optimize` reports: per walk, and for the whole run."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.slam.checks import CheckResult
from rmbuild.slam.evidence.base import Ties
from rmbuild.slam.placement import Placement
from rmbuild.slam.problem import COVERED_BIN_M, WalkSet
from rmbuild.slam.solve import SolveOutcome
from rmbuild.slam.uncertainty import predicted_errors


def walk_table(walks: WalkSet, placement: Placement, pairs: pd.DataFrame, checks: CheckResult,
               outcome: SolveOutcome, final_xyt: np.ndarray, ties: Ties) -> pd.DataFrame:
    """Per walk: walk_id, n_poses, linked, component, reference, n_cross_pairs, n_partner_walks,
    shared_path_m, world_T_walk_x_m / _y_m / _theta_rad, heading_known, extent_ratio, predicted_error_m
    (:mod:`rmbuild.slam.uncertainty`; NaN for walks not placed), placement, placement_round,
    placement_inliers, anchored, scale, scale_fitted, rf_overlap_scans / rf_log_lr (the RF check's figures:
    scans overlapping the walks placed before it, their mean log likelihood ratio near vs far; NaN when not
    judged)."""
    n_walks = walks.n_walks
    n_cross, _, shared, partners = _cross_pair_counts(walks, pairs)
    linked = placement.linked & walks.keep
    cross = pairs[pairs["kind"] == "cross"]
    pred = predicted_errors(walks, final_xyt, linked, cross["node_k"].to_numpy(), cross["node_q"].to_numpy(), ties,
                            np.asarray(placement.heading_known, bool), placement.rf_log_lr,
                            np.asarray(placement.method) == "continuity")
    T = placement.world_T_walk
    anchored = placement.anchored if placement.anchored is not None else np.zeros(n_walks, bool)
    return pd.DataFrame({
        "walk_id": walks.walk_ids, "n_poses": walks.ends - walks.starts, "linked": linked,
        "component": placement.component.astype(np.int64), "reference": np.arange(n_walks) == placement.reference,
        "n_cross_pairs": n_cross, "n_partner_walks": partners, "shared_path_m": shared,
        "world_T_walk_x_m": T[:, 0], "world_T_walk_y_m": T[:, 1], "world_T_walk_theta_rad": T[:, 2],
        "heading_known": placement.heading_known, "extent_ratio": checks.extent_ratio, "predicted_error_m": pred,
        "placement": placement_labels(placement, linked, anchored),
        "placement_round": placement.round_placed if placement.round_placed is not None else np.full(n_walks, -1),
        "placement_inliers": placement.n_inliers if placement.n_inliers is not None else np.zeros(n_walks, int),
        "anchored": anchored,
        "scale": outcome.scale, "scale_fitted": outcome.scale_fitted,
        "rf_overlap_scans": _or(placement.rf_overlap_scans, np.zeros(n_walks, np.int64)),
        "rf_log_lr": _or(placement.rf_log_lr, np.full(n_walks, np.nan)),
    })


def _or(a: np.ndarray | None, default: np.ndarray) -> np.ndarray:
    return a if a is not None else default


def _cross_pair_counts(walks: WalkSet, pairs: pd.DataFrame):
    """Per walk: cross pairs, of them in range at the end, shared path (m) they cover, partner walks."""
    n_walks = walks.n_walks
    cr = pairs[pairs["kind"] == "cross"]
    nk, nq = cr["node_k"].to_numpy(), cr["node_q"].to_numpy()
    wk, wq = walks.walk_of[nk], walks.walk_of[nq]
    inr = cr["in_range"].to_numpy().astype(np.int64)
    n_cross = np.bincount(wk, minlength=n_walks) + np.bincount(wq, minlength=n_walks)
    n_in = np.bincount(wk, weights=inr, minlength=n_walks) + np.bincount(wq, weights=inr, minlength=n_walks)
    own, other = np.r_[wk, wq], np.r_[wq, wk]  # each pair seen from both of its walks
    partners = np.bincount(np.unique(own * n_walks + other) // n_walks, minlength=n_walks).tolist()
    return n_cross.astype(np.int64), n_in.astype(np.int64), _covered_per_walk(walks, own, np.r_[nk, nq]), partners


def _covered_per_walk(walks: WalkSet, walk: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """(n_walks,) :func:`covered_m` of each walk's ``nodes`` (``walk``: whose node each is), all walks at once."""
    bins = np.floor(walks.path[nodes] / COVERED_BIN_M).astype(np.int64)
    stride = int(bins.max(initial=0)) + 1
    return np.bincount(np.unique(walk.astype(np.int64) * stride + bins) // stride, minlength=walks.n_walks) \
        * COVERED_BIN_M


def placement_labels(placement: Placement, linked: np.ndarray, anchored: np.ndarray) -> np.ndarray:
    """How each walk got its initial frame: "reference", "translation" / "se2" (walk-to-map fit with the
    compass rotation / with a fitted one), "pair" (a walk-pair edge), "merge" (its component was fitted to
    the map as one body), "anchor" (not linked, placed by anchors), "refuted" (not linked: the RF check
    contradicted its fit), "" (neither, or every walk at the origin)."""
    out = np.array(placement.method, dtype=object, copy=True)
    out[placement.reference] = "reference"
    out[~linked & (out != "refuted")] = ""
    out[~linked & anchored] = "anchor"
    return out


def unlinked_warning(walks: WalkSet, table: pd.DataFrame, reference: int) -> str | None:
    """One line naming the walks not linked to the reference walk (None when every kept walk is)."""
    linked, anchored = table["linked"].to_numpy(), table["anchored"].to_numpy()
    unlinked = np.flatnonzero(walks.keep & ~linked & ~anchored)
    if not len(unlinked):
        return None
    by_anchor = int((anchored & ~linked).sum())
    names = ", ".join(walks.walk_ids[w] for w in unlinked[:5]) + (", ..." if len(unlinked) > 5 else "")
    also = f"; {by_anchor} more placed by anchors alone" if by_anchor else ""
    return (f"{len(unlinked)} of {int(walks.keep.sum())} walk(s) not linked to the reference walk "
            f"{walks.walk_ids[reference]} ({names}): their placement is not constrained by Wi-Fi{also} "
            "and they are left out of the map (optimize/walks.parquet: linked, anchored, component)"
            f"{_groups(table, unlinked)}; "
            "to place them give known positions (`optimize --anchors FILE`), a floor plan (`ingest --floorplan "
            "FILE`) or more walks through the same places")


def _groups(table: pd.DataFrame, unlinked: np.ndarray) -> str:
    """How the unlinked walks hang together: groups placed against each other (their ``component``), which
    one walk through a group's places and the map's would join, largest first; "" when none has 2 walks."""
    sizes = table["component"].to_numpy()[unlinked]
    _, counts = np.unique(sizes, return_counts=True)
    groups = np.sort(counts[counts >= 2])[::-1]
    if not len(groups):
        return ""
    shown = ", ".join(str(int(n)) for n in groups[:5]) + (", ..." if len(groups) > 5 else "")
    return (f"; {int(groups.sum())} of them form {len(groups)} group(s) placed against each other ({shown} walks): "
            "one walk through a group's places and the map's would join the group")
