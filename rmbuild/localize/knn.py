"""FL / kNN and distance-weighted kNN fingerprint localizers (He et al. 2015; Chen et al. 2018 eq. 3-4).

The neighbour search shortlists ``K + margin`` candidates per query in float32, then re-ranks the shortlist
exactly in float64 (in a batch, only the entries whose float32 value may be rounded: with integer dBm the
float32 products are exact), so neighbours and distances equal a float64 brute-force search (up to exact
ties). The default (fill, euclidean) shortlist exploits sparse fingerprints
(:mod:`rmbuild.localize.knn_search`); the other metrics use dense float32 matrix products. Throughput
against scikit-learn: bench/bench_map.py.

With ``a = rss − fill`` (0 where missing) and ``b`` the detection indicator:

* fill / euclidean: ``d² = ‖a_q − a_r‖² = ‖a_q‖² + ‖a_r‖² − 2 a_q·a_r``
* fill / rms (Gu et al. 2017 eq. 9): the same divided by ``M = n_q + n_r − b_q·b_r`` (|union of detected APs|)
* exclude: ``d² = Σ_shared (v_q − v_r)² / |shared|``, with ``Σ_shared = (v_q²)·b_rᵀ + b_q·(v_r²)ᵀ −
  2 v_q·v_rᵀ`` and ``|shared| = b_q·b_rᵀ``; RPs sharing fewer than ``min_shared_aps`` APs are never
  neighbours.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.config.evaluate import EvaluateConfig, KnnConfig
from rmbuild.localize.base import Query, ReferenceSet, as_reference
from rmbuild.localize.knn_search import FEW_QUERIES, SparseL2Shortlist, in_chunks

#: float32 elements per block of the distance matrix (memory bound of one block: 4 bytes each).
_BLOCK_ELEMS = 1 << 21
#: extra candidates beyond K in the float32 shortlist, re-ranked in float64 (float32 rounding moves a
#: distance by far less than the gap between 8 ranks).
_MARGIN = 8


class KnnLocalizer:
    """Mean position of the K reference points nearest in RSS space."""

    name: ClassVar[str] = "knn"
    weighted: ClassVar[bool] = False

    def __init__(self, cfg: KnnConfig | None = None) -> None:
        self.cfg = cfg or KnnConfig()
        self.ref: ReferenceSet | None = None

    @classmethod
    def from_config(cls, cfg: EvaluateConfig) -> KnnLocalizer:
        return cls(cfg.knn)

    # ------------------------------------------------------------------ fit
    def fit(self, ref) -> KnnLocalizer:
        """Store the reference points (a RadioMap's ``cfg.reference`` view, or a ReferenceSet)."""
        ref = as_reference(ref, self.cfg.reference)
        if len(ref) == 0:
            raise ValueError("reference set is empty")
        self.ref = ref
        b = ~np.isnan(ref.rss_dbm)
        self._b = b.astype(np.float32)
        self._n = b.sum(axis=1).astype(np.float64)
        if self.cfg.missing == "fill":
            a = np.where(b, ref.rss_dbm.astype(np.float64) - self.cfg.fill_dbm, 0.0)
        else:  # centred values; the centre cancels in shared differences
            a = np.where(b, ref.rss_dbm.astype(np.float64) + 70.0, 0.0)
        self._a64 = a
        self._a = a.astype(np.float32)
        self._sq = (a * a).sum(axis=1)
        self._sq32 = (self._a * self._a)
        self._sq32n = self._sq.astype(np.float32)
        plain = self.cfg.missing == "fill" and self.cfg.metric == "euclidean"
        self._shortlist = SparseL2Shortlist(a, ref.xy) if plain else None
        return self

    # ------------------------------------------------------------ distances
    def _prep_query(self, rss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        b = ~np.isnan(rss)
        if self.cfg.missing == "fill":
            a = np.where(b, rss.astype(np.float64) - self.cfg.fill_dbm, 0.0)
        else:
            a = np.where(b, rss.astype(np.float64) + 70.0, 0.0)
        return a, b

    def _approx_d2(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """float32 (nq, n_rp) squared distances (inf = never a neighbour) from matrix products."""
        a32 = a.astype(np.float32)
        g = a32 @ self._a.T
        if self.cfg.missing == "fill":
            d2 = g
            d2 *= -2.0
            d2 += (a32 * a32).sum(axis=1)[:, None]
            d2 += self._sq32n[None, :]
            if self.cfg.metric == "rms":
                b32 = b.astype(np.float32)
                m = b32.sum(axis=1)[:, None] + self._n.astype(np.float32)[None, :] - b32 @ self._b.T
                d2 = d2 / np.maximum(m, 1.0)
        else:
            b32 = b.astype(np.float32)
            s = (a32 * a32) @ self._b.T + b32 @ self._sq32.T - 2.0 * g
            shared = b32 @ self._b.T
            d2 = s / np.maximum(shared, 1.0)
            d2[shared < self.cfg.min_shared_aps] = np.inf
        np.maximum(d2, 0.0, out=d2)
        return d2

    def _exact_d2(self, a: np.ndarray, b: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """float64 (nq, c) squared distances of each query to its candidate RPs ``cand`` (nq, c)."""
        ar = self._a64[cand]  # (nq, c, n_ap)
        if self.cfg.missing == "fill":
            # float64 identity: exact to ~1e-12 relative, cheaper than forming the differences
            d2 = (a * a).sum(axis=1)[:, None] + self._sq[cand] - 2.0 * np.einsum("ij,icj->ic", a, ar)
            np.maximum(d2, 0.0, out=d2)
            if self.cfg.metric == "rms":
                br = self._b[cand].astype(bool)
                m = (b[:, None, :] | br).sum(axis=2)
                d2 = d2 / np.maximum(m, 1)
        else:
            br = self._b[cand].astype(bool)
            both = b[:, None, :] & br
            d2 = np.where(both, (a[:, None, :] - ar) ** 2, 0.0).sum(axis=2)
            shared = both.sum(axis=2)
            d2 = d2 / np.maximum(shared, 1)
            d2[shared < self.cfg.min_shared_aps] = np.inf
        return d2

    def _candidates(self, a: np.ndarray, b: np.ndarray, c: int) -> np.ndarray:
        """(nq, c) RP indices holding each query's ``c`` nearest by the float32 distances."""
        d2 = self._approx_d2(a, b)
        if c < d2.shape[1]:
            return np.argpartition(d2, c - 1, axis=1)[:, :c]
        return np.broadcast_to(np.arange(d2.shape[1]), d2.shape).copy()

    def kneighbors(self, rss_dbm: np.ndarray, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """K nearest RPs of each query row (NaN = missing, columns in the reference's AP order).

        Returns ``(dist (n, k) float64 in dB, idx (n, k) int64)``, sorted by distance; slots with no
        admissible RP (``exclude`` mode) have dist = inf and idx = -1.
        """
        if self.ref is None:
            raise RuntimeError("fit() first")
        n_rp = len(self.ref)
        k = min(k or self.cfg.k, n_rp)
        c = min(n_rp, k + _MARGIN)
        nq = len(rss_dbm)
        if self._shortlist is not None:
            return self._kneighbors_few(rss_dbm, k, c) if nq <= FEW_QUERIES else self._kneighbors_many(rss_dbm, k, c)
        dist = np.full((nq, k), np.inf)
        idx = np.full((nq, k), -1, dtype=np.int64)
        n_ap = max(self.ref.rss_dbm.shape[1], 1)
        block = max(1, min(_BLOCK_ELEMS // max(n_rp, 1), _BLOCK_ELEMS // (c * n_ap)))
        for s in range(0, nq, block):
            a, b = self._prep_query(rss_dbm[s:s + block])
            cand = self._candidates(a, b, c)
            e2 = self._exact_d2(a, b, cand)
            o = np.argsort(e2, axis=1, kind="stable")[:, :k]
            e2 = np.take_along_axis(e2, o, axis=1)
            ci = np.take_along_axis(cand, o, axis=1)
            ci[~np.isfinite(e2)] = -1
            dist[s:s + block] = np.sqrt(e2)
            idx[s:s + block] = ci
        return dist, idx

    def _kneighbors_many(self, rss_dbm: np.ndarray, k: int, c: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`kneighbors` of many (fill, euclidean) queries, chunk by chunk on the shortlist's worker
        threads: the shortlist's float32 values where they are exact (integer dBm, the usual case: then
        ``‖a_q‖²`` plus the value is the float64 distance), float64 for the other entries, then the sort."""
        sl = self._shortlist
        assert sl is not None
        nq = len(rss_dbm)
        dist = np.empty((nq, k))
        idx = np.empty((nq, k), dtype=np.int64)
        step = max(1, min(sl.chunk_queries(nq), _BLOCK_ELEMS // (c * max(sl.n_ap, 1))))

        def run(s: int, e: int) -> None:
            a, _ = self._prep_query(rss_dbm[s:e])
            cand, d32 = sl.select(a, c)  # by increasing d32
            sq = (a * a).sum(axis=1)
            e2 = sq[:, None] + d32
            r, j = np.nonzero(~sl.exact(a, cand))
            if len(r):  # the float64 identity as in _exact_d2, for the entries float32 may have rounded
                ci = cand[r, j]
                e2[r, j] = sq[r] + self._sq[ci] - 2.0 * np.einsum("ij,ij->i", a[r], self._a64[ci])
                o = np.argsort(e2, axis=1, kind="stable")
                e2, cand = np.take_along_axis(e2, o, axis=1), np.take_along_axis(cand, o, axis=1)
            dist[s:e] = np.sqrt(np.maximum(e2[:, :k], 0.0))
            idx[s:e] = cand[:, :k]

        in_chunks(nq, step, run)
        return dist, idx

    def _kneighbors_few(self, rss_dbm: np.ndarray, k: int, c: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`kneighbors` of a few (fill, euclidean) queries one by one, over each one's detected APs only:
        the same float64 distances as the batch path, at a fraction of its fixed per-call cost."""
        assert self._shortlist is not None
        dist = np.empty((len(rss_dbm), k))
        idx = np.empty((len(rss_dbm), k), dtype=np.int64)
        for i, row in enumerate(np.asarray(rss_dbm, dtype=np.float64)):
            cols = np.flatnonzero(~np.isnan(row))
            v = row[cols] - self.cfg.fill_dbm
            cand = self._shortlist.one(cols, v, c)
            d2 = v @ v + self._sq[cand] - 2.0 * (self._a64[cand[:, None], cols] @ v)
            o = np.argsort(d2, kind="stable")[:k]
            dist[i] = np.sqrt(np.maximum(d2[o], 0.0))
            idx[i] = cand[o]
        return dist, idx

    # -------------------------------------------------------------- predict
    def _weights(self, dist: np.ndarray) -> np.ndarray:
        ok = np.isfinite(dist)
        if not self.weighted:
            return ok.astype(np.float64)
        eps = self.cfg.weight_eps_db
        with np.errstate(divide="ignore"):
            w = np.where(ok, 1.0 / np.maximum(dist, eps), 0.0) if eps > 0 else np.where(ok, 1.0 / dist, 0.0)
        exact = ok & (dist == 0.0)
        if eps == 0:
            rows = exact.any(axis=1)
            w[rows] = exact[rows].astype(np.float64)
        return w

    def predict_rss(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n, 2) positions from fingerprints already in the reference's AP order; NaN = no neighbour."""
        dist, idx = self.kneighbors(rss_dbm)
        w = self._weights(dist)
        xy = self.ref.xy[np.maximum(idx, 0)]  # type: ignore[union-attr]
        sw = w.sum(axis=1)
        ok = sw > 0
        if ok.all():  # the usual case, without the masks' cost (a tenth of a single query's time)
            return np.einsum("ik,ikd->id", w, xy) / sw[:, None]
        out = np.full((len(w), 2), np.nan)
        out[ok] = np.einsum("ik,ikd->id", w[ok], xy[ok]) / sw[ok, None]
        return out

    def summary(self) -> dict:
        """Localizer-specific figures for the report (none for kNN)."""
        return {}

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres in the map's frame, one row per query scan; NaN where no RP is admissible."""
        if self.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.ref.bssids)
        return self.predict_rss(q.rss_dbm)


class WeightedKnnLocalizer(KnnLocalizer):
    """Distance-weighted kNN: weights 1 / max(d, weight_eps_db); exact matches win when eps = 0."""

    name: ClassVar[str] = "wknn"
    weighted: ClassVar[bool] = True
