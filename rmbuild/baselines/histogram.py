"""Matching scans against RSS histograms, with and without the walking direction (the subway-station Wi-Fi
+ PDR paper, §III-B; the map layer is :mod:`rmbuild.radiomap.histogram`).

For a scan with RSSI ``s_i`` from AP i and an RP whose histogram of AP i has bin probabilities ``p``,
``Pr_i`` = the probability of the bin that holds ``s_i`` (the paper's ``|s − a_j| ≤ BW/2``). With
``smooth_db > 0`` (ours) every map reading is first spread over the neighbouring bins by a Gaussian.

``scoring = "mark"`` — the paper:

* **feature matching**: AP i is *matched* when ``Pr_i > 0``; an RP is a candidate when its matched APs are
  at least ``match_fraction`` (70 %) of the scan's APs; when no RP reaches that, the RPs with the most
  matched APs are the candidates.
* **probability mark**: ``Mark = D · Σ_i Pr_i R_i / n`` over the n matched APs, ``R_i`` = the AP's
  readings at the RP over the most any AP has there (the paper's probability of occurrence), ``D`` =
  ``direction_gain`` (1.2) when the RP's walking direction is the walker's, else 1.
* **selection**: the best-marked candidates whose marks add up to ``mark_share`` (5 %) of all
  candidates' marks (at least one), averaged weighted by mark. (The paper's selection formula is
  garbled in our copy; this is our reading of "k nearest neighbours with Σ Mark against 5 %".)

``scoring = "likelihood"`` — ours, the histogram as the density of a naive-Bayes likelihood:
``log L = Σ_i log(Pr_i, or floor_prob where the histogram has no mass) + log D``; the position is the
posterior-weighted mean of the ``k`` most probable RPs.

``hist`` matches against per-cell histograms (all directions together). ``hist_dir`` keeps every
(cell, walking-direction sector) apart as its own RP, as the paper keeps one database per direction, and
needs the walker's direction in the map frame: the PDR displacement since the previous scan, rotated by
the least-squares angle between the PDR and ``hist``'s own fixes over the last ``rotation_window_scans``
scans (causal; the paper's PDR heading was absolute). Without steps, or before three fixes, the direction
is unknown and every D is 1.

Scores are sparse matrix products: one column per (AP, bin), so a block of scans costs O(nnz).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy import sparse

from rmbuild.baselines.config import HistogramLocConfig
from rmbuild.baselines.smoothing import frame_rotation, pdr_positions, rotate
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, checked, sub_config
from rmbuild.radiomap.histogram import MIN_MOVE_M, direction_sector

_BLOCK = 256
#: σ; a smoothed histogram spreads each reading this far on either side (so "matched" means within it).
SMOOTH_REACH_SIGMAS = 2.0
#: fixes a walk needs in the rotation window before its PDR directions are trusted in the map frame.
MIN_FIXES_FOR_DIRECTION = 3


class HistogramLocalizer:
    """Probability-mark matching of single scans against per-cell RSS histograms."""

    name: ClassVar[str] = "hist"
    directional: ClassVar[bool] = False

    def __init__(self, cfg: HistogramLocConfig | None = None) -> None:
        self.cfg = checked(cfg, HistogramLocConfig)
        self.bssids: np.ndarray | None = None
        self.fallbacks: set[str] = set()

    @classmethod
    def from_config(cls, cfg) -> HistogramLocalizer:
        return cls(sub_config(cfg, "hist", HistogramLocConfig))

    # ------------------------------------------------------------------ fit
    def fit(self, radio_map) -> HistogramLocalizer:
        """Index the map's histogram layer (a RadioMap built by rmbuild; a bare ReferenceSet has none)."""
        layer = getattr(radio_map, "histograms", None)
        if layer is None or len(layer) == 0:
            raise InputError(f"{self.name}: the radio map has no RSS histograms (build it with rmbuild)")
        sector = layer.sector.astype(np.int64) if self.directional else np.full(len(layer), -1)
        rp_u, rp = np.unique(np.c_[layer.cell, sector], axis=0, return_inverse=True)
        rp = rp.reshape(-1)
        n_rp, n_ap = len(rp_u), len(radio_map.bssids)
        reach = self._reach(layer.bin_db)
        self._bin0 = int(layer.bin.min()) - reach
        self._n_bins = int(layer.bin.max()) - self._bin0 + 1 + reach
        # per (RP, AP): readings T and R = T / (the RP's largest T) — sparse, one value per entry
        _, pair = np.unique(rp * n_ap + layer.ap, return_inverse=True)
        pair = pair.reshape(-1)
        tot = np.bincount(pair, weights=layer.count)
        rp_max = np.zeros(n_rp)
        np.maximum.at(rp_max, rp, tot[pair])
        w = layer.count / tot[pair]  # Pr of each entry's bin
        if self.cfg.scoring == "mark":
            w = w * tot[pair] / rp_max[rp]  # Pr · R
        rp, ap, b, w = self._spread(rp, layer.ap.astype(np.int64), layer.bin.astype(np.int64), w, layer.bin_db)
        shape = (n_rp, n_ap * self._n_bins)
        v = sparse.csr_matrix((w, (rp, ap * self._n_bins + (b - self._bin0))), shape=shape).tocoo()
        v.sum_duplicates()  # spread neighbours of one (RP, AP) land in the same bins: add them
        if self.cfg.scoring == "mark":
            self._v = v.tocsr()
            self._o = sparse.csr_matrix((np.ones(v.nnz), (v.row, v.col)), shape=shape)
        else:  # log((Pr + ε) / ε): zero where the histogram is empty, so the product stays sparse
            eps = self.cfg.floor_prob
            self._v = sparse.csr_matrix((np.log((v.data + eps) / eps), (v.row, v.col)), shape=shape)
        self._xy = radio_map.cell_xy[rp_u[:, 0]]
        self.rp_sector = rp_u[:, 1]
        self.bin_db = layer.bin_db
        self.n_directions = layer.n_directions
        self.bssids = np.asarray(radio_map.bssids, dtype=object)
        return self

    def _reach(self, bin_db: float) -> int:
        """Bins a reading is spread over on either side (0 = the paper's plain histogram)."""
        return int(np.ceil(SMOOTH_REACH_SIGMAS * self.cfg.smooth_db / bin_db)) if self.cfg.smooth_db > 0 else 0

    def _spread(self, rp, ap, b, cnt, bin_db):
        """Histogram entries (``cnt`` per entry) with each entry's mass spread over the neighbouring bins by
        a Gaussian of σ = ``smooth_db`` cut at ±:data:`SMOOTH_REACH_SIGMAS` σ (its total stays the same)."""
        reach = self._reach(bin_db)
        if reach == 0:
            return rp, ap, b, cnt
        j = np.arange(-reach, reach + 1)
        k = np.exp(-0.5 * (j * bin_db / self.cfg.smooth_db) ** 2)
        k /= k.sum()
        rep = len(j)
        return (np.repeat(rp, rep), np.repeat(ap, rep), (b[:, None] + j[None, :]).ravel(),
                (cnt[:, None] * k[None, :]).ravel())

    @property
    def n_rp(self) -> int:
        return len(self._xy)

    # --------------------------------------------------------------- scores
    def _query_matrix(self, rss_dbm: np.ndarray) -> sparse.csr_matrix:
        """(n, n_ap·n_bins) indicator of each scan's (AP, bin) entries (bins outside the map's range dropped)."""
        r, a = np.nonzero(~np.isnan(rss_dbm))
        b = np.floor(rss_dbm[r, a].astype(float) / self.bin_db).astype(np.int64) - self._bin0
        ok = (b >= 0) & (b < self._n_bins)
        return sparse.csr_matrix((np.ones(int(ok.sum())), (r[ok], a[ok] * self._n_bins + b[ok])),
                                 shape=(len(rss_dbm), self._v.shape[1]))

    def marks(self, rss_dbm: np.ndarray, sector: np.ndarray | None = None) -> np.ndarray:
        """(n, n_rp) the paper's marks of scans in the map's AP order (0 = not a candidate); ``sector`` (n,)
        the walker's direction sector (−1 unknown) or None."""
        q = self._query_matrix(rss_dbm)
        s = (q @ self._v.T).toarray()
        m = (q @ self._o.T).toarray()
        frac = m / np.maximum((~np.isnan(rss_dbm)).sum(axis=1), 1)[:, None]
        cand = frac >= self.cfg.match_fraction - 1e-12
        best = frac.max(axis=1, keepdims=True)
        cand = np.where(~cand.any(axis=1, keepdims=True), (frac >= best - 1e-12) & (best > 0), cand)
        mark = s / np.maximum(m, 1.0) * self._direction_gain(sector)
        return np.where(cand, mark, 0.0)

    def log_likelihood(self, rss_dbm: np.ndarray, sector: np.ndarray | None = None) -> np.ndarray:
        """(n, n_rp) log L of scans in the map's AP order under ``scoring = "likelihood"`` (up to a
        constant per scan)."""
        ll = (self._query_matrix(rss_dbm) @ self._v.T).toarray()
        return ll + np.log(self._direction_gain(sector))

    def _direction_gain(self, sector: np.ndarray | None) -> np.ndarray | float:
        """(n, n_rp) D per scan and RP (1 where the directions differ or are unknown), or 1.0."""
        if sector is None:
            return 1.0
        same = (sector[:, None] >= 0) & (self.rp_sector[None, :] == sector[:, None])
        return np.where(same, self.cfg.direction_gain, 1.0)

    def select(self, mark: np.ndarray) -> np.ndarray:
        """(n, 2) mark-weighted mean of each row's best RPs holding ``mark_share`` of its mark; NaN if none."""
        o = np.argsort(-mark, axis=1, kind="stable")
        ms = np.take_along_axis(mark, o, axis=1)
        cum = np.cumsum(ms, axis=1)
        k = (cum < self.cfg.mark_share * ms.sum(axis=1, keepdims=True) - 1e-12).sum(axis=1) + 1
        w = np.where((np.arange(ms.shape[1])[None, :] < k[:, None]) & (ms > 0), ms, 0.0)
        sw = w.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = (w[:, :, None] * self._xy[o]).sum(axis=1) / sw[:, None]
        out[sw <= 0] = np.nan
        return out

    def most_probable(self, ll: np.ndarray) -> np.ndarray:
        """(n, 2) posterior-weighted mean of each row's ``k`` most probable RPs."""
        k = min(self.cfg.k, ll.shape[1])
        top = np.argpartition(-ll, k - 1, axis=1)[:, :k]
        lt = np.take_along_axis(ll, top, axis=1)
        p = np.exp(lt - lt.max(axis=1, keepdims=True))
        return (p[:, :, None] * self._xy[top]).sum(axis=1) / p.sum(axis=1)[:, None]

    def predict_rss(self, rss_dbm: np.ndarray, sector: np.ndarray | None = None) -> np.ndarray:
        """(n, 2) positions of scans in the map's AP order (``sector`` as in :meth:`marks`); NaN for a scan
        with no AP of the map."""
        out = np.full((len(rss_dbm), 2), np.nan)
        for s in range(0, len(rss_dbm), _BLOCK):
            x = rss_dbm[s:s + _BLOCK]
            sec = None if sector is None else sector[s:s + _BLOCK]
            if self.cfg.scoring == "mark":
                out[s:s + _BLOCK] = self.select(self.marks(x, sec))
            else:
                out[s:s + _BLOCK] = self.most_probable(self.log_likelihood(x, sec))
        out[np.isnan(rss_dbm).all(axis=1)] = np.nan
        return out

    def predict(self, query: Query) -> np.ndarray:
        if self.bssids is None:
            raise RuntimeError("fit() first")
        return self.predict_rss(query.aligned(self.bssids).rss_dbm)

    def summary(self) -> dict:
        return {"fallbacks": sorted(self.fallbacks), "n_rps": self.n_rp}


