"""What placement produces and works on: a walk fit, the growing state, the final placement."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class WalkFit:
    """A rigid fit of one walk (or a rigid group of walks) to the placed map."""

    t: np.ndarray  # (3,) world_T_walk
    score: int  # distinct inlier scans of the walk
    second: int  # the same for the best hypothesis elsewhere (pairs), or the outlier scans (kNN)
    shared_m: float  # walked path (m) the inliers cover
    partners: int  # placed walks among the inliers
    method: str  # "translation" (compass rotation), "se2" (fitted rotation), "pair" (a walk-pair edge)
    inliers: np.ndarray  # bool over the correspondences fitted


@dataclass
class GrowState:
    """The placement while it grows: per walk its frame, component (-1 = not yet placed), the round it was
    placed in, its inlier count and shared path at placement, how it was placed, whether its compass
    rotation is trusted, and when it was placed (``order``: the placement event, -1 never; walks placed
    together by one round, merge or tie share one; ``epoch`` the latest event)."""

    T: np.ndarray
    comp: np.ndarray
    rnd: np.ndarray
    n_inl: np.ndarray
    shared: np.ndarray
    method: np.ndarray
    heading_used: np.ndarray
    reference: int
    order: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    epoch: int = 0
    fixed: np.ndarray | None = None  # (n_walks,) walks held where they are (an incremental run's map), or None

    @staticmethod
    def empty(n_walks: int, reference: int, heading_known: np.ndarray, fixed: np.ndarray | None = None) -> GrowState:
        """Nothing placed; the ``fixed`` walks (an incremental run's held map) already in component 0 at the
        identity frame, placed by one event."""
        st = GrowState(np.zeros((n_walks, 3)), np.full(n_walks, -1), np.full(n_walks, -1),
                       np.zeros(n_walks, np.int64), np.zeros(n_walks), np.full(n_walks, "", dtype=object),
                       heading_known.copy(), reference, np.full(n_walks, -1, np.int64), fixed=fixed)
        if fixed is not None:
            st.comp[fixed], st.rnd[fixed], st.method[fixed], st.order[fixed] = 0, 0, "held", st.tick()
        return st

    def tick(self) -> int:
        """Start a new placement event (the walks placed next share it)."""
        self.epoch += 1
        return self.epoch

    def place(self, w: int, f: WalkFit, c_id: int, rnd: int) -> None:
        self.T[w] = f.t
        self.comp[w], self.rnd[w], self.n_inl[w] = c_id, rnd, f.score
        self.shared[w], self.method[w] = f.shared_m, f.method
        self.order[w] = self.epoch

    def seed(self, w: int, c_id: int) -> None:
        self.comp[w], self.rnd[w], self.method[w], self.T[w] = c_id, 0, "seed", (0.0, 0.0, 0.0)
        self.order[w] = self.tick()

    def copy(self) -> GrowState:
        return GrowState(self.T.copy(), self.comp.copy(), self.rnd.copy(), self.n_inl.copy(), self.shared.copy(),
                         self.method.copy(), self.heading_used.copy(), self.reference, self.order.copy(), self.epoch,
                         self.fixed)


@dataclass
class Placement:
    """Every walk's initial frame in the common frame and how it got it.

    ``world_T_walk`` (n_walks, 3); ``component`` (n_walks,) 0 = the reference walk's (linked) component;
    ``heading_known`` walks whose compass rotation is trusted; ``method`` how each walk was placed
    ("seed", "translation", "se2", "pair", "merge", "refuted" (unlinked by the RF check), "");
    ``links`` (node_k, node_q) scan links the kNN
    rounds placed walks with, or None; ``gate_m`` the distance (m) within which a correspondence is
    consistent with this placement, None when the placement verified nothing (every walk at the origin).
    ``frame`` names the map's frame ("reference walk", "floorplan", "anchors"). Anchors and a floor plan
    set ``frame_rotation`` (rad, applied to the reference frame); anchors set ``gauge_full`` /
    ``gauge_rotation_only`` (component roots that need a full / rotation-only gauge prior) and
    ``anchored``; without anchors each component's root gets a full gauge prior.
    ``edge_fits``: (tested, accepted) walk-pair fits; ``log``: one record per fit tried (diagnostics);
    ``round_placed`` / ``n_inliers`` / ``shared_m`` (n_walks,): the growth round a walk was placed in (-1
    never, 0 for seeds), its inlier scans and shared path (m) then; ``fixed`` (n_walks,) the walks an
    incremental run held where they were (None in a full run); ``refuted`` the walks the RF check
    (:mod:`.rfcheck`) took out of the reference component, ``rf_overlap_scans`` / ``rf_log_lr`` (n_walks,) the
    check's figures; ``order`` (n_walks,) the placement event that put each walk where it is
    (:class:`GrowState`).
    """

    world_T_walk: np.ndarray
    component: np.ndarray
    reference: int
    heading_known: np.ndarray
    method: np.ndarray
    links: tuple[np.ndarray, np.ndarray] | None = None
    gate_m: float | None = None
    frame_rotation: float = 0.0
    frame: str = "reference walk"
    gauge_full: list[int] = field(default_factory=list)
    gauge_rotation_only: list[int] = field(default_factory=list)
    anchored: np.ndarray | None = None
    n_anchors: int = 0
    edge_fits: tuple[int, int] = (0, 0)
    log: list[dict] = field(default_factory=list)
    round_placed: np.ndarray | None = None
    n_inliers: np.ndarray | None = None
    shared_m: np.ndarray | None = None
    refuted: list[int] = field(default_factory=list)
    order: np.ndarray | None = None
    rf_overlap_scans: np.ndarray | None = None
    rf_log_lr: np.ndarray | None = None
    fixed: np.ndarray | None = None
    rf_typical_match_db: float | None = None

    @property
    def linked(self) -> np.ndarray:
        return self.component == 0
