"""Kalman post-filter of a localizer's track with PDR displacements (subway-station paper §III.C).

Per walk, state = position (map frame). Prediction: ``x_t = x_{t−1} + R(θ) Δ_t`` with ``Δ_t`` the PDR
displacement (walk frame) between the two scans and ``R(θ)`` the walk frame's rotation into the map frame,
estimated causally as the least-squares angle between the PDR and the localizer's displacements over the
last ``rotation_window_scans`` scans (0 before two localized scans). Process noise
``Q = (σ0 + σ1 ‖Δ‖)² I``, measurement = the localizer's position with ``R = σ_z² I``. ``mode = "rts"``
adds a Rauch-Tung-Striebel backward pass (uses the future: offline only).

Use :class:`KalmanSmoothed` around any localizer, or the registered ``*_kf`` classes.
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from rmbuild.baselines.config import SmoothingConfig
from rmbuild.localize.base import Query, checked, sub_config


def pdr_positions(t_s: np.ndarray, steps: pd.DataFrame) -> np.ndarray:
    """(n, 2) PDR position (walk frame, m) at the scan times: steps accumulated up to each time."""
    st = steps.sort_values("t_s", kind="stable")
    ts = st["t_s"].to_numpy(dtype=float)
    ln = np.nan_to_num(st["step_length_m"].to_numpy(dtype=float))
    hd = st["heading_rad"].to_numpy(dtype=float)
    cx = np.r_[0.0, np.cumsum(ln * np.cos(hd))]
    cy = np.r_[0.0, np.cumsum(ln * np.sin(hd))]
    k = np.searchsorted(ts, t_s, side="right")
    return np.c_[cx[k], cy[k]]


def frame_rotation(pdr: np.ndarray, fixes: np.ndarray) -> float:
    """rad; the least-squares rotation taking a walk's PDR displacements onto its fixes' displacements.

    ``pdr`` (n, 2) PDR positions (walk frame) and ``fixes`` (n, 2) map-frame positions at the same times
    (NaN = no fix); displacements between consecutive rows with a fix. 0 with fewer than two fixes.
    """
    good = np.isfinite(fixes).all(axis=1)
    if good.sum() < 2:
        return 0.0
    a = np.diff(pdr[good], axis=0)
    b = np.diff(fixes[good], axis=0)
    return float(np.arctan2((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum(), (a * b).sum()))


def rotate(v: np.ndarray, theta: float) -> np.ndarray:
    """(..., 2) vectors rotated by ``theta`` rad."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def kalman_smooth(z: np.ndarray, pdr: np.ndarray, cfg: SmoothingConfig) -> np.ndarray:
    """Filter (or RTS-smooth) one walk. ``z`` (n, 2) localizer positions (NaN = none), ``pdr`` (n, 2)
    PDR positions at the same times (walk frame). Returns (n, 2); NaN before the first measurement."""
    n = len(z)
    xf = np.full((n, 2), np.nan)  # filtered
    xp = np.full((n, 2), np.nan)  # predicted (before the update)
    pf = np.full(n, np.nan)  # isotropic covariances: P = p I throughout
    pp = np.full(n, np.nan)
    x = None
    p = 0.0
    r = cfg.measurement_sd_m ** 2
    last = 0
    for i in range(n):
        if x is not None:
            dp = pdr[i] - pdr[last]
            lo = max(0, i - cfg.rotation_window_scans)
            x = x + rotate(dp, frame_rotation(pdr[lo:i], z[lo:i]))
            p = p + (cfg.process_sd_m + cfg.process_sd_per_m * float(np.hypot(*dp))) ** 2
            last = i
            xp[i], pp[i] = x, p
        if np.isfinite(z[i]).all():
            if x is None:
                x, p, last = z[i].astype(float).copy(), r, i
                xp[i], pp[i] = x, p
            else:
                gain = p / (p + r)
                x = x + gain * (z[i] - x)
                p = (1.0 - gain) * p
        if x is not None:
            xf[i], pf[i] = x, p
    if cfg.mode != "rts":
        return xf
    out = xf.copy()
    for i in range(n - 2, -1, -1):
        if np.isfinite(pf[i]) and np.isfinite(pp[i + 1]) and pp[i + 1] > 0:
            out[i] = xf[i] + (pf[i] / pp[i + 1]) * (out[i + 1] - xp[i + 1])
    return out


@runtime_checkable
class _Summarizing(Protocol):
    def summary(self) -> dict: ...


class KalmanSmoothed:
    """Wraps a fitted-or-not localizer: its per-scan positions, Kalman-filtered with each walk's PDR."""

    name: ClassVar[str] = "kf"
    base_name: ClassVar[str] = ""

    def __init__(self, base, cfg: SmoothingConfig | None = None) -> None:
        self.base = base
        self.cfg = checked(cfg, SmoothingConfig)
        self.diagnostics: dict[str, dict] = {}

    @classmethod
    def from_config(cls, cfg) -> KalmanSmoothed:
        from rmbuild.localize.base import make_localizer

        return cls(make_localizer(cls.base_name, cfg), sub_config(cfg, "smoothing", SmoothingConfig))

    def fit(self, ref) -> KalmanSmoothed:
        self.base.fit(ref)
        return self

    def predict(self, query: Query) -> np.ndarray:
        raw = np.asarray(self.base.predict(query), dtype=float)
        out = raw.copy()
        self.diagnostics = {}
        for wid, rows in query.walks():
            steps = None if query.steps is None else query.steps.get(wid)
            if steps is None or len(steps) == 0:
                self.diagnostics[wid] = {"fallbacks": ["steps:none"]}  # left unsmoothed
                continue
            out[rows] = kalman_smooth(raw[rows], pdr_positions(query.t_s[rows], steps), self.cfg)
            self.diagnostics[wid] = {"fallbacks": []}
        return out

    def summary(self) -> dict:
        base = self.base.summary() if isinstance(self.base, _Summarizing) else {}
        fb = sorted({f for d in self.diagnostics.values() for f in d["fallbacks"]} | set(base.get("fallbacks", [])))
        return {**base, "fallbacks": fb}


class KnnKalman(KalmanSmoothed):
    name: ClassVar[str] = "knn_kf"
    base_name: ClassVar[str] = "knn"


class NaiveBayesKalman(KalmanSmoothed):
    name: ClassVar[str] = "nb_kf"
    base_name: ClassVar[str] = "nb"


class SsdKalman(KalmanSmoothed):
    name: ClassVar[str] = "ssd_kf"
    base_name: ClassVar[str] = "ssd"


class SlacKalman(KalmanSmoothed):
    name: ClassVar[str] = "slac_kf"
    base_name: ClassVar[str] = "slac"