class DirectionHistogramLocalizer(HistogramLocalizer):
    """Per (cell, walking direction) histograms; the mark of an RP whose direction is the walker's gains D."""

    name: ClassVar[str] = "hist_dir"
    directional: ClassVar[bool] = True

    def predict(self, query: Query) -> np.ndarray:
        if self.bssids is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.bssids)
        fixes = self.predict_rss(q.rss_dbm)  # direction-free first: they orient each walk's PDR
        sector = np.full(len(q), -1, dtype=np.int64)
        self.fallbacks = set()
        for wid, rows in q.walks():
            steps = None if q.steps is None else q.steps.get(wid)
            if steps is None or len(steps) == 0 or self.n_directions == 0:
                self.fallbacks.add("steps:none" if self.n_directions else "map:no_directions")
                continue
            sector[rows] = self.walker_sectors(fixes[rows], pdr_positions(q.t_s[rows], steps))
        return self.predict_rss(q.rss_dbm, sector)

    def walker_sectors(self, fixes: np.ndarray, pdr: np.ndarray) -> np.ndarray:
        """(n,) the walker's direction sector at each scan of one walk (−1 unknown), causal."""
        out = np.full(len(fixes), -1, dtype=np.int64)
        win = self.cfg.rotation_window_scans
        good = np.isfinite(fixes).all(axis=1)
        for i in range(1, len(fixes)):
            lo = max(0, i - win + 1)
            if good[lo:i + 1].sum() < MIN_FIXES_FOR_DIRECTION:
                continue
            d = pdr[i] - pdr[i - 1]
            if np.hypot(*d) < MIN_MOVE_M:
                continue
            v = rotate(d, frame_rotation(pdr[lo:i + 1], fixes[lo:i + 1]))
            out[i] = int(direction_sector(np.array([np.arctan2(v[1], v[0])]), self.n_directions)[0])
        return out
