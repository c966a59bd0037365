"""Components as rigid bodies: merged onto the reference's map, or turned to agree with the compass."""

from __future__ import annotations

import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import PlacementConfig
from rmbuild.slam.evidence.base import RotationPriors
from rmbuild.slam.evidence.compass import component_compass_offset
from rmbuild.slam.placement.edges import RANSAC_SEED
from rmbuild.slam.placement.fits import accept_pairs_fit, fit_to_pairs
from rmbuild.slam.placement.grow import compass_priors, window_lengths
from rmbuild.slam.placement.model import GrowState
from rmbuild.slam.placement.refine import refine_placed
from rmbuild.slam.problem import WalkSet


def merge_components(st: GrowState, walks: WalkSet, nk: np.ndarray, nq: np.ndarray, rot: RotationPriors,
                     cfg: PlacementConfig, log: list) -> tuple[GrowState, bool]:
    """Fit whole components (walks placed against each other) rigidly onto other components — component 0
    first, then the others, largest first — until none is accepted; returns (state, merged any).

    A component of several short walks pools its links: each walk alone may lack the shared path a fit
    needs while the group has it. The fit is :func:`fit_to_pairs` with the moving component's frame as the
    walk frame (translation-only when the compass gives the relative rotation, SE(2) otherwise) and the
    same acceptance; shared path sums over the component's walks. Single-walk components are not moved
    (growth already tried them).
    """
    rng = np.random.default_rng(RANSAC_SEED + 1)
    st = st.copy()
    merged_any = False
    while True:
        sizes = np.bincount(st.comp, minlength=int(st.comp.max()) + 1)
        order = [int(c) for c in np.argsort(-sizes, kind="stable") if c > 0 and sizes[c] >= 2]
        targets = [0] + [int(d) for d in np.argsort(-sizes, kind="stable") if d > 0 and sizes[d] >= 1]
        done = False
        for c in order:
            for d in targets:
                if d != c and _merge_one(st, walks, nk, nq, rot, cfg, rng, c, d, log):
                    done = merged_any = True
                    break
            if done:
                break  # the components changed: recompute sizes and links
        if not done:
            break
    if not merged_any:
        return st, False
    placed = st.comp == 0
    st.T = refine_placed(st.T, placed, nk, nq, walks, st.reference, compass_priors(rot, st.reference),
                         st.heading_used, rot.sigma, cfg.gate_m, window_lengths(walks, cfg), st.fixed)
    _, st.comp = np.unique(st.comp, return_inverse=True)  # renumber the rest 1, 2, ... in their old order
    return st, True


def _merge_one(st: GrowState, walks: WalkSet, nk: np.ndarray, nq: np.ndarray, rot: RotationPriors,
               cfg: PlacementConfig, rng: np.random.Generator, c: int, d: int, log: list) -> bool:
    """Fit component c onto component d from their links; on acceptance move c into d (in place)."""
    wo = walks.walk_of
    wk, wq = wo[nk], wo[nq]
    placed, members = st.comp == d, st.comp == c
    m = (placed[wk] & members[wq]) | (placed[wq] & members[wk])
    if m.sum() < cfg.min_inliers:
        return False
    rows = np.flatnonzero(m)
    mnode = np.where(placed[wk[rows]], nk[rows], nq[rows])
    cnode = np.where(placed[wk[rows]], nq[rows], nk[rows])
    pm, pc = walks.world_xy(st.T, mnode), walks.world_xy(st.T, cnode)
    # walked distance made distinct per walk so the shared path sums the component's walks
    cpath = walks.path[cnode] + wo[cnode] * (np.ceil(walks.walk_lengths().max()) + 10.0)
    prior = _relative_compass(st, rot, c, d)
    f, ok = None, False
    if np.isfinite(prior):
        f = fit_to_pairs(pm, pc, cnode, cpath, wo[mnode], prior, cfg, rng)
        ok = accept_pairs_fit(f, False, cfg)
    if not ok:
        f2 = fit_to_pairs(pm, pc, cnode, cpath, wo[mnode], None, cfg, rng)
        if accept_pairs_fit(f2, True, cfg):
            f, ok = f2, True
    log.append({"phase": "merge", "component": int(c), "onto": int(d), "walks": int(members.sum()),
                "accepted": bool(ok), "score": f.score if f else 0, "second": f.second if f else 0,
                "shared_m": f.shared_m if f else 0.0, "method": f.method if f else "", "pairs": len(rows),
                "T": None if f is None else f.t.tolist(), "members": np.flatnonzero(members).tolist()})
    if not ok or f is None:
        return False
    st.T[members] = geometry.compose(f.t, st.T[members])
    st.comp[members] = d
    st.method[members] = "merge"
    st.order[members] = st.tick()
    if f.method == "se2":
        st.heading_used[members] = False
    return True


def _relative_compass(st: GrowState, rot: RotationPriors, c: int, d: int) -> float:
    """Rotation (rad) taking component c's frame to component d's by the compass (NaN without one): the
    reference component's frame is the compass frame (d = 0); another's is its own seed's."""
    ref = st.reference
    if not rot.known[ref]:
        return np.nan
    hc = (st.comp == c) & st.heading_used & rot.known
    if not hc.any():
        return np.nan
    off_c = component_compass_offset(st.T, hc, rot, ref)
    if d == 0:
        return off_c
    hd = (st.comp == d) & st.heading_used & rot.known
    return float(geometry.wrap(off_c - component_compass_offset(st.T, hd, rot, ref))) if hd.any() else np.nan


def orient_components(st: GrowState, rot: RotationPriors) -> GrowState:
    """Rotate each component other than the reference's (about the origin) so that its walks' compass
    rotations agree with the reference's on average (circular mean over its walks with a trusted compass).
    A further component is seeded in its seed walk's own frame, whose start heading is arbitrary; without
    this its walks would start the joint solve up to 180 deg from their heading priors."""
    ref = st.reference
    if not rot.known[ref]:
        return st
    st = st.copy()
    for c in np.unique(st.comp):
        members = st.comp == c
        hm = members & st.heading_used & rot.known
        if c == st.comp[ref] or not hm.any():
            continue
        off = component_compass_offset(st.T, hm, rot, ref)
        st.T[members] = geometry.compose(np.array([0.0, 0.0, off]), st.T[members])
    return st

