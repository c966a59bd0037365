"""Offline device calibration: fit a test device's RSS model against the map's device, and map its scans.

SLAC's comparison case (He et al., UbiComp 2015): a linear model ``φ_device = k ψ_map + b`` fitted from
co-located readings, then every scan mapped back, ``ψ = (φ − b) / k``, before an ordinary localizer runs.

**Why a plain least-squares fit is biased, and what :func:`fit_device_model` does instead.** Co-located
per-(spot, AP) means are noisy on *both* sides (each device's session offset per AP, a few dB, does not
average out over repeated scans), and the weaker device's means near its detection floor are means of the
readings it happened to detect. Ordinary least squares of device on map then (a) shrinks ``k`` towards 0 by
the map side's noise (regression dilution) and (b) flattens it further because the device's low end is
truncated upwards. On the synthetic venue a (1.25, −6 dB) device came out as k = 0.68 ± 0.03, b = −42 ± 2 dB
from 60 standing spots (bench/bench_localizers.py, eight draws; docs/notes/localizers.md). The fit here is a
Deming (errors-in-variables) regression with error-variance ratio ``k²`` (both devices see the same radio
noise, the device scaled by k), iterated, on the pairs whose estimated true level lies at least
:data:`FLOOR_MARGIN_DB` above both devices' detection floors (selected on the fit's latent value, not on
either noisy side, so the selection does not tilt the fit): 1.30 ± 0.11, −3 ± 6 dB from 60 spots; 1.24 ±
0.05, −6.7 ± 2.6 dB from 240.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rmbuild.baselines.config import OfflineCalibrationConfig
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, checked, sub_config
from rmbuild.radiomap.reference import ReferenceSet

#: dB; pairs are used only where both devices read at least this far above their detection floors: a
#: mean within two or three reading-noise σ (5 dB for a k = 1.25 device) of where detection starts to fail
#: (a few dB above the lowest reading) is a mean of the detected readings only. Synthetic venue, device
#: k = 1.25, b = −6, eight draws (bench/bench_localizers.py): 10 dB gave k 1.23 ± 0.06 from 60 spots but
#: 1.17 ± 0.02 from 240 (still biased); 15 dB 1.30 ± 0.11 and 1.24 ± 0.05. IPIN and UJI fits moved by
#: < 0.02 in k between the two.
FLOOR_MARGIN_DB = 15.0
#: 1; fewer trimmed pairs than this and the fit falls back to all pairs (named in the result).
MIN_TRIMMED_PAIRS = 10
#: iterations of the trim / Deming fixed point (it settles in 3-6 on every data set measured).
_MAX_ITER = 30


@dataclass(frozen=True)
class DeviceFit:
    """``φ_device = k ψ_map + b`` (dBm). ``n_pairs``: co-located (spot, AP) pairs given; ``n_used``: pairs
    the fit used; ``floors_dbm``: (map, device) detection floors assumed; ``method``: "deming_trimmed" or,
    when too few pairs clear the floors, "deming_all"."""

    k: float
    b: float
    n_pairs: int
    n_used: int
    floors_dbm: tuple[float, float]
    method: str

    def to_json(self) -> dict:
        return {"k": round(self.k, 4), "b": round(self.b, 3), "n_pairs": self.n_pairs, "n_used": self.n_used,
                "floors_dbm": [round(f, 1) for f in self.floors_dbm], "method": self.method}


def deming(x: np.ndarray, y: np.ndarray, ratio: float) -> tuple[float, float]:
    """Deming regression ``y = k x + b`` with error-variance ratio ``ratio = σ_y² / σ_x²``."""
    mx, my = float(x.mean()), float(y.mean())
    sxx = float(((x - mx) ** 2).mean())
    syy = float(((y - my) ** 2).mean())
    sxy = float(((x - mx) * (y - my)).mean())
    if abs(sxy) < 1e-12:
        return 0.0, my
    d = syy - ratio * sxx
    k = (d + np.sqrt(d * d + 4.0 * ratio * sxy * sxy)) / (2.0 * sxy)
    return float(k), my - float(k) * mx


def fit_device_model(
    map_dbm: np.ndarray,
    device_dbm: np.ndarray,
    floors_dbm: tuple[float, float] | None = None,
    margin_db: float = FLOOR_MARGIN_DB,
) -> DeviceFit:
    """Fit ``device = k · map + b`` from co-located readings (see the module docstring for the method).

    ``map_dbm``, ``device_dbm``: same shape, per (spot, AP) mean RSSI of the map's and the test device,
    NaN where either has none. ``floors_dbm``: the two devices' detection floors (default: the lowest value
    each side has). Raises InputError with fewer than 2 pairs or no spread in ``map_dbm``.
    """
    a = np.asarray(map_dbm, dtype=float).ravel()
    d = np.asarray(device_dbm, dtype=float).ravel()
    ok = np.isfinite(a) & np.isfinite(d)
    x, y = a[ok], d[ok]
    if len(x) < 2 or np.ptp(x) == 0:
        raise InputError(f"offline device fit needs >= 2 co-located readings with spread, got {len(x)}")
    fx, fy = floors_dbm if floors_dbm is not None else (float(x.min()), float(y.min()))
    k, b = deming(x, y, 1.0)
    use = np.ones(len(x), dtype=bool)
    for _ in range(_MAX_ITER):
        k_pos = max(k, 1e-3)
        # select on the fit's estimate of the true map value, (x + (y − b) / k) / 2: under the Deming model
        # its error is independent of the residual, so the selection does not tilt the fit (selecting on x
        # alone would: pairs just above the cut are those whose map value came out high)
        latent = 0.5 * (x + (y - b) / k_pos)
        new = latent >= max(fx + margin_db, (fy + margin_db - b) / k_pos)
        if new.sum() < MIN_TRIMMED_PAIRS:
            k, b = _deming_fixed_point(x, y, k)
            return DeviceFit(k, b, len(x), len(x), (fx, fy), "deming_all")
        k, b = _deming_fixed_point(x[new], y[new], k)
        if np.array_equal(new, use):
            break
        use = new
    return DeviceFit(k, b, len(x), int(use.sum()), (fx, fy), "deming_trimmed")


def _deming_fixed_point(x: np.ndarray, y: np.ndarray, k0: float) -> tuple[float, float]:
    """Deming with ratio k² where k is the fit's own slope (iterated from ``k0``)."""
    k = max(abs(k0), 0.1)
    b = 0.0
    for _ in range(_MAX_ITER):
        k_new, b = deming(x, y, k * k)
        if abs(k_new - k) < 1e-6:
            return k_new, b
        k = max(abs(k_new), 0.1)
    return k, b


