"""Placement: every walk's initial frame in the common frame, from the evidence sources.

:func:`place` composes the steps of method "grow" (module docstrings of :mod:`.grow` and :mod:`.merge`):

1. growth on the links (walk-pair edges as the fallback) from the reference walk;
2. growth on localised scans, extending the reference's component;
3. merges of further components onto it, each followed by more scan growth, while the map grows;
4. the remaining components turned to agree with the compass;
5. components joined by position ties (session continuity, :mod:`.link`).

Without a configured reference the walk with the most links seeds the map; when its component ends up
smaller (in walked path) than another, growth is run again from that other component's best-linked walk
and the larger reference component is kept. Method "origin" (the paper) leaves every walk at the origin.
"""

from __future__ import annotations

import numpy as np

from rmbuild.config.optimize import PlacementConfig
from rmbuild.slam.evidence.base import EvidenceSource, Links, RotationPriors, Ties
from rmbuild.slam.placement.edges import pair_edges
from rmbuild.slam.placement.grow import PairEvidence, ScanEvidence, grow
from rmbuild.slam.placement.link import link_components
from rmbuild.slam.placement.merge import merge_components, orient_components
from rmbuild.slam.placement.model import GrowState, Placement, WalkFit
from rmbuild.slam.problem import WalkSet

__all__ = ["Placement", "WalkFit", "place"]

# merge / scan-growth alternations after the first growth
MERGE_ROUNDS = 3


def gather(sources: list[EvidenceSource], walks: WalkSet) -> tuple[Links, RotationPriors, object, Ties]:
    """The sources' links and ties (concatenated), rotation priors (the first source's that has them, else
    none known) and scan locator (the first one offered)."""
    ks, qs, rot, sim, ties = [], [], None, None, []
    for s in sources:
        lk = s.links()
        if lk is not None:
            ks.append(lk.node_k)
            qs.append(lk.node_q)
        rot = rot or s.rotation_priors()
        sim = sim or s.scan_locator()
        t = s.ties()
        if t is not None:
            ties.append(t)
    empty = np.zeros(0, np.int64)
    links = Links(np.concatenate(ks) if ks else empty, np.concatenate(qs) if qs else empty)
    tie = Ties(*(np.concatenate([getattr(t, f) for t in ties]) if ties else empty
                 for f in ("node_a", "node_b", "sigma_m")))
    if rot is None:
        n = walks.n_walks
        rot = RotationPriors(np.zeros(n), np.zeros(n, bool), np.full(n, np.inf))
    return links, rot, sim, tie


def place(walks: WalkSet, sources: list[EvidenceSource], cfg: PlacementConfig, reference: int | None,
          fixed: np.ndarray | None = None) -> Placement:
    """Every walk's initial frame (module docstring). ``fixed`` (n_walks,): an incremental run's held walks,
    in the reference's component from the start at their (identity) frames and never moved; growth, merges
    and ties then extend that map (``reference`` must be one of them)."""
    links, rot, sim, ties = gather(sources, walks)
    if cfg.method == "origin":
        return origin_placement(walks, links, reference)
    cnt = np.bincount(np.r_[walks.walk_of[links.node_k], walks.walk_of[links.node_q]],
                      minlength=walks.n_walks).astype(float)
    edges = pair_edges(walks, links, rot, cfg.min_shared_se2_m)
    ctx = (walks, links, rot, sim, ties, cfg, cnt, [(e.a, e.b, e.T) for e in edges if e.accepted], fixed)
    if reference is not None:
        res = _grow_from(reference, *ctx)
    else:
        res = _grow_from(int(np.argmax(np.where(walks.keep, cnt, -1))), *ctx)
        wlen = walks.walk_lengths() * walks.keep
        size = np.bincount(res.component, weights=wlen)
        big = int(np.argmax(size))
        if big != 0 and size[big] > size[0]:
            alt = _grow_from(int(np.argmax(np.where((res.component == big) & walks.keep, cnt, -1))), *ctx)
            if float(wlen[alt.component == 0].sum()) > size[0]:
                res = alt
    res.edge_fits = (len(edges), sum(e.accepted for e in edges))
    return res


def _grow_from(ref: int, walks: WalkSet, links: Links, rot: RotationPriors, sim, ties: Ties,
               cfg: PlacementConfig, cnt: np.ndarray, edges: list, fixed: np.ndarray | None) -> Placement:
    """One growth (links, scan rounds, merges) from the reference walk ``ref`` (or the ``fixed`` walks)."""
    log: list[dict] = []
    st = GrowState.empty(walks.n_walks, ref, rot.known, fixed)
    st = grow(st, PairEvidence(walks, links.node_k, links.node_q, edges, cfg), walks, rot, cfg, cnt, log)
    lk_all, lq_all = [], []

    def scan_growth(st: GrowState) -> GrowState:
        ev = ScanEvidence(walks, sim, cfg)
        st = grow(ev.restart(st, rot), ev, walks, rot, cfg, cnt, log)
        lk, lq = ev.links()
        lk_all.append(lk)
        lq_all.append(lq)
        return st

    for _ in range(MERGE_ROUNDS):
        if sim is not None:
            st = scan_growth(st)
        st = orient_components(st, rot)
        st, linked = link_components(st, walks, ties, links, rot, cfg, log) if len(ties) else (st, 0)
        st, merged = merge_components(st, walks, links.node_k, links.node_q, rot, cfg, log)
        if not (linked or merged):
            break
    st = orient_components(st, rot)
    scan_links = (np.concatenate(lk_all), np.concatenate(lq_all)) if lk_all else None
    return Placement(st.T, st.comp, ref, st.heading_used & rot.known, st.method, links=scan_links,
                     gate_m=cfg.gate_m, log=log, round_placed=st.rnd, n_inliers=st.n_inl, shared_m=st.shared,
                     order=st.order, fixed=fixed)


def origin_placement(walks: WalkSet, links: Links, reference: int | None) -> Placement:
    """The paper: every walk at the origin; components from any cross-walk link."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = walks.n_walks
    a, b = walks.walk_of[links.node_k], walks.walk_of[links.node_q]
    _, comp = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    ref = int(reference) if reference is not None else int(np.argmax(np.bincount(np.r_[a, b], minlength=n)))
    _, comp = np.unique(np.where(comp == comp[ref], -1, comp), return_inverse=True)
    return Placement(np.zeros((n, 3)), comp, ref, np.zeros(n, bool), np.full(n, "", dtype=object), gate_m=None)
