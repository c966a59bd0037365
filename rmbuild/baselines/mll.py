"""MLL: maximum-likelihood localization along the walking trajectory (SLAC's baseline; He et al. 2015).

As SLAC's comparison describes it: scans and steps are taken as conditionally independent, the likelihood
of a sequence of positions is the product of the Wi-Fi likelihood of every scan and the motion likelihood
of every walked stretch, and the position of the most likely sequence is the estimate. Per walk, for scan
m with the window of the last ``M`` (non-empty) scans ``m−M+1 … m``::

    maximise over RPs r_{m−M+1..m}:  Σ_j log P(φ_j | r_j) + Σ_j log N(‖r_j − r_{j−1}‖ − δ_j; 0, σ²)

``P(φ|r)`` is the naive-Bayes Gaussian likelihood per AP (missing readings at ``fill_dbm``), ``δ_j`` the
PDR distance walked between scans j−1 and j (the step counter: lengths only, no headings), σ =
``motion_sd_m``. States per scan are the ``n_candidates`` RPs most likely by Wi-Fi alone; the maximum is
exact over them (max-product / Viterbi along the window). The estimate for scan m is the end of the best
sequence (causal: scans after m are never used). Empty scans get NaN and their steps carry over.
Without step events the walk falls back to the Wi-Fi maximum (``"steps:none"`` in :meth:`summary`).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pandas as pd

from rmbuild.baselines.bayes import NaiveBayesLocalizer
from rmbuild.baselines.config import BayesConfig, MllConfig
from rmbuild.localize.base import Query, as_reference, checked, sub_config


def walked_between(t_scan: np.ndarray, steps: pd.DataFrame | None) -> np.ndarray:
    """(n,) PDR distance (m) walked in (t_{i−1}, t_i] for each scan time (0 for the first scan)."""
    if steps is None or len(steps) == 0:
        return np.zeros(len(t_scan))
    st = steps.sort_values("t_s", kind="stable")
    cl = np.r_[0.0, np.cumsum(np.nan_to_num(st["step_length_m"].to_numpy(dtype=float)))]
    hi = np.searchsorted(st["t_s"].to_numpy(dtype=float), t_scan, side="right")
    out = cl[hi] - cl[np.r_[hi[:1], hi[:-1]]]
    return np.asarray(out, dtype=float)


class MllLocalizer:
    """Windowed maximum likelihood of Wi-Fi scans and walked distances over the map's RPs."""

    name: ClassVar[str] = "mll"

    def __init__(self, cfg: MllConfig | None = None) -> None:
        self.cfg = checked(cfg, MllConfig)
        self.nb = NaiveBayesLocalizer(BayesConfig(kernel_sigma_db=self.cfg.kernel_sigma_db,
                                                  fill_dbm=self.cfg.fill_dbm, reference=self.cfg.reference))
        self.fallbacks: set[str] = set()

    @classmethod
    def from_config(cls, cfg) -> MllLocalizer:
        return cls(sub_config(cfg, "mll", MllConfig))

    def fit(self, ref) -> MllLocalizer:
        self.nb.fit(as_reference(ref, self.cfg.reference))
        return self

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres in the map frame, causal per walk; NaN for scans without any AP of the map."""
        if self.nb.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.nb.ref.bssids)
        idx, ll = self.nb.top(q.rss_dbm, self.cfg.n_candidates)
        ok = ~np.isnan(q.rss_dbm).all(axis=1)
        out = np.full((len(q), 2), np.nan)
        self.fallbacks = set()
        for wid, rows in q.walks():
            steps = None if q.steps is None else q.steps.get(wid)
            no_steps = steps is None or len(steps) == 0
            if no_steps:
                self.fallbacks.add("steps:none")
            rows = rows[ok[rows]]
            if len(rows):
                walked = None if no_steps else walked_between(q.t_s[rows], steps)
                out[rows] = self.track(idx[rows], ll[rows], walked)
        return out

    def track(self, idx: np.ndarray, ll: np.ndarray, walked: np.ndarray | None) -> np.ndarray:
        """One walk: candidates ``idx`` / ``ll`` (n, C), ``walked`` (n,) m since the previous scan (None: no
        steps, each scan on its own). Returns (n, 2) the end of the best window sequence after each scan."""
        xy = self.nb.ref.xy  # type: ignore[union-attr]
        inv2 = 1.0 / (2.0 * self.cfg.motion_sd_m ** 2)
        m = self.cfg.window_scans if walked is not None else 1
        out = np.empty((len(idx), 2))
        for i in range(len(idx)):
            lo = max(0, i - m + 1)
            msg = ll[lo].copy()
            for j in range(lo + 1, i + 1):
                d = np.linalg.norm(xy[idx[j]][None, :, :] - xy[idx[j - 1]][:, None, :], axis=2)
                msg = ll[j] + (msg[:, None] - (d - walked[j]) ** 2 * inv2).max(axis=0)  # type: ignore[index]
            out[i] = xy[idx[i, int(np.argmax(msg))]]
        return out

    def summary(self) -> dict:
        return {"fallbacks": sorted(self.fallbacks)}
