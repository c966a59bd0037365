"""The tables and figures :func:`rmbuild.slam.optimize` reports: per walk, and for the whole run."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.slam.checks import CheckResult
from rmbuild.slam.evidence.base import Ties
from rmbuild.slam.held import Holding
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
    judged), reason (one sentence: why the walk is where it is, or why it was left out)."""
    n_walks = walks.n_walks
    n_cross, _, shared, partners = _cross_pair_counts(walks, pairs)
    linked = placement.linked & walks.keep
    cross = pairs[pairs["kind"] == "cross"]
    pred = predicted_errors(walks, final_xyt, linked, cross["node_k"].to_numpy(), cross["node_q"].to_numpy(), ties,
                            np.asarray(placement.heading_known, bool), placement.rf_log_lr,
                            np.asarray(placement.method) == "continuity")
    T = placement.world_T_walk
    anchored = placement.anchored if placement.anchored is not None else np.zeros(n_walks, bool)
    table = pd.DataFrame({
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
    return table.assign(reason=placement_reasons(table, placement.log))


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


def placement_reasons(table: pd.DataFrame, log: list[dict]) -> list[str]:
    """Per walk of :func:`walk_table`'s ``table``: one sentence saying how it was placed and on what
    evidence, or why it was left out (``log``: the placement's records; a merge's or a continuity join's
    names the walks it moved)."""
    joined: dict[int, dict] = {}
    for rec in log:  # the last accepted group move of each walk is the one that put it where it is
        if rec.get("phase") in ("merge", "continuity") and rec.get("accepted") and rec.get("members"):
            joined.update({int(w): rec for w in rec["members"]})
    comp = table["component"].to_numpy()
    sizes = np.bincount(comp, minlength=int(comp.max(initial=0)) + 1)
    return [_reason(row, joined.get(i), int(sizes[row.component])) for i, row in enumerate(table.itertuples())]


def _reason(row, group_move: dict | None, component_size: int) -> str:
    """:func:`placement_reasons` for one walk (a row of the walk table)."""
    how, pred = row.placement, row.predicted_error_m
    error = f"; predicted error {pred:.1f} m" if np.isfinite(pred) else ""
    rf = (f"; RF check: mean log-LR {row.rf_log_lr:+.2f} over {row.rf_overlap_scans} overlapping scans"
          if np.isfinite(row.rf_log_lr) else "")
    if how == "reference":
        return f"reference walk: the map's frame is its own{error}"
    if how == "held":
        return f"held: placed by the last optimize and kept where it was (an incremental run){error}"
    if how in ("translation", "se2", "pair"):
        fit = {"translation": "a translation (compass heading)", "se2": "a rigid fit (own rotation)",
               "pair": "a walk-pair fit"}[how]
        return (f"placed by Wi-Fi, {fit} on {row.placement_inliers} scans; shares {row.shared_path_m:.0f} m of "
                f"path with {row.n_partner_walks} other walk(s){rf}{error}")
    if how == "merge" and group_move:
        return (f"placed with a group of {group_move['walks']} walk(s) fitted to the map as one body: "
                f"fitted on {group_move['score']} scans over {group_move['shared_m']:.0f} m{rf}{error}")
    if how == "continuity" and group_move:
        return (f"placed with a group of {group_move['walks']} walk(s) by a continuity tie (one recording "
                f"session, tie sigma {group_move['sigma_m']:.1f} m){rf}{error}")
    if how == "floorplan":
        return f"placed by the floor plan's fit of its group of walks{error}"
    if how == "anchor":
        return "not linked by Wi-Fi: placed by its anchors alone"
    if how == "refuted":
        return f"left out: where Wi-Fi placed it, the radio disagrees with the walks already there{rf}"
    if row.linked:
        return f"placed ({how}){error}"
    group = (f" with {component_size - 1} other walk(s) placed against it" if component_size > 1 else "")
    return (f"left out: no verified link to the map{group} ({row.n_cross_pairs} Wi-Fi pairs with "
            f"{row.n_partner_walks} other walk(s))")


def incremental_summary(walks: WalkSet, holding: Holding, table: pd.DataFrame) -> dict:
    """What an incremental run placed: the new walks (placed or not), the held walks, and the old walks the
    last optimize left out, which were placed again with the new ones (now linked or not)."""
    linked = table["linked"].to_numpy(bool)
    ids = np.asarray(walks.walk_ids, dtype=object)
    new = ~holding.old & walks.keep
    redo = holding.old & ~holding.fixed & walks.keep
    return {"new_walks": ids[~holding.old].tolist(), "new_walks_placed": int((new & linked).sum()),
            "held_walks": int(holding.fixed.sum()), "old_walks_placed_again": ids[redo].tolist(),
            "old_walks_now_linked": ids[redo & linked].tolist()}


def placement_summary(table: pd.DataFrame) -> dict:
    """Walks per placement kind (Wi-Fi fit, merge, continuity, ...) with their median predicted error (m)."""
    kinds = table["placement"].replace({"translation": "wifi", "se2": "wifi", "pair": "wifi", "": "left out",
                                         "refuted": "left out"})
    out = {}
    for kind, rows in table.groupby(kinds.to_numpy(), sort=False):
        pred = rows["predicted_error_m"].to_numpy(float)
        out[str(kind)] = {"walks": len(rows),
                          "median_predicted_error_m": round(float(np.nanmedian(pred)), 2)
                          if np.isfinite(pred).any() else None}
    return out


#: m; a map whose linked walks' median predicted error exceeds this is said to be uncertain. Chosen across the
#: real floors and synthetic venues measured (docs/notes/placement-precision.md): every venue with 83-100 % of
#: its linked walks within 8 m of the truth had a median of 2.6-4.3 m, every floor with 29-70 % one of
#: 6.7-18.3 m; any value between makes the same call on each of them left out
DOUBTFUL_MEDIAN_ERROR_M = 5.5
#: m; a walk "placed right" lies within this of the truth (the measure of the notes): counted in the warning
RIGHT_M = 8.0


def uncertain_placement_warning(table: pd.DataFrame) -> str | None:
    """One line when the linked walks' median predicted error exceeds DOUBTFUL_MEDIAN_ERROR_M (None otherwise):
    on such floors whole groups of walks were found misplaced together, which no single walk's figures show."""
    pred = table.loc[table["linked"].to_numpy(bool), "predicted_error_m"].to_numpy(float)
    pred = pred[np.isfinite(pred)]
    med = float(np.median(pred)) if len(pred) >= 2 else 0.0
    if med <= DOUBTFUL_MEDIAN_ERROR_M:
        return None
    return (f"the linked walks' median predicted error is {med:.1f} m ({int((pred > RIGHT_M).sum())} "
            f"of {len(pred)} over {RIGHT_M:.0f} m): with evidence this weak, whole groups of walks can sit tens of "
            "metres from where they were walked and the Wi-Fi does not show it; check the map against a few known "
            "positions in each region of the floor (`optimize --anchors FILE`) and rely on walks by their predicted "
            "error (optimize/walks.parquet: predicted_error_m, reason)")


def unlinked_warning(walks: WalkSet, table: pd.DataFrame, reference: int, plan_used: bool) -> str | None:
    """One line naming the walks not linked to the reference walk (None when every kept walk is); a floor
    plan is suggested only when none was used."""
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
            "to place them give known positions (`optimize --anchors FILE`), "
            + ("" if plan_used else "a floor plan (`ingest --floorplan FILE`), ")
            + "or more walks through the same places (optimize/walks.parquet: reason)")


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
