"""SmartLocator's auto-adaptive dead reckoning (Becker, Jäger, Süß, "Indoor Smartphone Localization with
Auto-Adaptive Dead Reckoning", ICONS 2015), and its static-weight comparison.

Per walk, in time order: the position is carried forward by the PDR displacement since the previous scan
(rotated into the map frame), and every Wi-Fi fix (naive Bayes, eq. 1-5) is blended in (eq. 9)::

    Loc(t) = α · Fix(t) + (1 − α) · Loc(t − 1),   α = min(Q + α_t, 1)   (eq. 8)

``Q`` is the fix's accuracy factor and ``α_t`` a factor growing linearly with the time since the
previous fix (Fig. 4: 0.04 per second up to 0.4). The paper's eq. 8 prints ``max(Q + α_t, 1)``, which
would always give 1 (the fix overwrites); the clamp to 1 is what the text and its figures mean. ``Q``
rises with the number of APs in the scan (Fig. 6: 0 at 2 APs, 0.3 at 5). The static variant uses a fixed
``α = static_weight`` (the paper's Fig. 9c: 0.5). The first fix is taken as it is. (A Q from the spread
of the most likely RPs was measured and not kept: docs/notes/localizers.md.)

The paper's PDR heading comes from a compass; here each walk's PDR is in its own frame, so its rotation
into the map frame is the least-squares angle between the PDR and the fixes' displacements over the last
``rotation_window_scans`` scans (causal). Without step events a walk falls back to the fixes alone
(``"steps:none"``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from rmbuild.baselines.bayes import NaiveBayesLocalizer
from rmbuild.baselines.config import BayesConfig, SmartLocatorConfig
from rmbuild.baselines.smoothing import frame_rotation, pdr_positions, rotate
from rmbuild.localize.base import Query, as_reference, checked, sub_config


class SmartLocator:
    """Auto-adaptive fusion of naive-Bayes fixes with PDR (weight from each fix's accuracy and age)."""

    name: ClassVar[str] = "smartloc"
    adaptive: ClassVar[bool] = True

    def __init__(self, cfg: SmartLocatorConfig | None = None, nb: BayesConfig | None = None) -> None:
        self.cfg = checked(cfg, SmartLocatorConfig)
        self.nb = NaiveBayesLocalizer(nb)
        self.fallbacks: set[str] = set()
        self.mean_weight: float | None = None

    @classmethod
    def from_config(cls, cfg) -> SmartLocator:
        return cls(sub_config(cfg, "smartloc", SmartLocatorConfig), sub_config(cfg, "nb", BayesConfig))

    def fit(self, ref) -> SmartLocator:
        self.nb.fit(as_reference(ref, self.nb.cfg.reference))
        return self

    def accuracy(self, rss_dbm: np.ndarray) -> np.ndarray:
        """(n,) accuracy factor Q of each scan's fix: q_max · clip((APs − lo) / (hi − lo), 0, 1)."""
        n_ap = (~np.isnan(rss_dbm)).sum(axis=1)
        lo, hi = self.cfg.aps_range
        return self.cfg.q_max * np.clip((n_ap - lo) / (hi - lo), 0.0, 1.0)

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres in the map frame, causal per walk; NaN before a walk's first fix."""
        if self.nb.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.nb.ref.bssids)
        fixes = self.nb.predict_rss(q.rss_dbm)
        fixes[np.isnan(q.rss_dbm).all(axis=1)] = np.nan
        quality = self.accuracy(q.rss_dbm)
        out = fixes.copy()
        self.fallbacks = set()
        weights: list[np.ndarray] = []
        for wid, rows in q.walks():
            steps = None if q.steps is None else q.steps.get(wid)
            if steps is None or len(steps) == 0:
                self.fallbacks.add("steps:none")
                continue
            pdr = pdr_positions(q.t_s[rows], steps)
            out[rows], w = self.fuse(fixes[rows], quality[rows], q.t_s[rows], pdr)
            weights.append(w)
        w_all = np.concatenate(weights) if weights else np.zeros(0)
        self.mean_weight = float(np.nanmean(w_all)) if np.isfinite(w_all).any() else None
        return out

    def weight(self, quality: float, age_s: float) -> float:
        """α of one fix: eq. 8 (clamped to 1), or the static weight."""
        cfg = self.cfg
        if not self.adaptive:
            return cfg.static_weight
        return min(quality + min(cfg.time_gain_per_s * age_s, cfg.time_gain_max), 1.0)

    def fuse(self, fixes: np.ndarray, quality: np.ndarray, t_s: np.ndarray, pdr: np.ndarray) -> tuple:
        """One walk: ``fixes`` (n, 2) (NaN = none), ``quality`` (n,) Q, ``t_s`` (n,) s, ``pdr`` (n, 2) PDR
        positions (walk frame) at the scan times. Returns ((n, 2) positions, (n,) α used, NaN = none)."""
        n = len(fixes)
        out = np.full((n, 2), np.nan)
        alpha = np.full(n, np.nan)
        loc: np.ndarray | None = None
        t_last = 0.0
        for i in range(n):
            if loc is not None and i > 0:
                lo = max(0, i - self.cfg.rotation_window_scans)
                loc = loc + rotate(pdr[i] - pdr[i - 1], frame_rotation(pdr[lo:i], fixes[lo:i]))
            if np.isfinite(fixes[i]).all():
                if loc is None:
                    loc = fixes[i].astype(float).copy()
                else:
                    alpha[i] = self.weight(float(quality[i]), float(t_s[i] - t_last))
                    loc = alpha[i] * fixes[i] + (1.0 - alpha[i]) * loc
                t_last = float(t_s[i])
            if loc is not None:
                out[i] = loc
        return out, alpha

    def summary(self) -> dict:
        return {"fallbacks": sorted(self.fallbacks), "mean_weight": self.mean_weight}


class StaticSmartLocator(SmartLocator):
    """The paper's comparison: every fix blended in with the same weight ``static_weight``."""

    name: ClassVar[str] = "smartloc_static"
    adaptive: ClassVar[bool] = False
