"""SSD and SSR: signal-strength differences and ratios between APs (SLAC's online-calibration baselines).

A fingerprint becomes its pairwise AP differences ``φ_i − φ_j``, which a device offset ``b`` does not
change. Over the APs S shared by a scan and an RP, with the residual ``e = φ − ψ̄``::

    (1/|S|²) Σ_{i,j∈S} ((φ_i − φ_j) − (ψ̄_i − ψ̄_j))² = 2 [mean_S(e²) − mean_S(e)²]

i.e. the SSD distance is the spread of the residual around its mean. Both means come from matrix products
with the detection indicators, so a query costs O(Q·L). Neighbours: RPs sharing at least
``min_shared_aps`` APs and ``min_shared_fraction`` of the scan's APs; position = mean of the K nearest.
A gain ``k ≠ 1`` is not cancelled.

**SSR** uses the ratios ``φ_i / φ_j`` of the RSSI values in dBm instead. Compared as log-ratios,
``log(−φ_i) − log(−φ_j)``, they are the same construction on the feature ``log(−φ)``: the SSR distance is
2 Var_S(log(−φ) − log(−ψ̄)), in which a device gain (φ = kψ) cancels exactly and an offset does not.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.baselines.config import SsdConfig, SsrConfig
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, ReferenceSet, as_reference, checked, sub_config

_BLOCK = 512


class SsdLocalizer:
    """K nearest RPs by signal-strength-difference distance (offset-invariant)."""

    name: ClassVar[str] = "ssd"
    config_cls: ClassVar[type] = SsdConfig

    def __init__(self, cfg: SsdConfig | SsrConfig | None = None) -> None:
        self.cfg: SsdConfig | SsrConfig = checked(cfg, self.config_cls)
        self.ref: ReferenceSet | None = None

    @classmethod
    def from_config(cls, cfg) -> SsdLocalizer:
        return cls(sub_config(cfg, cls.name, cls.config_cls))

    def fit(self, ref) -> SsdLocalizer:
        ref = as_reference(ref, self.cfg.reference)
        if len(ref) == 0:
            raise InputError("SSD: the reference set is empty")
        self.ref = ref
        det = ~np.isnan(ref.rss_dbm)
        psi = np.where(det, self.feature(ref.rss_dbm), 0.0)
        self._B = det.astype(np.float64)
        self._P = psi
        self._P2 = psi * psi
        return self

    @staticmethod
    def feature(rss_dbm: np.ndarray) -> np.ndarray:
        """What is differenced between APs: the RSSI, centred (the centre cancels in differences)."""
        return np.asarray(rss_dbm, dtype=np.float64) + 70.0

    def distances(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n, Q) squared distance 2 Var_S(f(φ) − f(ψ̄)), f = :meth:`feature` (inf where not admissible)."""
        det = ~np.isnan(rss_dbm)
        phi = np.where(det, self.feature(rss_dbm), 0.0)
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


#: dBm; readings are clipped to at most this before the log of SSR's feature (a reading of 0 dBm or more
#: would have no log; real RSSI stays far below).
_SSR_MAX_DBM = -1.0


class SsrLocalizer(SsdLocalizer):
    """K nearest RPs by signal-strength-ratio distance (gain-invariant)."""

    name: ClassVar[str] = "ssr"
    config_cls: ClassVar[type] = SsrConfig

    @staticmethod
    def feature(rss_dbm: np.ndarray) -> np.ndarray:
        """log(−φ): ratios of dBm values become differences of it."""
        return np.log(-np.minimum(np.asarray(rss_dbm, dtype=np.float64), _SSR_MAX_DBM))
