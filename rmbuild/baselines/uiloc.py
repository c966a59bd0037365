"""UILoc's initial-localization fusion: kNN and least-squares multilateration, weighted by exp(−distance).

Chen, Zhang and Xue (Sensors 2018, sec. 4.2) fuse two estimates of a scan's position: the kNN estimate A
(eq. 3-4) and the least-squares estimate B from ranges to beacons of known position (eq. 5-14, unknowns
``x, y, r1`` linear once ranges are differenced against the first beacon). Each is weighted by
``exp(−|OX|)`` with O the position implied by the beacon heard strongest, normalised (eq. 15-19).

Transfer to a Wi-Fi radio map (which has no beacon positions nor a ranging model): at ``fit`` each AP's
position is the power-weighted centroid of the RPs where it is heard within :data:`AP_TOP_DB` of its
strongest, and one log-distance model ``rss = P0 − 10 η log10(d)`` is fitted to every (RP, AP) reading
against those positions (the paper fits its own RSS-to-distance polynomial, eq. 2). O is the position of
the AP heard strongest in the scan (the paper also uses the phone's heading, which single scans lack).
Where fewer than :data:`LS_MIN_APS` located APs are heard, the kNN estimate stands alone.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.config.evaluate import EvaluateConfig, KnnConfig
from rmbuild.localize.base import Query, ReferenceSet, as_reference
from rmbuild.localize.knn import KnnLocalizer

#: RPs within this many dB of an AP's strongest reading place it (dB; a ~2x distance band at η ≈ 3).
AP_TOP_DB = 6.0
#: APs (strongest first) used in one scan's least-squares solve; 3 unknowns need >= 4 APs (eq. 12).
LS_MAX_APS = 8
LS_MIN_APS = 4
#: Ranges below this are clipped (m): the log-distance model is not fitted inside a metre.
MIN_RANGE_M = 1.0
#: Bounds of the fitted path-loss exponent η (free-space 2 to heavily obstructed indoor 6).
ETA_BOUNDS = (1.5, 6.0)


class UilocLocalizer:
    """kNN + least-squares fusion (UILoc eq. 15-19); kNN alone where the scan hears too few located APs."""

    name: ClassVar[str] = "uiloc"

    def __init__(self, cfg: KnnConfig | None = None) -> None:
        self.cfg = cfg or KnnConfig()
        self.knn = KnnLocalizer(self.cfg)
        self._summary: dict = {}

    @classmethod
    def from_config(cls, cfg: EvaluateConfig) -> UilocLocalizer:
        return cls(cfg.knn)

    def fit(self, ref) -> UilocLocalizer:
        """The kNN part on the reference set; AP positions and the path-loss model from its readings."""
        ref = as_reference(ref, self.cfg.reference)
        self.knn.fit(ref)
        self.ref = ref
        self.ap_xy = ap_positions(ref)
        self.p0, self.eta = fit_path_loss(ref, self.ap_xy)
        return self

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) fused positions in the map frame; NaN where kNN has no estimate."""
        q = query.aligned(self.ref.bssids)
        a = self.knn.predict_rss(q.rss_dbm)
        b, o = self.ls_estimates(q.rss_dbm)
        d_a = np.hypot(*(a - o).T)
        d_b = np.hypot(*(b - o).T)
        # eq. 15-18: W_fp = e^-dA / (e^-dA + e^-dB), written in a form that cannot overflow
        w_fp = 1.0 / (1.0 + np.exp(np.clip(d_a - d_b, -50.0, 50.0)))
        has_b = np.isfinite(b).all(axis=1) & np.isfinite(a).all(axis=1)
        out = a.copy()
        out[has_b] = w_fp[has_b, None] * a[has_b] + (1.0 - w_fp[has_b, None]) * b[has_b]
        self._summary = {"path_loss_p0_dbm": round(self.p0, 2), "path_loss_eta": round(self.eta, 3),
                         "ls_share": round(float(has_b.mean()) if len(has_b) else 0.0, 3),
                         "mean_w_ls": round(float(np.mean(1.0 - w_fp[has_b])) if has_b.any() else 0.0, 3)}
        return out

    def ls_estimates(self, rss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per scan: the least-squares position B (NaN when too few located APs) and the anchor O (the
        strongest located AP's position; NaN when none is heard)."""
        located = np.isfinite(self.ap_xy).all(axis=1)
        b = np.full((len(rss), 2), np.nan)
        o = np.full((len(rss), 2), np.nan)
        for i, row in enumerate(rss):
            heard = np.flatnonzero(np.isfinite(row) & located)
            if len(heard) == 0:
                continue
            top = heard[np.argsort(-row[heard], kind="stable")[:LS_MAX_APS]]
            o[i] = self.ap_xy[top[0]]
            if len(top) >= LS_MIN_APS:
                r = np.maximum(10.0 ** ((self.p0 - row[top].astype(np.float64)) / (10.0 * self.eta)), MIN_RANGE_M)
                b[i] = multilaterate(self.ap_xy[top], r)
        return b, o

    def summary(self) -> dict:
        """The path-loss fit, the share of scans with a least-squares estimate and its mean weight."""
        return dict(self._summary)


def multilaterate(xy: np.ndarray, r: np.ndarray) -> np.ndarray:
    """UILoc eq. 10-14: (x, y) from anchors ``xy`` (N, 2) and ranges ``r`` (N,), N >= 4, the first anchor
    the reference. Unknowns Z = (x, y, r1) solve G Z = H in the least-squares sense; NaN if degenerate."""
    d = xy[1:] - xy[0]
    k = (xy * xy).sum(axis=1)
    ri1 = r[1:] - r[0]
    g = -np.column_stack([d, ri1])
    h = 0.5 * (ri1 * ri1 - (k[1:] - k[0]))
    z, _, rank, _ = np.linalg.lstsq(g, h, rcond=None)
    return z[:2] if rank == 3 else np.full(2, np.nan)


def ap_positions(ref: ReferenceSet, top_db: float = AP_TOP_DB) -> np.ndarray:
    """(n_ap, 2) each AP's position: the linear-power-weighted centroid of the RPs where its mean RSS is
    within ``top_db`` of its strongest; NaN for an AP no RP hears."""
    rss = ref.rss_dbm.astype(np.float64)
    with np.errstate(invalid="ignore"):
        best = np.nanmax(np.where(np.isfinite(rss), rss, -np.inf), axis=0)
        w = np.where(np.isfinite(rss) & (rss >= best - top_db), 10.0 ** ((rss - best) / 10.0), 0.0)
    sw = w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (w.T @ ref.xy) / sw[:, None]
    out[sw == 0] = np.nan
    return out


def fit_path_loss(ref: ReferenceSet, ap_xy: np.ndarray) -> tuple[float, float]:
    """One log-distance model ``rss = P0 − 10 η log10(max(d, 1 m))`` over every (RP, located AP) reading,
    ordinary least squares; η clipped to :data:`ETA_BOUNDS` (P0 refitted then). Returns (P0 dBm, η)."""
    r, c = np.nonzero(np.isfinite(ref.rss_dbm) & np.isfinite(ap_xy).all(axis=1)[None, :])
    if len(r) < 2:
        return -40.0, 3.0  # an empty map: a typical indoor 2.4 GHz model
    x = -10.0 * np.log10(np.maximum(np.hypot(*(ref.xy[r] - ap_xy[c]).T), MIN_RANGE_M))
    y = ref.rss_dbm[r, c].astype(np.float64)
    if np.ptp(x) == 0:
        return float(y.mean()), 3.0
    eta, p0 = np.polyfit(x, y, 1)
    eta = float(np.clip(eta, *ETA_BOUNDS))
    return float(np.mean(y - eta * x)), eta
