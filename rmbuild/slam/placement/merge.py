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
    """Fit whole secondary components (walks placed against each other but not against the reference's
    map) rigidly to component 0, largest first, until none is accepted; returns (state, merged any).

    A component of several short walks pools its links to the map: each walk alone may lack the shared
    path a fit needs while the group has it. The fit is :func:`fit_to_pairs` with the component's frame as
    the walk frame (translation-only when the compass gives the component's rotation, SE(2) otherwise) and
    the same acceptance; shared path sums over the component's walks. Single-walk components are not
    retried (the walk-to-map growth already failed them).
    """
    rng = np.random.default_rng(RANSAC_SEED + 1)
    st = st.copy()
    ref = st.reference
    wo = walks.walk_of
    wk, wq = wo[nk], wo[nq]
    walk_len = walks.walk_lengths()
    merged_any = False
    while True:
        placed = st.comp == 0
        sizes = np.bincount(st.comp, minlength=int(st.comp.max()) + 1)
        order = [c for c in np.argsort(-sizes, kind="stable") if c > 0 and sizes[c] >= 2]
        done = False
        for c in order:
            members = st.comp == c
            m = (placed[wk] & members[wq]) | (placed[wq] & members[wk])
            if m.sum() < cfg.min_inliers:
                continue
            rows = np.flatnonzero(m)
            mnode = np.where(placed[wk[rows]], nk[rows], nq[rows])
            cnode = np.where(placed[wk[rows]], nq[rows], nk[rows])
            pm, pc = walks.world_xy(st.T, mnode), walks.world_xy(st.T, cnode)
            # walked distance made distinct per walk so the shared path sums the component's walks
            cpath = walks.path[cnode] + wo[cnode] * (np.ceil(walk_len.max()) + 10.0)
            hm = members & st.heading_used & rot.known
            prior = component_compass_offset(st.T, hm, rot, ref) if rot.known[ref] and hm.any() else np.nan
            f, ok = None, False
            if np.isfinite(prior):
                f = fit_to_pairs(pm, pc, cnode, cpath, wo[mnode], prior, cfg, rng)
                ok = accept_pairs_fit(f, False, cfg)
            if not ok:
                f2 = fit_to_pairs(pm, pc, cnode, cpath, wo[mnode], None, cfg, rng)
                if accept_pairs_fit(f2, True, cfg):
                    f, ok = f2, True
            log.append({"phase": "merge", "component": int(c), "walks": int(members.sum()), "accepted": bool(ok),
                        "score": f.score if f else 0, "second": f.second if f else 0,
                        "shared_m": f.shared_m if f else 0.0, "method": f.method if f else "",
                        "pairs": len(rows), "T": None if f is None else f.t.tolist()})
            if not ok or f is None:
                continue
            st.T[members] = geometry.compose(f.t, st.T[members])
            st.comp[members] = 0
            st.method[members] = "merge"
            if f.method == "se2":
                st.heading_used[members] = False
            done = merged_any = True
            break  # the map grew: recompute sizes and links
        if not done:
            break
    if not merged_any:
        return st, False
    placed = st.comp == 0
    st.T = refine_placed(st.T, placed, nk, nq, walks, ref, compass_priors(rot, ref), st.heading_used, rot.sigma,
                         cfg.gate_m, window_lengths(walks, cfg))
    _, st.comp = np.unique(st.comp, return_inverse=True)  # renumber the rest 1, 2, ... in their old order
    return st, True


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
