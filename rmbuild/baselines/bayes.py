"""Naive Bayes fingerprinting with a Gaussian kernel per AP (Becker et al. 2015 eq. 1-5).

``P(C|x) ∝ P(C) Π_i P(x_i|C)`` with a uniform prior over RPs C. The kernel density of eq. 3 over an RP's
recorded readings is taken as one Gaussian ``N(ψ̄, σ_k² + σ_q²)`` (σ_k the kernel bandwidth, σ_q the RP's
RSSI std when the map has it, else 0) — the KDE of a Gaussian sample. APs are the union of the scan's
and the RP's; a reading missing on one side counts as ``fill_dbm``. The log-likelihood of every RP is
three matrix products::

    log P(x|C_q) = −½ Σ_j [(x_j − y_qj)² / v_qj + log(2π v_qj)]

The position is the posterior-weighted mean of the K (Becker et al. 2015: 3) most probable RPs (eq. 5).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.baselines.config import BayesConfig
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, ReferenceSet, as_reference, checked, sub_config

_BLOCK = 512


class NaiveBayesLocalizer:
    """Gaussian-kernel naive Bayes over the RPs; position from the K most probable (Becker et al. 2015)."""

    name: ClassVar[str] = "nb"

    def __init__(self, cfg: BayesConfig | None = None) -> None:
        self.cfg = checked(cfg, BayesConfig)
        self.ref: ReferenceSet | None = None

    @classmethod
    def from_config(cls, cfg) -> NaiveBayesLocalizer:
        return cls(sub_config(cfg, "nb", BayesConfig))

    def fit(self, ref) -> NaiveBayesLocalizer:
        ref = as_reference(ref, self.cfg.reference)
        if len(ref) == 0:
            raise InputError("naive Bayes: the reference set is empty")
        self.ref = ref
        det = ~np.isnan(ref.rss_dbm)
        y = np.where(det, ref.rss_dbm.astype(np.float64), self.cfg.fill_dbm)
        sq = np.zeros(det.shape)
        if ref.std_db is not None:
            sq = np.where(det, np.nan_to_num(np.asarray(ref.std_db, dtype=np.float64)) ** 2, 0.0)
        v = self.cfg.kernel_sigma_db ** 2 + sq
        self._iv = 1.0 / v  # (Q, L)
        self._yiv = y / v
        self._const = (y * y / v + np.log(2 * np.pi * v)).sum(axis=1)  # (Q,)
        return self

    def log_likelihood(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n, Q) log P(x|C) of scans (n, L) in the reference's AP order (NaN = missing)."""
        x = np.where(np.isnan(rss_dbm), self.cfg.fill_dbm, rss_dbm.astype(np.float64))
        return -0.5 * ((x * x) @ self._iv.T - 2.0 * x @ self._yiv.T + self._const[None, :])

    def top(self, rss_dbm: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` most probable RPs of each scan (n, L): (idx (n, k) int64, log P(x|C) (n, k)), unordered."""
        n_rp = len(self.ref)  # type: ignore[arg-type]
        k = min(k, n_rp)
        idx = np.empty((len(rss_dbm), k), dtype=np.int64)
        ll = np.empty((len(rss_dbm), k))
        for s in range(0, len(rss_dbm), _BLOCK):
            full = self.log_likelihood(rss_dbm[s:s + _BLOCK])
            top = np.argpartition(-full, k - 1, axis=1)[:, :k] if k < n_rp else \
                np.broadcast_to(np.arange(n_rp), full.shape).copy()
            idx[s:s + _BLOCK] = top
            ll[s:s + _BLOCK] = np.take_along_axis(full, top, axis=1)
        return idx, ll

    def predict_rss(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n, 2) positions (eq. 5) from scans in the reference's AP order."""
        top, lt = self.top(rss_dbm, self.cfg.k)
        p = np.exp(lt - lt.max(axis=1, keepdims=True))
        p /= p.sum(axis=1, keepdims=True)
        return (p[:, :, None] * self.ref.xy[top]).sum(axis=1)  # type: ignore[union-attr]

    def predict(self, query: Query) -> np.ndarray:
        if self.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.ref.bssids)
        out = self.predict_rss(q.rss_dbm)
        out[np.isnan(q.rss_dbm).all(axis=1)] = np.nan  # an empty scan carries no evidence
        return out

    def summary(self) -> dict:
        return {}