def colocated_pairs(map_ref: ReferenceSet, device_ref: ReferenceSet, tol_m: float = 0.01) -> tuple:
    """(map_dbm, device_dbm), both (n_common, n_ap): the per-AP means of the RPs the two sets share (same
    position within ``tol_m``), in ``map_ref``'s AP order (APs the device set lacks are NaN)."""
    key_m = {tuple(np.round(p / tol_m).astype(np.int64)): i for i, p in enumerate(map_ref.xy)}
    rows = [(key_m[k], j) for j, p in enumerate(device_ref.xy)
            if (k := tuple(np.round(p / tol_m).astype(np.int64))) in key_m]
    if not rows:
        raise InputError("offline device fit: the two reference sets share no position")
    im, idv = np.array(rows).T
    col = {str(b): j for j, b in enumerate(device_ref.bssids)}
    cj = np.array([col.get(str(b), -1) for b in map_ref.bssids])
    dev = np.full((len(idv), len(cj)), np.nan)
    dev[:, cj >= 0] = device_ref.rss_dbm[idv][:, cj[cj >= 0]]
    return map_ref.rss_dbm[im].astype(float), dev


def to_map_units(k: np.ndarray | float, b: np.ndarray | float, device_model: str) -> tuple:
    """(k', b') with map-unit signal u = k' φ + b' for a device model [k, b] of the given direction
    ("device": φ = kψ + b; "calibration": u = kφ + b, SLAC's eq. 5 literally)."""
    k = np.asarray(k, dtype=float)
    b = np.asarray(b, dtype=float)
    if device_model == "device":
        return 1.0 / k, -b / k
    return k, b


def calibrate_rss(rss_dbm: np.ndarray, k: float, b: float, device_model: str = "device") -> np.ndarray:
    """Scan RSSI (n, L) dBm mapped into the map's units by a known device model (NaN stays NaN)."""
    kp, bp = to_map_units(k, b, device_model)
    return (kp * np.asarray(rss_dbm, dtype=np.float64) + bp).astype(np.float32)


def calibrate_query(query: Query, k: float, b: float, device_model: str = "device") -> Query:
    """A copy of ``query`` with every reading mapped into the map's units (see :func:`calibrate_rss`)."""
    return Query(calibrate_rss(query.rss_dbm, k, b, device_model), query.bssids, query.t_s, query.walk_id,
                 query.node, query.steps, dict(query.extra))


class OfflineCalibrated:
    """A localizer run on scans mapped back by a device model fitted offline (``[evaluate.baselines.offline_cal]``)."""

    name: ClassVar[str] = "offline_cal"

    def __init__(self, base, cfg: OfflineCalibrationConfig | None = None) -> None:
        self.cfg = checked(cfg, OfflineCalibrationConfig)
        self.base = base

    @classmethod
    def from_config(cls, cfg) -> OfflineCalibrated:
        from rmbuild.localize.base import make_localizer

        sub = sub_config(cfg, "offline_cal", OfflineCalibrationConfig)
        if sub.base == cls.name:
            raise InputError("offline_cal.base must name another localizer")
        return cls(make_localizer(sub.base, cfg), sub)

    def fit(self, ref) -> OfflineCalibrated:
        self.base.fit(ref)
        return self

    def predict(self, query: Query) -> np.ndarray:
        return self.base.predict(calibrate_query(query, self.cfg.k, self.cfg.b_db))

    def summary(self) -> dict:
        return {"k": self.cfg.k, "b": self.cfg.b_db, "base": self.cfg.base, **self.base.summary()}
