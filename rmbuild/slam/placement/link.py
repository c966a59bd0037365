"""Components joined by position ties (session continuity), checked against the links between them.

Growth places walks against the map it grows from the reference walk; walks that share no radio evidence
with that map form further components, each internally consistent but placed apart. A tie (one walk's end,
the next walk's start, within about sigma metres) joins two components: after the components have been
turned to the compass, the tie gives the translation that puts one onto the other. Ties are taken in order
of their sigma (the most precise first, as Kruskal's algorithm takes edges), each one joining two
components (the one without the reference moves; of two others the smaller). Before a move is made the
links between the two components vote: the translations their pairs ask for within 3 sigma of the tie's
are pooled when they agree (RANSAC, the placement's gate and minimum inliers) and refine the move; when
they agree on a translation elsewhere and outnumber the ones near the tie, the tie is not used.
"""

from __future__ import annotations

import numpy as np

from rmbuild.config.optimize import PlacementConfig
from rmbuild.slam.evidence.base import Links, RotationPriors, Ties
from rmbuild.slam.placement.model import GrowState
from rmbuild.slam.problem import WalkSet

# a tie's translation may be refined by links that agree within this many of its sigmas
REFINE_SIGMAS = 3.0


def link_components(st: GrowState, walks: WalkSet, ties: Ties, links: Links, rot: RotationPriors,
                    cfg: PlacementConfig, log: list) -> tuple[GrowState, int]:
    """Join components along ``ties`` (module docstring); returns (state, ties used). Components whose
    walks have no trusted compass are not joined (their rotation is unknown)."""
    st = st.copy()
    wo = walks.walk_of
    oriented = _oriented_components(st, rot)
    size = walks.walk_lengths()
    used = 0
    for i in np.argsort(ties.sigma_m, kind="stable"):
        a, b, sig = int(ties.node_a[i]), int(ties.node_b[i]), float(ties.sigma_m[i])
        ca, cb = int(st.comp[wo[a]]), int(st.comp[wo[b]])
        if ca == cb or not (oriented[ca] and oriented[cb]):
            continue
        delta = walks.world_xy(st.T, np.array([a]))[0] - walks.world_xy(st.T, np.array([b]))[0]
        move, stay = (ca, cb) if _moves(ca, cb, st, size) else (cb, ca)
        if move == ca:
            delta = -delta
        tie_delta = delta.copy()
        delta, verdict = _vote(st, walks, links, move, stay, delta, sig, cfg)
        log.append({"phase": "continuity", "component": move, "onto": stay, "sigma_m": sig,
                    "accepted": verdict != "contradicted", "verdict": verdict, "node_a": a, "node_b": b,
                    "walks": int((st.comp == move).sum()), "tie": tie_delta.tolist(), "T": delta.tolist(),
                    "members": np.flatnonzero(st.comp == move).tolist()})
        if verdict == "contradicted":
            continue
        members = st.comp == move
        st.T[members, :2] += delta
        st.method[members] = "continuity"
        st.order[members] = st.tick()
        st.comp[members] = stay
        used += 1
    _, st.comp = np.unique(np.where(st.comp == st.comp[st.reference], -1, st.comp), return_inverse=True)
    return st, used


def _oriented_components(st: GrowState, rot: RotationPriors) -> np.ndarray:
    """Per component id: it has a walk with a trusted compass (so it was turned to the compass)."""
    n = int(st.comp.max()) + 1
    out = np.zeros(n, bool)
    has = st.heading_used & rot.known
    out[np.unique(st.comp[has])] = True
    return out if rot.known[st.reference] else np.zeros(n, bool)


def _moves(ca: int, cb: int, st: GrowState, size: np.ndarray) -> bool:
    """Whether component ca (rather than cb) is the one to move."""
    ref = int(st.comp[st.reference])
    if ca == ref or cb == ref:
        return cb == ref
    return size[st.comp == ca].sum() <= size[st.comp == cb].sum()


def _vote(st: GrowState, walks: WalkSet, links: Links, move: int, stay: int, delta: np.ndarray, sigma: float,
          cfg: PlacementConfig) -> tuple[np.ndarray, str]:
    """(translation, verdict): "tie" (no links agree or disagree), "refined" (links within REFINE_SIGMAS
    agree, their inlier mean is used), "contradicted" (links agree on a translation elsewhere)."""
    wo = walks.walk_of
    ck, cq = st.comp[wo[links.node_k]], st.comp[wo[links.node_q]]
    m = ((ck == move) & (cq == stay)) | ((ck == stay) & (cq == move))
    if m.sum() < cfg.min_inliers:
        return delta, "tie"
    k, q = links.node_k[m], links.node_q[m]
    mover = np.where(ck[m] == move, k, q)
    other = np.where(ck[m] == move, q, k)
    t = walks.world_xy(st.T, other) - walks.world_xy(st.T, mover)  # per link: the move it asks for
    close = np.linalg.norm(t[:, None] - t[None], axis=2) < cfg.gate_m
    votes = close.sum(axis=1)
    best = int(np.argmax(votes))
    near_tie = np.linalg.norm(t - delta, axis=1) < REFINE_SIGMAS * sigma
    local = np.flatnonzero(near_tie)
    if len(local) and votes[local].max() >= cfg.min_inliers:
        h = local[int(np.argmax(votes[local]))]
        return t[close[h]].mean(axis=0), "refined"
    if votes[best] >= cfg.min_inliers and not near_tie[best]:
        return delta, "contradicted"
    return delta, "tie"

