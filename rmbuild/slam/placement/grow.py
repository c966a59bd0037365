"""Growth: walks placed round by round against the map placed so far.

Short crowdsourced walks mostly just cross each other: a pair of walks rarely shares enough path to be
verified on its own. Fitting a walk to the *map built so far* pools the evidence of every placed walk it
meets. From a seed walk, each round fits every unplaced walk to the placed map (:mod:`.fits`), places all
that are accepted, refines the placed walks jointly (:mod:`.refine`) and distrusts the compass of a walk
whose refined rotation disagrees with it; rounds stop when no walk is added, and the next seed (the
unplaced walk with the most links) grows a further component. Two kinds of evidence drive it:
:class:`PairEvidence` (the sources' links; walk-pair edges as a fallback when a round places nothing)
and :class:`ScanEvidence` (each scan localised by its nearest placed scans; long walks fitted on windows).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from functools import partial

import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import PlacementConfig
from rmbuild.slam.evidence.base import RotationPriors
from rmbuild.slam.pairs import BLOCK_ELEMS
from rmbuild.slam.placement.edges import RANSAC_SEED
from rmbuild.slam.placement.fits import accept_pairs_fit, accept_scans_fit, fit_to_pairs, fit_to_scans
from rmbuild.slam.placement.model import GrowState, WalkFit
from rmbuild.slam.placement.refine import refine_placed
from rmbuild.slam.problem import WalkSet

# rounds of placement per component at most
MAX_ROUNDS = 100
# kNN placement: nearest placed scans kept per unplaced scan
KNN_K = 3
# rows per block of the kNN distance products
KNN_BLOCK_ROWS = 2048
# the kNN merge's float32 screen keeps an entry whose squared distance may be within (1 + SCREEN_REL) times
# the bound squared plus SCREEN_ABS_DB2 (dB²) of it: float32 rounding of its terms (~1e5 dB²) is ~0.05 dB²
SCREEN_REL = 1e-3
SCREEN_ABS_DB2 = 1.0
# sigmas; a placed walk whose refined rotation is further than this from its compass rotation has an
# unreliable compass: its heading priors are dropped
HEADING_OUTLIER_SIGMAS = 4.0
# rad; a walk with a compass whose compass-rotation fit failed is placed by an SE(2) fit only when the fitted
# rotation lies this close to its compass: further off, the two contradict each other and the walk waits
# (docs/notes/optimize.md: IPIN -2 linked-walk error 9.5 -> 5.6 m, ILC F1 kNN 1.72 -> 1.64x; 20-30 deg alike)
SE2_MAX_COMPASS_DEV_RAD = np.radians(30.0)


def window_lengths(walks: WalkSet, cfg: PlacementConfig) -> np.ndarray:
    """Walked length (m) of each walk, capped at the fit window (the length a rigid fit covers) when set."""
    wl = walks.walk_lengths()
    return np.minimum(wl, cfg.window_m) if cfg.window_m > 0 else wl


def compass_priors(rot: RotationPriors, seed: int) -> np.ndarray:
    """Each walk's compass rotation relative to the seed walk's (NaN where unknown, all NaN without one)."""
    if not rot.known[seed]:
        return np.full(len(rot.theta), np.nan)
    return np.where(rot.known, geometry.wrap(rot.theta - rot.theta[seed]), np.nan)


def leftovers(st: GrowState, rot: RotationPriors, c_id: int) -> None:
    """Walks never placed: a component each, turned by the compass relative to the reference when known."""
    ref = st.reference
    for w in np.flatnonzero(st.comp < 0):
        st.comp[w] = c_id
        c_id += 1
        if rot.known[ref] and rot.known[w]:
            st.T[w, 2] = geometry.wrap(rot.theta[w] - rot.theta[ref])


def _distrust_outliers(st: GrowState, placed: np.ndarray, prior: np.ndarray, sig: np.ndarray) -> None:
    off = np.abs(geometry.wrap(st.T[:, 2] - prior)) > HEADING_OUTLIER_SIGMAS * sig
    st.heading_used &= ~(placed & np.isfinite(prior) & off)


def _within(rss, rows: np.ndarray, cols: np.ndarray, dot: np.ndarray, common: np.ndarray, bound: np.ndarray,
            min_common: int) -> tuple[np.ndarray, np.ndarray]:
    """Entries (i, j) of the rows x cols block with ``min_common`` shared APs whose eq. 9 distance may be at
    most ``bound[i]``: a float32 screen of sq_r + sq_c - 2 dot <= bound² union, loose by SCREEN_REL and
    SCREEN_ABS_DB2 (far more than float32 rounding), so that every entry within the bound is kept."""
    lim = np.add.outer(rss.cnt[rows].astype(np.float32), rss.cnt[cols].astype(np.float32))
    lim -= common
    np.maximum(lim, 1, out=lim)
    lim *= (np.square(bound, dtype=np.float32) * np.float32(1 + SCREEN_REL))[:, None]
    lim += np.float32(SCREEN_ABS_DB2)
    lim += dot
    lim += dot
    lim -= rss.sq[rows].astype(np.float32)[:, None]
    ok = lim >= rss.sq[cols].astype(np.float32)[None, :]
    del lim
    ok &= common >= min_common
    i, j = np.nonzero(ok)
    return i, j


def _keep_nearest(best_d: np.ndarray, best_c: np.ndarray, rows: np.ndarray, i: np.ndarray, c: np.ndarray,
                  d: np.ndarray) -> None:
    """Merge candidates (row ``rows[i]``, column ``c``, distance ``d``) into each row's KNN_K nearest (in
    place), kept in order of distance (then column)."""
    k = best_d.shape[1]
    rr = np.r_[np.repeat(np.arange(len(rows)), k), i]
    dd = np.r_[best_d[rows].ravel(), d]
    cc = np.r_[best_c[rows].ravel(), c]
    o = np.lexsort((cc, dd, rr))
    rank = np.arange(len(o)) - np.searchsorted(rr[o], rr[o])
    top = o[rank < k]
    best_d[rows] = dd[top].reshape(-1, k)
    best_c[rows] = cc[top].reshape(-1, k)


Fit = Callable[[float | None], WalkFit | None]
Accept = Callable[[WalkFit | None, bool], bool]


def _fit_both(fit: Fit, accept: Accept, prior_w: float) -> tuple[WalkFit | None, bool]:
    """Translation fit with the compass rotation, else (or when it fails) an SE(2) fit — with a compass, only
    one whose rotation agrees with it (SE2_MAX_COMPASS_DEV_RAD)."""
    f, ok = None, False
    if np.isfinite(prior_w):
        f = fit(float(prior_w))
        ok = accept(f, False)
    if not ok:
        f2 = fit(None)
        if accept(f2, True) and (not np.isfinite(prior_w) or f2 is None
                                 or abs(geometry.wrap(f2.t[2] - prior_w)) <= SE2_MAX_COMPASS_DEV_RAD):
            f, ok = f2, True
    return f, ok


def _log(log: list, c_id: int, r: int, w: int, ok: bool, f: WalkFit | None, n: int, phase: str) -> None:
    log.append({"phase": phase, "component": c_id, "round": r, "walk": int(w), "accepted": bool(ok),
                "score": f.score if f else 0, "second": f.second if f else 0, "shared_m": f.shared_m if f else 0.0,
                "method": f.method if f else "", "pairs": n, "T": None if f is None else f.t.tolist()})


class GrowthEvidence(ABC):
    """What one kind of placement evidence does inside :func:`grow` (module docstring)."""

    @abstractmethod
    def start_component(self, st: GrowState, seed: int, c_id: int) -> np.ndarray:
        """Seed component ``c_id``; returns its placed walks (bool, n_walks)."""

    @abstractmethod
    def round(self, st: GrowState, placed: np.ndarray, free: np.ndarray, prior: np.ndarray, c_id: int, r: int,
              log: list) -> list[tuple[int, WalkFit]]:
        """The accepted placements of round ``r``: (walk, fit)."""

    @abstractmethod
    def placed(self, st: GrowState, w: int, f: WalkFit, prior: np.ndarray, rot: RotationPriors) -> None:
        """Bookkeeping after walk ``w`` was placed by ``f`` (its compass trust, its links)."""

    @abstractmethod
    def refine_links(self) -> tuple[np.ndarray, np.ndarray]:
        """The links the placed walks are refined on."""


def grow(st: GrowState, ev: GrowthEvidence, walks: WalkSet, rot: RotationPriors, cfg: PlacementConfig,
         cand_count: np.ndarray, log: list) -> GrowState:
    """The placement loop: components grown round by round from seeds, then the walks left over."""
    wlen = window_lengths(walks, cfg)
    seed: int | None = st.reference
    c_id = 0
    while seed is not None:
        prior = compass_priors(rot, seed)
        placed = ev.start_component(st, seed, c_id)
        for r in range(1, MAX_ROUNDS + 1):
            free = walks.keep & (st.comp < 0)
            new = ev.round(st, placed, free, prior, c_id, r, log)
            if not new:
                break
            st.tick()
            for w, f in new:
                st.place(w, f, c_id, r)
                placed[w] = True
                ev.placed(st, w, f, prior, rot)
            nk, nq = ev.refine_links()
            st.T = refine_placed(st.T, placed, nk, nq, walks, seed, prior, st.heading_used, rot.sigma, cfg.gate_m,
                                 wlen, st.fixed)
            _distrust_outliers(st, placed, prior, rot.sigma)
        c_id += 1
        free = walks.keep & (st.comp < 0)
        seed = int(np.argmax(np.where(free, cand_count, -1))) if free.any() else None
        if seed is not None and cand_count[seed] <= 0:
            seed = None
    leftovers(st, rot, c_id)
    return st


class PairEvidence(GrowthEvidence):
    """Links (node_k, node_q) and walk-pair edges [(a, b, A_T_B)]: a walk is fitted to its links to placed
    walks; when a round places nothing, an accepted walk-pair edge to a placed walk places it."""

    def __init__(self, walks: WalkSet, nk: np.ndarray, nq: np.ndarray, edges: list, cfg: PlacementConfig):
        self.walks, self.nk, self.nq, self.edges, self.cfg = walks, nk, nq, edges, cfg
        self.rng = np.random.default_rng(RANSAC_SEED)

    def start_component(self, st: GrowState, seed: int, c_id: int) -> np.ndarray:
        placed = st.comp == c_id  # an incremental run's held map is component 0 from the start
        if not placed.any():
            placed[seed] = True
            st.seed(seed, c_id)
        return placed

    def placed(self, st: GrowState, w: int, f: WalkFit, prior: np.ndarray, rot: RotationPriors) -> None:
        if f.method in ("se2", "pair") and np.isfinite(prior[w]):
            st.heading_used[w] = bool(abs(geometry.wrap(f.t[2] - prior[w])) < HEADING_OUTLIER_SIGMAS * rot.sigma[w])

    def refine_links(self) -> tuple[np.ndarray, np.ndarray]:
        return self.nk, self.nq

    def _fit(self, pm, pw, wnode, wpath, mwalk, rot: float | None) -> WalkFit | None:
        return fit_to_pairs(pm, pw, wnode, wpath, mwalk, rot, self.cfg, self.rng)

    def round(self, st, placed, free, prior, c_id, r, log) -> list:
        walks = self.walks
        wk, wq = walks.walk_of[self.nk], walks.walk_of[self.nq]
        m = (placed[wk] & free[wq]) | (placed[wq] & free[wk])
        if not m.any():
            return []
        rows = np.flatnonzero(m)
        mnode = np.where(placed[wk[rows]], self.nk[rows], self.nq[rows])
        wnode = np.where(placed[wk[rows]], self.nq[rows], self.nk[rows])
        pm = walks.world_xy(st.T, mnode)
        wof = walks.walk_of[wnode]
        order = np.argsort(wof, kind="stable")
        bounds = np.r_[0, np.flatnonzero(np.diff(wof[order])) + 1, len(order)]
        new = []
        for b0, b1 in zip(bounds[:-1], bounds[1:]):
            idx = order[b0:b1]
            w = int(wof[idx[0]])
            args = (pm[idx], walks.raw[wnode[idx], :2], wnode[idx], walks.path[wnode[idx]], walks.walk_of[mnode[idx]])
            f, ok = _fit_both(partial(self._fit, *args), partial(accept_pairs_fit, cfg=self.cfg), prior[w])
            if ok:
                new.append((w, f))
            _log(log, c_id, r, w, ok, f, len(idx), "pairs")
        if self.edges and not new:  # fallback when walk-to-map growth stalls
            for a, b, Tab in self.edges:
                for u, v, rel in ((a, b, Tab), (b, a, geometry.inverse(Tab))):
                    if placed[u] and free[v] and v not in {w for w, _ in new}:
                        t = geometry.compose(st.T[u], rel)
                        new.append((v, WalkFit(t, 0, 0, 0.0, 1, "pair", np.zeros(0, bool))))
        return new



class ScanEvidence(GrowthEvidence):
    """Each unplaced scan localised by its KNN_K nearest placed scans in RSS distance (updated as walks are
    placed). A scan is *covered* when a neighbour is closer than its own walk's window median (its
    similarity threshold); its map position is the mean of its covered neighbours' positions. A walk is
    fitted to its covered scans (long walks on half-overlapping windows of ``window_m``, the best accepted
    window placing it); the links of a placement are every inlier scan with each covered neighbour."""

    def __init__(self, walks: WalkSet, sim, cfg: PlacementConfig):
        self.walks, self.sim, self.cfg = walks, sim, cfg
        self.rng = np.random.default_rng(RANSAC_SEED)
        self.row_walk = walks.walk_of[sim.row_node]
        self.rows_of = [np.flatnonzero(self.row_walk == w) for w in range(walks.n_walks)]
        thr = sim.threshold
        self.thr = np.where(np.isfinite(thr), thr, np.nanmedian(thr) if np.isfinite(thr).any() else np.inf)
        self.link_k: list[np.ndarray] = []
        self.link_q: list[np.ndarray] = []

    def links(self) -> tuple[np.ndarray, np.ndarray]:
        lk = np.concatenate(self.link_k) if self.link_k else np.zeros(0, np.int64)
        lq = np.concatenate(self.link_q) if self.link_q else np.zeros(0, np.int64)
        return lk, lq

    def restart(self, st: GrowState, rot: RotationPriors) -> GrowState:
        """A state that keeps component 0 of ``st`` (the map to extend) and frees every other walk."""
        start = st.comp == 0
        st2 = GrowState.empty(self.walks.n_walks, st.reference, rot.known, st.fixed)
        for a in ("T", "rnd", "n_inl", "shared", "method", "heading_used", "order"):
            getattr(st2, a)[start] = getattr(st, a)[start]
        st2.epoch = st.epoch
        self._start = start
        return st2

    def start_component(self, st: GrowState, seed: int, c_id: int) -> np.ndarray:
        n_rows = len(self.row_walk)
        self.best_d = np.full((n_rows, KNN_K), np.inf, np.float32)
        self.best_c = np.full((n_rows, KNN_K), -1, np.int64)
        if c_id == 0:
            placed = self._start.copy()
            st.comp[placed] = 0
        else:
            placed = np.zeros(self.walks.n_walks, bool)
            st.seed(seed, c_id)
            placed[seed] = True
        self._new_walks: list[int] = np.flatnonzero(placed).tolist()
        return placed

    def placed(self, st: GrowState, w: int, f: WalkFit, prior: np.ndarray, rot: RotationPriors) -> None:
        self._new_walks.append(w)
        if f.method == "se2" and np.isfinite(prior[w]):
            st.heading_used[w] = False
        a, b = self._pending[w]
        self.link_k.append(a)
        self.link_q.append(b)

    def refine_links(self) -> tuple[np.ndarray, np.ndarray]:
        return self.links()

    def _fit(self, p_own, x_hat, path, rot: float | None) -> WalkFit | None:
        return fit_to_scans(p_own, x_hat, path, rot, self.cfg, self.rng)

    def _merge_neighbours(self, new_walks: list, free: np.ndarray) -> None:
        """Merge the newly placed walks' scans into every unplaced scan's KNN_K nearest within its threshold
        (only those are ever used: a neighbour further than the threshold does not cover the scan)."""
        new_rows = np.concatenate([self.rows_of[w] for w in new_walks]) if new_walks else np.zeros(0, np.int64)
        u_rows = np.flatnonzero(free[self.row_walk])
        if not (len(new_rows) and len(u_rows)):
            return
        # fewer rows per block against many new scans: a block's temporaries stay ~BLOCK_ELEMS entries
        step = max(16, min(KNN_BLOCK_ROWS, BLOCK_ELEMS // len(new_rows)))
        for b0 in range(0, len(u_rows), step):
            self._merge_block(u_rows[b0:b0 + step], new_rows)

    def _merge_block(self, ur: np.ndarray, new_rows: np.ndarray) -> None:
        """One block of :meth:`_merge_neighbours`: the float32 products of ``ur`` x ``new_rows``, eq. 9's
        float64 distance only for the entries a screen keeps (:func:`_within`), merged in distance order."""
        rss = self.sim.rss
        bound = np.minimum(self.thr[ur], self.best_d[ur, KNN_K - 1])
        dot, common = rss.products(ur, new_rows)
        i, j = _within(rss, ur, new_rows, dot, common, bound, self.sim.min_common)
        r, c = ur[i], new_rows[j]
        d = rss.distance(rss.cnt[r], rss.cnt[c], rss.sq[r], rss.sq[c], dot[i, j], common[i, j])
        del dot, common
        ok = d <= bound[i]
        _keep_nearest(self.best_d, self.best_c, ur, i[ok], c[ok], d[ok])

    def round(self, st, placed, free, prior, c_id, r, log) -> list:
        self._merge_neighbours(self._new_walks, free)
        self._new_walks = []
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        walks, row_node = self.walks, self.sim.row_node
        pos = np.full((len(self.row_walk), 2), np.nan)
        pr = np.flatnonzero(placed[self.row_walk])
        pos[pr] = walks.world_xy(st.T, row_node[pr])
        new = []
        for w in np.flatnonzero(free):
            rw = self.rows_of[w]
            if not len(rw):
                continue
            ok_nb = self.best_d[rw] < self.thr[rw][:, None]
            cov = ok_nb.any(axis=1)
            if cov.sum() < self.cfg.min_inliers:
                continue
            rwc, nbm = rw[cov], ok_nb[cov]
            P = pos[self.best_c[rwc]]  # (c, K, 2)
            x_hat = np.nansum(P * nbm[:, :, None], axis=1) / nbm.sum(axis=1)[:, None]
            f, ok = self._fit_windows(row_node[rwc], x_hat, prior[w])
            _log(log, c_id, r, int(w), ok, f, int(cov.sum()), "knn")
            if ok and f is not None and len(f.inliers) == len(rwc):
                inl_rows = rwc[f.inliers]
                kk_ = np.repeat(row_node[inl_rows], KNN_K)
                qq_ = self.best_c[inl_rows].ravel()
                good = nbm[f.inliers].ravel() & (qq_ >= 0)
                self._pending[int(w)] = (kk_[good], row_node[qq_[good]])
                new.append((int(w), f))
        return new

    def _fit_windows(self, nodes: np.ndarray, x_hat: np.ndarray, prior_w: float) -> tuple[WalkFit | None, bool]:
        """The best accepted fit over the walk's windows of ``window_m`` walked metres (or the whole walk)."""
        walks, cfg = self.walks, self.cfg
        pth = walks.path[nodes]
        win = cfg.window_m
        starts = np.arange(pth.min(), max(pth.max() - win, pth.min()) + win / 2, win / 2) if win > 0 else [0]
        f, ok = None, False
        for s0 in starts:
            sel = (pth >= s0) & (pth <= s0 + win) if win > 0 else np.ones(len(pth), bool)
            if sel.sum() < cfg.min_inliers:
                continue
            args = (walks.raw[nodes[sel], :2], x_hat[sel], pth[sel])
            fw, okw = _fit_both(partial(self._fit, *args), partial(accept_scans_fit, cfg=cfg), prior_w)
            if okw and fw is not None and (f is None or not ok or fw.score > f.score):
                full = np.zeros(len(pth), bool)
                full[np.flatnonzero(sel)[fw.inliers]] = True
                fw.inliers = full
                f, ok = fw, True
            elif f is None:
                f = fw
        return f, ok
