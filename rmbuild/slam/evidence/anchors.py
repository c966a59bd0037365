"""Anchor evidence: known building-frame positions of walks at given times (walk_id, t_s, x_m, y_m).

- After placement each placed component is moved onto its anchors: an SE(2) fit with two or more anchors
  more than 1 m apart, else a translation (the rotation stays the reference component's, which the
  compass gives). A component with anchors needs no gauge prior of its own (a translation-only one keeps
  a rotation prior on its root).
- Solve: a position prior (sigma ``sigma_m``) on the pose nearest in time to each anchor.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pandas as pd

from rmbuild import geometry
from rmbuild.config.optimize import AnchorConfig
from rmbuild.errors import InputError
from rmbuild.slam.evidence.base import EvidenceSource, StaticFactors
from rmbuild.slam.factors import X
from rmbuild.slam.problem import WalkSet

ANCHOR_COLUMNS = ("walk_id", "t_s", "x_m", "y_m")
# m; anchors of one component must spread this far (in x or y) to fix its rotation too
MIN_SPREAD_FOR_ROTATION_M = 1.0


class AnchorSource(EvidenceSource):
    """Known positions (module docstring); an empty table is allowed and contributes nothing."""

    name = "anchors"

    def __init__(self, walks: WalkSet, anchors: pd.DataFrame | None, cfg: AnchorConfig):
        self.warnings: list[str] = []
        self.cfg = cfg
        self.table = anchors if anchors is not None else pd.DataFrame(columns=list(ANCHOR_COLUMNS))
        self.nodes = anchor_nodes(self.table, walks, cfg.max_gap_s) if len(self.table) else np.zeros(0, np.int64)
        self.xy = self.table[["x_m", "y_m"]].to_numpy(float) if len(self.table) else np.zeros((0, 2))

    def place(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        """Move each placed component onto its anchors; set the placement's gauge and ``anchored``."""
        comp = placement.component
        T = placement.world_T_walk
        full, rot_only = [], []
        anchored = np.zeros(len(comp), bool)
        th_ref = 0.0  # rotation the anchors gave the reference component (the others follow it)
        for c in np.unique(comp).tolist():  # a plan may have emptied some component ids
            walks_c = np.flatnonzero(comp == c)
            root = placement.reference if c == 0 else int(walks_c[0])
            m = comp[walks.walk_of[self.nodes]] == c if len(self.nodes) else np.zeros(0, bool)
            if m.sum() == 0:
                full.append(root)
                continue
            src, dst = init_xyt[self.nodes[m], :2], self.xy[m]
            if m.sum() >= 2 and np.ptp(dst, axis=0).max() > MIN_SPREAD_FOR_ROTATION_M:
                Tc = geometry.fit_rigid(src, dst)
                anchored[walks_c] = True
            else:
                Tc = geometry.fit_rigid(src, dst, theta=th_ref)
                rot_only.append(root)
                anchored[walks_c] = np.asarray(placement.heading_known, bool)[walks_c]
            if c == 0:
                th_ref = float(Tc[2])
            T[walks_c] = geometry.compose(Tc, T[walks_c])
        if len(self.nodes):
            placement.frame_rotation += th_ref
            placement.frame = "anchors"
        placement.gauge_full, placement.gauge_rotation_only = full, rot_only
        placement.anchored = anchored & walks.keep
        placement.n_anchors = len(self.nodes)

    def required_nodes(self) -> np.ndarray:
        return self.nodes

    def static_factors(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> StaticFactors:
        noise = gtsam.noiseModel.Isotropic.Sigma(2, self.cfg.sigma_m)
        f = [gtsam.PoseTranslationPrior2D(X(int(node)), gtsam.Pose2(float(x), float(y), 0.0), noise)
             for node, (x, y) in zip(self.nodes.tolist(), self.xy.tolist())]
        return StaticFactors(f, {"anchor": len(f)})

    def report(self) -> dict:
        return {"anchors": len(self.nodes)}


def anchor_nodes(anchors: pd.DataFrame, walks: WalkSet, max_gap_s: float) -> np.ndarray:
    """Node id of the pose nearest in time to each anchor; InputError (naming the anchor's row, counted
    from 1) for an unknown walk or an anchor more than ``max_gap_s`` outside its walk's time span."""
    for col in ANCHOR_COLUMNS:
        if col not in anchors:
            raise InputError(f"anchors table lacks column {col!r}")
    index = {w: i for i, w in enumerate(walks.walk_ids)}
    out = np.empty(len(anchors), np.int64)
    for i, (wid, ta) in enumerate(zip(anchors["walk_id"].astype(str), anchors["t_s"].to_numpy(float))):
        if wid not in index:
            raise InputError(f"anchor row {i + 1}: unknown walk {wid!r}")
        s, e = walks.starts[index[wid]], walks.ends[index[wid]]
        tt = walks.t_s[s:e]
        if not np.isfinite(ta) or not (tt[0] - max_gap_s <= ta <= tt[-1] + max_gap_s):
            raise InputError(f"anchor row {i + 1}: t_s={ta} is outside walk {wid}'s time span [{tt[0]}, {tt[-1]}] "
                             f"(by more than anchors.max_gap_s = {max_gap_s:g} s)")
        out[i] = s + int(np.argmin(np.abs(tt - ta)))
    return out
