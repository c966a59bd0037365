"""Which floor each scan was taken on: RSS distance to every floor's fingerprints, filtered along the walk.

Per scan and floor, the distance is the mean of the :data:`K_NEAREST` smallest Euclidean RSS distances to
that floor's reference fingerprints, over the building's APs with an AP not heard standing at
:data:`FILL_DBM` (the "fill" convention of the kNN localizer). An AP of another floor heard by the scan, or
a strong AP of this floor it misses, counts against the floor. Along a walk, a hidden Markov
model with one state per floor turns the distances into a floor: emission ``exp(-(d_f - min_f d) / TAU_DB)``,
a floor change between two scans with probability :data:`P_CHANGE`; the forward (causal) filter's most probable floor is
the answer, as a live localizer would give it.
"""

from __future__ import annotations

import numpy as np

#: dBm standing for an AP not heard (the kNN localizer's default fill; UJIIndoorLoc's +100 "not heard")
FILL_DBM = -110.0
#: reference fingerprints averaged per floor (the kNN localizer's default K)
K_NEAREST = 3
#: dB: distance gap turning into a likelihood ratio of e. 5, 10, 20 dB measured (docs/notes/floors.md): the same on
#: the ILC sites; on synthetic buildings 10 beats 5 (e.g. 96.3 vs 95.4 % at 10 dB floor attenuation) and
#: 20 more so, but 20 is slower to follow a floor change (90 % of changes within 2 scans, vs 1 at 10)
TAU_DB = 10.0
#: probability that the floor changes between two scans of a walk (scans ~2-4 s apart; a floor change
#: takes stairs or a lift, a few per walk at most)
P_CHANGE = 0.01
#: query rows per block of the distance matrix (bounds memory: block x references float32)
_BLOCK_ROWS = 256


def floor_distances(refs: list[np.ndarray], query: np.ndarray) -> np.ndarray:
    """(n_query, n_floors) mean distance (dB) to each floor's ``K_NEAREST`` nearest references.

    ``refs[f]``: float (n_ref_f, n_ap) RSS in dBm, NaN not heard, columns in the order of ``query``'s
    (n_query, n_ap). A floor without references is infinitely far."""
    a_q = _offset(query)
    sq_q = (a_q.astype(np.float64) ** 2).sum(axis=1)
    out = np.full((len(query), len(refs)), np.inf)
    for f, ref in enumerate(refs):
        if len(ref) == 0:
            continue
        cols = np.flatnonzero((~np.isnan(ref)).any(axis=0))
        a_r = _offset(ref[:, cols])
        sq_r = (a_r.astype(np.float64) ** 2).sum(axis=1)
        k = min(K_NEAREST, len(ref))
        for s in range(0, len(query), _BLOCK_ROWS):
            blk = a_q[s:s + _BLOCK_ROWS][:, cols]
            d2 = sq_q[s:s + _BLOCK_ROWS, None] + sq_r[None, :] - 2.0 * (blk @ a_r.T).astype(np.float64)
            d = np.sqrt(np.maximum(d2, 0.0))
            out[s:s + _BLOCK_ROWS, f] = np.partition(d, k - 1, axis=1)[:, :k].mean(axis=1)
    return out


def _offset(rss: np.ndarray) -> np.ndarray:
    return np.where(np.isnan(rss), 0.0, rss - FILL_DBM).astype(np.float32)


def filter_floors(dist: np.ndarray, walk_id: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """(n_query, n_floors) forward-filtered floor probabilities, walk by walk in time order."""
    n, nf = dist.shape
    post = np.zeros((n, nf))
    if nf == 1:
        post[:] = 1.0
        return post
    trans = np.full((nf, nf), P_CHANGE / (nf - 1))
    np.fill_diagonal(trans, 1.0 - P_CHANGE)
    wid = np.asarray(walk_id).astype(str)
    for w in dict.fromkeys(wid):
        rows = np.flatnonzero(wid == w)
        rows = rows[np.argsort(t_s[rows], kind="stable")]
        belief = np.full(nf, 1.0 / nf)
        for r in rows:
            d = dist[r]
            emit = np.exp(-(d - d[np.isfinite(d)].min()) / TAU_DB) if np.isfinite(d).any() else np.ones(nf)
            belief = emit * (trans.T @ belief)
            belief /= belief.sum() if belief.sum() > 0 else 1.0
            post[r] = belief
    return post


def classify_floors(refs: list[np.ndarray], query: np.ndarray, walk_id: np.ndarray,
                    t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(floor index per scan after filtering, floor index per scan alone) for ``query`` (see
    :func:`floor_distances`); scans are grouped into walks by ``walk_id`` and ordered by ``t_s``."""
    dist = floor_distances(refs, query)
    alone = np.argmin(dist, axis=1)
    return np.argmax(filter_floors(dist, walk_id, np.asarray(t_s, dtype=float)), axis=1), alone
