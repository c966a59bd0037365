"""RSS distance of eq. 9 (Gu et al. 2017) as matrix products.

With ``a = rss - fill`` (0 for a missing AP) and ``b`` the detection indicator, the sum of squared
differences over the union of two fingerprints' APs is ``‖a_k − a_q‖²`` and the union's size is
``n_k + n_q − b_k·b_q``; so ``d(k, q) = sqrt(‖a_k − a_q‖² / |union|)`` for whole blocks at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild.types import Fingerprints


@dataclass
class RssMatrix:
    """Fingerprints prepared for eq. 9: ``a`` (n, m) float32 dB above fill, ``b`` (n, m) float32 0/1,
    ``sq`` (n,) ‖a‖², ``cnt`` (n,) number of APs seen."""

    a: np.ndarray
    b: np.ndarray
    sq: np.ndarray
    cnt: np.ndarray

    @staticmethod
    def from_fingerprints(fp: Fingerprints, fill_dbm: float) -> RssMatrix:
        det = ~np.isnan(fp.rss_dbm)
        a = np.where(det, fp.rss_dbm - np.float32(fill_dbm), 0).astype(np.float32, copy=False)
        b = det.astype(np.float32)
        return RssMatrix(a, b, np.einsum("ij,ij->i", a, a, dtype=np.float64), b.sum(axis=1, dtype=np.float64))

    @property
    def sq32(self) -> np.ndarray:
        return self.sq.astype(np.float32)

    @property
    def cnt32(self) -> np.ndarray:
        return self.cnt.astype(np.float32)

    def __len__(self) -> int:
        return len(self.a)

    def block(self, rows: np.ndarray | slice, cols: np.ndarray | slice | None = None):
        """(d, common) for rows x cols: eq. 9 distance (dB, float32) and number of shared APs."""
        cols = slice(None) if cols is None else cols
        dot, common = self.products(rows, cols)
        return self.distance(self.cnt[rows][:, None], self.cnt[cols][None, :], self.sq[rows][:, None],
                             self.sq[cols][None, :], dot, common), common

    def products(self, rows: np.ndarray | slice, cols: np.ndarray | slice):
        """(dot, common) for rows x cols: the float32 products eq. 9 is computed from."""
        return self.a[rows] @ self.a[cols].T, self.b[rows] @ self.b[cols].T

    @staticmethod
    def distance(cnt_r, cnt_c, sq_r, sq_c, dot, common) -> np.ndarray:
        """Eq. 9 distance (dB, float32) from the products (``dot`` is overwritten), the rows' and columns' AP
        counts and squared norms broadcast against them: a block (rows as columns, columns as rows) or
        entries picked from one, each entry by the same float64 operations in the same order."""
        # sqrt(max(sq_r + sq_c - 2 dot, 0) / max(cnt_r + cnt_c - common, 1)), in place: the temporaries
        # of a (rows x n) block dominated the pair search's and the placement's time at 150k poses
        union = cnt_r + cnt_c
        union -= common
        np.maximum(union, 1, out=union)
        dot *= 2.0
        sq = sq_r + sq_c
        sq -= dot
        del dot
        np.maximum(sq, 0, out=sq)
        sq /= union
        del union
        np.sqrt(sq, out=sq)
        return sq.astype(np.float32)

    def block_sq32(self, rows: np.ndarray, cols: np.ndarray):
        """(d², common) for rows x cols in float32: the squared eq. 9 distance (dB²) with float32
        arithmetic (for ranking: rounding ~0.01 dB² at typical ‖a‖² ~ 10⁵ dB²), and the shared APs."""
        d = self.a[rows] @ self.a[cols].T
        common = self.b[rows] @ self.b[cols].T
        d *= -2.0
        d += self.sq32[rows][:, None]
        d += self.sq32[cols][None, :]
        np.maximum(d, 0, out=d)
        union = np.add.outer(self.cnt32[rows], self.cnt32[cols])
        union -= common
        np.maximum(union, 1, out=union)
        d /= union
        return d, common

    def pairs(self, i: np.ndarray, j: np.ndarray, chunk: int = 20000):
        """(d, common) for row pairs (i[p], j[p]) (exact, chunked)."""
        d = np.empty(len(i), np.float32)
        common = np.empty(len(i), np.float32)
        for s in range(0, len(i), chunk):
            ii, jj = i[s:s + chunk], j[s:s + chunk]
            diff = self.a[ii] - self.a[jj]
            c = np.einsum("ij,ij->i", self.b[ii], self.b[jj])
            union = self.cnt[ii] + self.cnt[jj] - c
            d[s:s + chunk] = np.sqrt(np.einsum("ij,ij->i", diff, diff) / np.maximum(union, 1))
            common[s:s + chunk] = c
        return d, common


def rss_distance_reference(rss_k: np.ndarray, rss_q: np.ndarray, fill_dbm: float = -110.0) -> float:
    """Eq. 9 literally for two fingerprints (NaN = not seen): union of APs, missing filled with fill_dbm."""
    seen = ~np.isnan(rss_k) | ~np.isnan(rss_q)
    m = int(seen.sum())
    if m == 0:
        return 0.0
    a = np.where(np.isnan(rss_k), fill_dbm, rss_k)[seen]
    b = np.where(np.isnan(rss_q), fill_dbm, rss_q)[seen]
    return float(np.sqrt(np.sum((a - b) ** 2) / m))
