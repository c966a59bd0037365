"""SSD: signal-strength-difference fingerprints (Hossain et al. 2013; a baseline of He et al. 2015).

A fingerprint becomes its pairwise AP differences ``φ_i − φ_j``, which a device offset ``b`` does not
change. Over the APs S shared by a scan and an RP, with the residual ``e = φ − ψ̄``::

    (1/|S|²) Σ_{i,j∈S} ((φ_i − φ_j) − (ψ̄_i − ψ̄_j))² = 2 [mean_S(e²) − mean_S(e)²]

i.e. the SSD distance is the spread of the residual around its mean. Both means come from matrix products
with the detection indicators, so a query costs O(Q·L). Neighbours: RPs sharing at least
``min_shared_aps`` APs and ``min_shared_fraction`` of the scan's APs; position = mean of the K nearest.
A gain ``k ≠ 1`` is not cancelled (SSR, the ratio variant, would cancel a gain instead of an offset).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.config.localize import SsdConfig
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, ReferenceSet, as_reference, checked
from rmbuild.localize.slac import sub_config

_BLOCK = 512


class SsdLocalizer:
    """K nearest RPs by signal-strength-difference distance (offset-invariant)."""

    name: ClassVar[str] = "ssd"

    def __init__(self, cfg: SsdConfig | None = None) -> None:
        self.cfg = checked(cfg, SsdConfig)
        self.ref: ReferenceSet | None = None

    @classmethod
    def from_config(cls, cfg) -> SsdLocalizer:
        return cls(sub_config(cfg, "ssd", SsdConfig))

    def fit(self, ref) -> SsdLocalizer:
        ref = as_reference(ref, self.cfg.reference)
        if len(ref) == 0:
            raise InputError("SSD: the reference set is empty")
        self.ref = ref
        det = ~np.isnan(ref.rss_dbm)
        psi = np.where(det, ref.rss_dbm.astype(np.float64) + 70.0, 0.0)  # centred; cancels in differences
        self._B = det.astype(np.float64)
        self._P = psi
        self._P2 = psi * psi
        return self

    def distances(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n, Q) squared SSD distance 2 Var_S(φ − ψ̄) (inf where the RP is not admissible)."""
        det = ~np.isnan(rss_dbm)
        phi = np.where(det, rss_dbm.astype(np.float64) + 70.0, 0.0)
        b = det.astype(np.float64)
        n_s = b @ self._B.T
        se = phi @ self._B.T - b @ self._P.T
        se2 = (phi * phi) @ self._B.T + b @ self._P2.T - 2.0 * phi @ self._P.T
        with np.errstate(divide="ignore", invalid="ignore"):
            m = np.maximum(n_s, 1.0)
            d2 = 2.0 * np.maximum(se2 / m - (se / m) ** 2, 0.0)
        need = np.maximum(self.cfg.min_shared_aps, np.ceil(self.cfg.min_shared_fraction * b.sum(axis=1) - 1e-9))
        d2[n_s < need[:, None]] = np.inf
        return d2

    def predict_rss(self, rss_dbm: np.ndarray) -> np.ndarray:
        k = min(self.cfg.k, len(self.ref))  # type: ignore[arg-type]
        out = np.full((len(rss_dbm), 2), np.nan)
        for s in range(0, len(rss_dbm), _BLOCK):
            d2 = self.distances(rss_dbm[s:s + _BLOCK])
            top = np.argpartition(d2, k - 1, axis=1)[:, :k]
            ok = np.isfinite(np.take_along_axis(d2, top, axis=1))
            xy = self.ref.xy[top]  # type: ignore[union-attr]
            cnt = ok.sum(axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                out[s:s + _BLOCK] = (ok[:, :, None] * xy).sum(axis=1) / cnt[:, None]
            out[s:s + _BLOCK][cnt == 0] = np.nan
        return out

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres; NaN where no RP shares enough APs (e.g. a scan with fewer than 2 APs)."""
        if self.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.ref.bssids)
        return self.predict_rss(q.rss_dbm)

    def summary(self) -> dict:
        return {}
