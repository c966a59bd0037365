"""The RF check of a placement: does the walk, where a fit puts it, look like the map it lands on?

A fit is proposed by the scans or links that agree with it (its inliers). A walk put in the wrong place by a
handful of look-alike scans shows itself in everything else it overlaps: where the fit lays it over placed
scans, the radio differs. For each of the walk's scans with placed scans within the RF model's near
distance (:data:`rmbuild.slam.rfmodel.NEAR_M`) under the fit, the median over those neighbours of the RF
model's log likelihood ratio (near vs far) says whether the overlap looks near; the check is the mean of
these over the overlapping scans. Calibrated per data set by the RF model, it means the same in every venue.
A phone with another gain looks far from everything; each walk's distances are reduced first by how much
further its best matches in other walks are than the median walk's.

:func:`refute` applies it to the solved poses: each linked walk against the walks of the reference component
placed before it (the map it was fitted to; walks placed in one round, merge or tie count as one), so that a
group of walks placed wrong together, or onto each other, does not vouch for itself; a walk the overlap
contradicts is left unlinked (out of the map) rather than kept at a wrong place.
(Applied to the placement before the solve it also refuted walks the solve puts right; applied inside growth,
refusing each fit as it is made, it changed which walks seed the later merges and cost MS ILC site1/F2 23
linked walks; docs/notes/optimize.md.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rmbuild.slam.pairs import BLOCK_ELEMS
from rmbuild.slam.problem import WalkSet
from rmbuild.slam.rfmodel import NEAR_M


@dataclass
class OverlapEvidence:
    """What a fit's overlap with the placed map says: scans of the walk with placed scans within NEAR_M, and
    the mean over them of the median log LR of their RSS distances to those neighbours (NaN if none)."""

    n_overlap: int
    mean_log_lr: float


# a linked walk whose overlap with the rest of its component has a mean log LR below this is refuted (left
# unlinked); a walk overlapping fewer than MIN_OVERLAP_SCANS scans is not judged. Chosen on five MS ILC floors
# and IPIN 2023 -2 (docs/notes/optimize.md, "RF check"): refuted walks there had 1.3-2.2x the others' error.
MIN_OVERLAP_LOG_LR = -0.5
MIN_OVERLAP_SCANS = 5
# share of the reference component's walks the check may refute at most (a safeguard: when most of a map
# looks inconsistent the RF model, not the placement, is the likelier fault)
MAX_REFUTED_SHARE = 0.5
# entries (rows x all rows) per block of the phone-offset pass: its float64 temporaries stay ~100 MB
OFFSET_BLOCK_ELEMS = BLOCK_ELEMS // 4
# fingerprint rows; from this many on (a venue-month) the offset pass computes each pair of rows once (the
# upper triangle of the symmetric distance matrix; the float32 products then differ by ~1e-6 dB in blocking)
SYMMETRIC_MIN_ROWS = 20_000
# fingerprint rows; from this many on (a venue-month, walked over many times) the check samples: each walk's
# offset from at most OFFSET_SAMPLE_ROWS of its scans against every k-th scan of the data set (at most
# OFFSET_MAX_COLUMNS: a venue's worth of others), and each scan's overlap from at most OVERLAP_MAX_NEIGHBOURS
# of its placed neighbours within NEAR_M, evenly spread over them, whose RSS distances are computed once
# (per pair, not for the walk's rows x all its neighbours) and kept while walks are refuted
SAMPLED_MIN_ROWS = 25_000
OFFSET_SAMPLE_ROWS = 16
OFFSET_MAX_COLUMNS = 20_000
OVERLAP_MAX_NEIGHBOURS = 32


def refute(placement, walks: WalkSet, sim, row_xy: np.ndarray | None = None,
           typical_match_db: float | None = None) -> list[int]:
    """Walks of the reference component whose placement the RF check contradicts, worst first: each is moved
    into a component of its own (unlinked, kept where it is) and the rest judged again without it, as walks
    placed onto a wrong one agree with it. Each walk is judged against the walks placed before it
    (``placement.order``; all the others when the placement has no order).
    Returns them in that order. The reference walk is kept. ``row_xy``: each fingerprint row's position
    (default: where the placement puts it). Each judged walk's last figure goes to ``placement.rf_overlap_scans``
    / ``placement.rf_log_lr`` (a refuted walk's: the one that refuted it; NaN for walks not judged).
    An incremental run's held walks (``placement.fixed``) are not judged; with ``typical_match_db`` (the held
    map's typical walk, :attr:`OverlapCheck.typical_db`) their phone offsets are not computed either. The
    typical walk's figure goes to ``placement.rf_typical_match_db``."""
    fixed = placement.fixed
    check = OverlapCheck(walks, sim, ~fixed if fixed is not None and typical_match_db is not None else None,
                         typical_match_db)
    placement.rf_typical_match_db = check.typical_db
    comp = placement.component
    xy = walks.world_xy(placement.world_T_walk, sim.row_node) if row_xy is None else row_xy
    tree = cKDTree(xy)  # every row; the positions stay while walks are refuted, only the map's walks change
    out: list[int] = []
    most = MAX_REFUTED_SHARE * max(int(((comp == 0) & walks.keep).sum()), 1)
    placement.rf_overlap_scans = np.zeros(walks.n_walks, np.int64)
    placement.rf_log_lr = np.full(walks.n_walks, np.nan)
    stale = np.ones(walks.n_walks, bool)  # walks whose figure must be (re)computed
    overlapped_by: list[set[int]] = [set() for _ in range(walks.n_walks)]  # walk -> the judged walks overlapping it
    while len(out) < most:
        in_map = comp[check.row_walk] == 0
        judge = (comp == 0) & walks.keep
        judge[placement.reference] = False
        if placement.fixed is not None:  # an incremental run's held map is not judged again
            judge &= ~placement.fixed
        for w in (int(v) for v in np.flatnonzero(judge & stale)):  # only a refuted walk changes a figure
            ev, seen = check.evidence(w, xy, tree, in_map, placement.order)
            placement.rf_overlap_scans[w], placement.rf_log_lr[w] = ev.n_overlap, ev.mean_log_lr
            for v in seen.tolist():
                overlapped_by[v].add(w)
        stale[:] = False
        llr = np.where(judge & (placement.rf_overlap_scans >= MIN_OVERLAP_SCANS), placement.rf_log_lr, np.nan)
        bad = np.flatnonzero(llr < MIN_OVERLAP_LOG_LR)
        if not len(bad):
            break
        worst = int(bad[np.argmin(llr[bad])])  # the lowest figure; of equal ones the first walk
        comp[worst] = int(comp.max()) + 1
        placement.method[worst] = "refuted"
        out.append(worst)
        stale[list(overlapped_by[worst])] = True
    return out


class OverlapCheck:
    """The RF check of fits against the placed scans (module docstring)."""

    def __init__(self, walks: WalkSet, sim, only: np.ndarray | None = None, typical_db: float | None = None):
        """``only`` (n_walks,): the walks whose phone offsets are needed (default all), measured against
        ``typical_db`` (default: the median over them)."""
        self.walks, self.sim = walks, sim
        self.only, self.typical_db = only, typical_db
        self.row_walk = walks.walk_of[sim.row_node]
        self.rows_of = [np.flatnonzero(self.row_walk == w) for w in range(walks.n_walks)]
        self.sampled = len(self.row_walk) >= SAMPLED_MIN_ROWS
        self._pairs: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # sampled: walk -> its pairs
        self.offset_db = self._walk_offsets()

    def _walk_offsets(self) -> np.ndarray:
        """Per walk, how much further (dB) its scans' best matches in other walks are than the data set's
        typical walk's: a phone with another gain looks far from everything, wherever it is placed."""
        best = np.full(self.walks.n_walks, np.nan)
        rows_of = self.rows_of
        if self.only is not None:  # an incremental run: only the walks to judge
            rows_of = [rw if self.only[w] else rw[:0] for w, rw in enumerate(rows_of)]
        if self.sampled:
            rows_of = [rw[np.unique(np.linspace(0, len(rw) - 1, OFFSET_SAMPLE_ROWS).astype(np.int64))] if len(rw)
                       else rw for rw in rows_of]
            dmin = np.full(len(self.row_walk), np.inf)
            rows = np.concatenate(rows_of)
            dmin[rows] = self._sampled_match(rows)
        else:
            dmin = self._best_other_walk_match() if self.only is None else np.full(len(self.row_walk), np.inf)
            if self.only is not None and any(len(rw) for rw in rows_of):
                rows = np.concatenate(rows_of)
                dmin[rows] = self._match_of(rows)
        for w, rw in enumerate(rows_of):
            if len(rw) and (self.row_walk != w).any():
                best[w] = float(np.median(dmin[rw])) if np.isfinite(dmin[rw]).any() else np.nan
        if self.typical_db is None:
            self.typical_db = float(np.nanmedian(best)) if np.isfinite(best).any() else None
        off = best - self.typical_db if self.typical_db is not None else best
        return np.where(np.isfinite(off), np.maximum(off, 0.0), 0.0)

    def _best_other_walk_match(self) -> np.ndarray:
        """Per fingerprint row, the RSS distance (dB) of its most similar row of another walk (sharing
        ``min_common`` APs; inf if none), in blocks of rows against all rows at once."""
        n = len(self.row_walk)
        out = np.full(n, np.inf)
        step = max(1, OFFSET_BLOCK_ELEMS // max(n, 1))
        sym = n >= SYMMETRIC_MIN_ROWS
        for lo in range(0, n, step):
            rows = np.arange(lo, min(lo + step, n))
            cols = slice(lo, None) if sym else slice(None)
            d = self._other_walk_distances(rows, cols)
            out[rows] = np.minimum(out[rows], d.min(axis=1))
            if sym:  # eq. 9 is symmetric: the block's columns take their minimum over its rows too
                out[lo:] = np.minimum(out[lo:], d.min(axis=0))
        return out

    def _match_of(self, rows: np.ndarray) -> np.ndarray:
        """For ``rows``, the RSS distance (dB) of their most similar row of another walk (inf if none)."""
        step = max(1, OFFSET_BLOCK_ELEMS // max(len(self.row_walk), 1))
        return np.concatenate([self._other_walk_distances(rows[lo:lo + step], slice(None)).min(axis=1)
                               for lo in range(0, len(rows), step)])

    def _sampled_match(self, rows: np.ndarray) -> np.ndarray:
        """For ``rows``, the RSS distance (dB) of the most similar of every k-th row (OFFSET_MAX_COLUMNS at most)
        of another walk sharing ``min_common`` APs (inf if none)."""
        n = len(self.row_walk)
        cols = np.arange(0, n, -(-n // OFFSET_MAX_COLUMNS))
        out = np.full(len(rows), np.inf)
        step = max(1, OFFSET_BLOCK_ELEMS // len(cols))
        for lo in range(0, len(rows), step):
            out[lo:lo + step] = self._other_walk_distances(rows[lo:lo + step], cols).min(axis=1)
        return out

    def _other_walk_distances(self, rows: np.ndarray, cols) -> np.ndarray:
        """RSS distances (dB) of ``rows`` x ``cols`` (indices or a slice), inf where the two rows are of one
        walk or share fewer than ``min_common`` APs."""
        d, common = self.sim.rss.block(rows, cols)
        ok = (common >= self.sim.min_common) & (self.row_walk[rows][:, None] != self.row_walk[None, cols])
        return np.where(ok, d, np.inf)

    def _map_rows(self, w: int, in_map: np.ndarray, order: np.ndarray | None) -> np.ndarray:
        """Bool over rows: the scans walk ``w`` is judged against — other walks' in the map, placed before it
        (``order``; None: all)."""
        ok_row = in_map & (self.row_walk != w)
        if order is not None:  # the map the walk was placed onto, not walks placed onto it
            ok_row &= order[self.row_walk] < order[w]
        return ok_row

    def evidence(self, w: int, xy: np.ndarray, tree: cKDTree, in_map: np.ndarray,
                 order: np.ndarray | None) -> tuple[OverlapEvidence, np.ndarray]:
        """Walk ``w``'s scans against the scans of the other walks in the map (``in_map``, bool over rows)
        placed before it (``order``, None: all), every row at ``xy`` (``tree`` over them); and the walks whose
        scans it overlapped."""
        rw = self.rows_of[w]
        none = (OverlapEvidence(0, float("nan")), np.zeros(0, np.int64))
        if not len(rw):
            return none
        if self.sampled:
            return self._sampled_evidence(w, xy, tree, in_map, order)
        ok_row = self._map_rows(w, in_map, order)
        hits = [h[ok_row[h]] for h in (np.asarray(h, np.int64) for h in tree.query_ball_point(xy[rw], NEAR_M))]
        has = np.array([len(h) > 0 for h in hits])
        if not has.any():
            return none
        cols = np.unique(np.concatenate([hits[i] for i in np.flatnonzero(has)]))
        near = np.linalg.norm(xy[rw[has]][:, None, :] - xy[cols][None, :, :], axis=2) < NEAR_M
        d, common = self.sim.rss.block(rw[has], cols)
        ok = near & (common >= self.sim.min_common)
        llr = np.where(ok, self.sim.rf.log_lr(np.where(ok, d - self.offset_db[w], 0.0)), np.nan)
        seen = ok.any(axis=1)
        if not seen.any():
            return none
        per_scan = np.nanmedian(llr[seen], axis=1)
        return OverlapEvidence(int(seen.sum()), float(np.mean(per_scan))), np.unique(self.row_walk[cols])

    def _sampled_evidence(self, w: int, xy: np.ndarray, tree: cKDTree, in_map: np.ndarray,
                          order: np.ndarray | None) -> tuple[OverlapEvidence, np.ndarray]:
        """:meth:`evidence` from up to OVERLAP_MAX_NEIGHBOURS neighbours per scan (their log LRs computed at the
        walk's first judgement; later ones drop the neighbours no longer in the map)."""
        if w not in self._pairs:
            self._pairs[w] = self._neighbour_pairs(w, xy, tree, in_map, order)
        row, col, llr = self._pairs[w]
        keep = in_map[col]
        row, col, llr = row[keep], col[keep], llr[keep]
        if not len(row):
            return OverlapEvidence(0, float("nan")), np.zeros(0, np.int64)
        o = np.lexsort((llr, row))  # each scan's log LRs ascending, scans in order: the medians by position
        row, llr = row[o], llr[o]
        start = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
        cnt = np.diff(np.r_[start, len(row)])
        med = 0.5 * (llr[start + (cnt - 1) // 2] + llr[start + cnt // 2])
        return OverlapEvidence(len(start), float(np.mean(med))), np.unique(self.row_walk[col])

    def _neighbour_pairs(self, w: int, xy: np.ndarray, tree: cKDTree, in_map: np.ndarray,
                         order: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, log LR) of walk ``w``'s scans and up to OVERLAP_MAX_NEIGHBOURS of their neighbours each
        (evenly spread over those within NEAR_M that share ``min_common`` APs)."""
        rw = self.rows_of[w]
        ok_row = self._map_rows(w, in_map, order)
        hits = tree.query_ball_point(xy[rw], NEAR_M)  # each scan's neighbours, ascending
        counts = np.fromiter((len(h) for h in hits), np.int64, len(hits))
        row = np.repeat(rw, counts)
        col = np.concatenate([np.asarray(h, np.int64) for h in hits]) if len(hits) else np.zeros(0, np.int64)
        keep = ok_row[col]
        row, col = row[keep], col[keep]
        keep = np.linalg.norm(xy[col] - xy[row], axis=1) < NEAR_M
        row, col = row[keep], col[keep]
        some = _spread(row, OVERLAP_MAX_NEIGHBOURS)
        row, col = row[some], col[some]
        d, common = self.sim.rss.pairs(row, col)
        ok = common >= self.sim.min_common
        row, col = row[ok], col[ok]
        return row, col, self.sim.rf.log_lr(d[ok] - self.offset_db[w])


def _spread(group: np.ndarray, most: int) -> np.ndarray:
    """Indices into ``group`` (runs of equal values, each run's entries in the order to keep) keeping at most
    ``most`` entries per run, evenly spread over it: the run's entries at ``np.linspace(0, len - 1, most)``
    (truncated) when it is longer."""
    start = np.flatnonzero(np.r_[True, group[1:] != group[:-1]]) if len(group) else np.zeros(0, np.int64)
    size = np.diff(np.r_[start, len(group)])
    short = size <= most
    keep = [np.arange(len(group))[np.repeat(short, size)]]
    long_start, long_size = start[~short], size[~short]
    if len(long_start):  # linspace's own arithmetic: i * ((n - 1) / (most - 1)), the last entry n - 1
        pos = np.zeros((len(long_start), most))
        if most > 1:
            pos = np.arange(most)[None, :] * ((long_size - 1) / (most - 1))[:, None]
            pos[:, -1] = long_size - 1
        keep.append((long_start[:, None] + pos.astype(np.int64)).ravel())
    return np.sort(np.concatenate(keep))
