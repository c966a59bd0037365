"""Whether an incremental run's new walks agree with the held map (:mod:`rmbuild.slam.held`).

The held walks stay where the last optimize put them; that is right only while the new evidence agrees with
them. Two tests, both on what the run computed anyway:

* **the map would move**: the walk-level refinement (:mod:`.refine`) of the reference component run again
  with the held walks released (only the reference walk pinned), on the links between the placed walks: a
  held walk that then moves further than its predicted error (the last optimize's, at least
  MIN_MOVE_M) is contradicted by the new links;
* **the RF check refutes the new placements**: the share of the walks this run placed that the RF check
  (:mod:`.rfcheck`) took out again.

Either beyond its limit, the incremental answer is not kept (the caller runs the full optimization).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild.slam.placement.model import Placement
from rmbuild.slam.placement.refine import refine_placed
from rmbuild.slam.problem import WalkSet

# m; a held walk counts as moved when its nodes move on average further than its predicted error and this
MIN_MOVE_M = 3.0
# share of the held walks (with links to the walks placed) that may move before the run gives up
MAX_MOVED_SHARE = 0.2
# share of the walks placed by this run that the RF check may refute before the run gives up
MAX_REFUTED_SHARE = 0.2


@dataclass
class HeldCheck:
    """The figures of the two tests and the verdict: ``moved`` held walks (of ``linked_held``: those with
    links to the walks placed), ``refuted`` / ``placed`` walks of this run, ``reason`` (None: agreed)."""

    moved: list[int]
    linked_held: int
    move_m: dict[int, float]
    refuted: int
    placed: int
    reason: str | None

    def report(self, walks: WalkSet) -> dict:
        return {"held_walks_moved": [walks.walk_ids[w] for w in self.moved], "held_walks_linked": self.linked_held,
                "held_move_m": {walks.walk_ids[w]: round(v, 2) for w, v in self.move_m.items()},
                "refuted": self.refuted, "placed": self.placed, "gave_up": self.reason}


def held_move(walks: WalkSet, placement: Placement, nk: np.ndarray, nq: np.ndarray, rot, gate_m: float,
              window_m: np.ndarray) -> dict[int, float]:
    """Per held walk linked to a walk this run placed: the mean distance (m) its nodes move when the
    reference component's walks are refined with the held walks released."""
    assert placement.fixed is not None
    fixed = placement.fixed
    placed = placement.linked & walks.keep
    wk, wq = walks.walk_of[nk], walks.walk_of[nq]
    cross = placed[wk] & placed[wq] & (fixed[wk] != fixed[wq])
    linked_held = np.unique(np.r_[wk[cross & fixed[wk]], wq[cross & fixed[wq]]])
    if not len(linked_held):
        return {}
    ref = placement.reference
    prior = np.where(rot.known, rot.theta - rot.theta[ref], np.nan) if rot.known[ref] else np.full(len(fixed), np.nan)
    T0 = placement.world_T_walk
    T1 = refine_placed(T0, placed, nk, nq, walks, ref, prior, placement.heading_known, rot.sigma, gate_m, window_m)
    out = {}
    for w in linked_held.tolist():
        nodes = np.arange(walks.starts[w], walks.ends[w])
        out[w] = float(np.linalg.norm(walks.world_xy(T1, nodes) - walks.world_xy(T0, nodes), axis=1).mean())
    return out


def check(walks: WalkSet, placement: Placement, move_m: dict[int, float], predicted_m: np.ndarray) -> HeldCheck:
    """The verdict (module docstring); ``predicted_m`` (n_walks,) the held walks' predicted errors (NaN unknown)."""
    limit = np.maximum(np.nan_to_num(predicted_m, nan=0.0), MIN_MOVE_M)
    moved = [w for w, m in move_m.items() if m > limit[w]]
    assert placement.fixed is not None
    fixed = placement.fixed
    refuted = np.isin(np.arange(walks.n_walks), placement.refuted) & ~fixed
    n_refuted = int(refuted.sum())
    n_placed = int((walks.keep & ~fixed & (placement.linked | refuted)).sum())
    reason = None
    if move_m and len(moved) > MAX_MOVED_SHARE * len(move_m):
        reason = (f"the new walks' links would move {len(moved)} of the {len(move_m)} held walks they touch "
                  f"further than their predicted error")
    elif n_placed and n_refuted > MAX_REFUTED_SHARE * n_placed:
        reason = f"the RF check refuted {n_refuted} of the {n_placed} walks placed against the held map"
    return HeldCheck(moved, len(move_m), move_m, n_refuted, n_placed, reason)
