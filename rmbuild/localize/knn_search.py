"""Shortlist of the nearest reference points in squared euclidean distance, exploiting sparse fingerprints.

With missing readings filled by a constant, ``a = rss − fill`` is 0 wherever an AP is not detected, and a
scan detects ~20 of ~200 APs. Reference points (RPs) are sorted along a Morton curve of their positions and
cut into blocks of :data:`RP_BLOCK`; a block's RPs detect few APs between them (~70 of 186 on the `large`
preset), so ``‖a_r‖² − 2 a_q·a_r`` of a whole block is one float32 matrix product over those APs only, with
``‖a_r‖²`` as one more column against a row of ones (no separate pass over the distances); ``‖a_q‖²`` is a
per-query constant and does not change the ranking. A few queries at a time
(one-at-a-time localization) go one by one: one float32 vector-matrix product over the rows (APs) of
``−2 aᵀ`` the query detects, in the original RP order, and one ``partition`` (the caller re-ranks over
the query's detected APs only, :meth:`KnnLocalizer._kneighbors_few`). (An inverted index — per AP,
the RPs detecting it — with a weighted ``bincount`` over the query's postings was 2-3x slower: a query's APs
are the common ones, ~90k postings of 1.6M entries, and the scattered sums cost more than the dense rows.)

The ``c`` smallest entries of each query's row come from a two-level selection: the minimum of every group
of :data:`GROUP` consecutive RPs (taken block by block right after the block's product, while it is in
cache: a separate pass over the whole matrix cost as much as half the products), the ``c`` groups with the
smallest minima (any of the ``c`` nearest RPs lies in one of them, ties aside), then the ``c`` smallest of
those groups' entries. Both levels partition int64 keys that order like (float32 value, index)
(:func:`sort_keys`): one ``np.partition`` gives the indices with the values, where partitioning the values
and finding their indices again by a mask cost twice as much. The float32 shortlist is meant to be
re-ranked exactly by the caller (or used as it is where it is exact: :meth:`SparseL2Shortlist.exact`). Measured
against scikit-learn in bench/bench_map.py.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from rmbuild.blas import one_blas_thread

#: RPs per block of the blocked product (128: ~0.4 of the dense flops on the `large` preset, few calls).
RP_BLOCK = 128
#: RPs per group of the two-level selection (16: 1/16 of the entries reach the first argpartition).
GROUP = 16
#: queries up to this many at once go one by one (:meth:`SparseL2Shortlist.one`) instead of the blocks.
FEW_QUERIES = 8
#: worker threads over chunks of queries; BLAS runs one thread inside each (the products are small, and a
#: multi-threaded BLAS on small products was 3-8x slower on the shared 2-core machine).
THREADS = min(2, os.cpu_count() or 1)
#: float32 elements of the (RP, query) distance matrix per chunk of queries (8 MB).
CHUNK_ELEMS = 1 << 21
#: ``‖a_r‖²`` of the padding rows: never among the nearest, and finite (an inf met a 0 of the padding of
#: OpenBLAS's AVX-512 kernels: NaN and a RuntimeWarning)
PAD_SQ = 1e30
#: float32 holds every integer of magnitude below this exactly.
F32_EXACT = float(1 << 24)


def morton_order(xy: np.ndarray, bits: int = 16) -> np.ndarray:
    """Permutation sorting points along a Z-order (Morton) curve; non-finite positions go last."""
    xy = np.asarray(xy, dtype=np.float64)
    ok = np.isfinite(xy).all(axis=1)
    if not ok.any():
        return np.arange(len(xy))
    lo = xy[ok].min(axis=0)
    span = max(float(np.ptp(xy[ok], axis=0).max()), 1e-9)
    g = np.zeros((len(xy), 2), dtype=np.uint64)
    g[ok] = ((xy[ok] - lo) / span * (2**bits - 1)).astype(np.uint64)
    code = np.zeros(len(xy), dtype=np.uint64)
    for b in range(bits):
        bit = np.uint64(b)
        code |= ((g[:, 0] >> bit) & np.uint64(1)) << np.uint64(2 * b)
        code |= ((g[:, 1] >> bit) & np.uint64(1)) << np.uint64(2 * b + 1)
    code[~ok] = np.iinfo(np.uint64).max
    return np.argsort(code, kind="stable")


class SparseL2Shortlist:
    """Candidates for the ``c`` nearest rows of ``a`` (n_rp, n_ap) in squared euclidean distance."""

    def __init__(self, a: np.ndarray, xy: np.ndarray) -> None:
        n_rp, n_ap = a.shape
        self.n_rp, self.n_ap = n_rp, n_ap
        self.perm = morton_order(xy)
        self.n_pad = -(-n_rp // GROUP) * GROUP
        ap = np.zeros((self.n_pad, n_ap), dtype=np.float32)
        ap[:n_rp] = a[self.perm]
        sq = np.full(self.n_pad, PAD_SQ, dtype=np.float32)
        sq[:n_rp] = (a[self.perm].astype(np.float64) ** 2).sum(axis=1)
        self.sq = sq
        self.wt = np.ascontiguousarray(-2.0 * a.T, dtype=np.float32)  # (n_ap, n_rp), original order: one query
        self.sq_orig = sq[:n_rp][np.argsort(self.perm)]
        sq64 = (a * a).sum(axis=1)
        self.int_rows = np.all(a == np.rint(a), axis=1) & (sq64 < F32_EXACT)  # original order
        self.sq_int_max = float(sq64[self.int_rows].max()) if self.int_rows.any() else 0.0
        # per block: its rows, the AP columns its RPs detect plus the constant row (index n_ap) that adds
        # ‖a_r‖² inside the product, and [−2 a_r over those columns | ‖a_r‖²]
        self.blocks: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        for s in range(0, self.n_pad, RP_BLOCK):
            e = min(s + RP_BLOCK, self.n_pad)
            cols = np.flatnonzero((ap[s:e] != 0).any(axis=0))
            w = np.hstack([-2.0 * ap[s:e][:, cols], sq[s:e, None]])
            self.blocks.append((s, e, np.r_[cols, n_ap], np.ascontiguousarray(w, dtype=np.float32)))

    def one(self, cols: np.ndarray, vals: np.ndarray, c: int) -> np.ndarray:
        """(c,) RP indices holding the ``c`` nearest of one query, ties aside: the query detects the AP columns
        ``cols`` with ``vals`` = rss − fill; one float32 vector-matrix product over those rows of ``−2 aᵀ``."""
        if c >= self.n_rp:
            return np.arange(self.n_rp)
        d = vals.astype(np.float32) @ self.wt[cols]
        d += self.sq_orig
        kth = np.partition(d, c - 1)[c - 1]  # the c-th value, then its indices: faster than argpartition
        j = np.flatnonzero(d <= kth)
        return j if len(j) == c else np.argpartition(d, c - 1)[:c]

    def exact(self, aq: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """(nq, c) whether :meth:`select`'s float32 values for the queries ``aq`` (nq, n_ap) float64 and their
        candidates ``cand`` (nq, c) are exact: integers on both sides (integer dBm and fill), and every partial
        sum of ``‖a_r‖² − 2 a_q·a_r`` (at most ``‖a_r‖² + 2 ‖a_q‖ ‖a_r‖`` in magnitude) an integer below
        2**24, so no product or sum is rounded, in whatever order the BLAS adds them."""
        sq = (aq * aq).sum(axis=1)
        bound = self.sq_int_max + 2.0 * np.sqrt(self.sq_int_max * sq)
        ok = np.all(aq == np.rint(aq), axis=1) & (bound < F32_EXACT)
        return ok[:, None] & self.int_rows[cand]

    def _distances(self, aq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n_pad, nq) float32 ``‖a_r‖² − 2 a_q·a_r`` in the permuted RP order (PAD_SQ on the padding), and
        (n_pad / GROUP, nq) the minimum of each group of GROUP rows, taken while a block is in cache."""
        nq = len(aq)
        aqt = np.empty((self.n_ap + 1, nq), dtype=np.float32)  # the query's a, then a row of ones
        aqt[:self.n_ap] = aq.T
        aqt[self.n_ap] = 1.0
        dt = np.empty((self.n_pad, nq), dtype=np.float32)
        gmin = np.empty((self.n_pad // GROUP, nq), dtype=np.float32)
        for s, e, cols, w in self.blocks:
            np.matmul(w, aqt[cols], out=dt[s:e])
            np.min(dt[s:e].reshape(-1, GROUP, nq), axis=1, out=gmin[s // GROUP:e // GROUP])
        return dt, gmin

    def chunk_queries(self, nq: int) -> int:
        """Queries per chunk: the (RP, query) distances of a chunk within CHUNK_ELEMS, one chunk per thread."""
        return max(1, min(CHUNK_ELEMS // self.n_pad, -(-nq // THREADS)))

    def select(self, aq: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``c`` nearest RPs of each query of one chunk, ties aside, on the calling thread (``c <= n_rp``):
        (nq, c) RP indices (original order) and their float32 ``‖a_r‖² − 2 a_q·a_r``, by increasing value."""
        return self._select(*self._distances(aq), c)

    def _select(self, dt: np.ndarray, gmin: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`select` from the distances ``dt`` (n_pad, nq) and their groups' minima ``gmin``."""
        nq = dt.shape[1]
        if c * GROUP >= self.n_pad:
            rows = np.broadcast_to(np.arange(self.n_pad), (nq, self.n_pad))
        else:
            g = sort_keys(np.ascontiguousarray(gmin.T), np.arange(len(gmin)))
            gs = np.partition(g, c - 1, axis=1)[:, :c] & _LOW
            rows = (gs[:, :, None] * GROUP + np.arange(GROUP)).reshape(nq, -1)
        keys = sort_keys(dt.ravel().take(rows * nq + np.arange(nq)[:, None]), rows)
        best = np.sort(np.partition(keys, c - 1, axis=1)[:, :c], axis=1)
        return self.perm[best & _LOW], key_values(best)


def in_chunks(n: int, step: int, run: Callable[[int, int], None]) -> None:
    """``run(s, e)`` over the chunks [s, e) of ``range(n)`` of ``step`` items, on THREADS worker threads with one
    BLAS thread each (numpy releases the GIL in the products, selections and gathers)."""
    starts = range(0, n, step)
    with one_blas_thread():
        if len(starts) > 1 and THREADS > 1:
            with ThreadPoolExecutor(THREADS) as ex:
                list(ex.map(lambda s: run(s, min(s + step, n)), starts))
        else:
            for s in starts:
                run(s, min(s + step, n))


_LOW = np.int64(0xFFFFFFFF)


def sort_keys(x: np.ndarray, low: np.ndarray) -> np.ndarray:
    """int64 keys ordering like the float32 ``x`` (no NaN), then like ``low`` (ints in [0, 2**32), broadcast
    to ``x``): the value's bits, negative values' flipped (−0 before +0), above the index; :func:`key_values`
    inverts it."""
    i = x.view(np.int32)
    k = (i ^ ((i >> 31) & np.int32(0x7FFFFFFF))).astype(np.int64)
    k <<= 32
    k |= low
    return k


def key_values(k: np.ndarray) -> np.ndarray:
    """The float32 values of :func:`sort_keys`'s keys."""
    h = (k >> 32).astype(np.int32)
    return (h ^ ((h >> 31) & np.int32(0x7FFFFFFF))).view(np.float32)
