"""PFL: a particle filter fusing PDR steps with fingerprint fixes (He et al. 2015's baseline PFL; Chen et al. 2018's
particle corrections of step length and walking direction).

Per test walk, state per particle: position (map frame), the rotation of the walk's PDR frame into the
map frame, and a step-length scale. Each PDR step moves every particle by ``scale · L · (1 + n)`` along
``heading + rotation`` (``n`` relative noise; the rotation takes a small random walk, Chen et al. 2018's heading
bias). Each Wi-Fi scan weights the particles by a Gaussian of their distance to the scan's kNN fix
(σ = ``fix_sd_m``); resampling when the effective sample size drops. The estimate is the weighted mean
after the scan's update (causal). Without step events the walk falls back to the kNN fixes (named
``"steps:none"`` in :attr:`PflLocalizer.diagnostics`).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pandas as pd

from rmbuild.baselines.config import PflConfig
from rmbuild.config.evaluate import KnnConfig
from rmbuild.localize.base import Query, as_reference, checked, sub_config
from rmbuild.localize.knn import KnnLocalizer


class PflLocalizer:
    """Particle filter: PDR motion model, kNN fixes as measurements (He et al. 2015 PFL, Chen et al. 2018)."""

    name: ClassVar[str] = "pfl"

    def __init__(self, cfg: PflConfig | None = None, knn: KnnConfig | None = None) -> None:
        self.cfg = checked(cfg, PflConfig)
        base = knn or KnnConfig()
        self.knn = KnnLocalizer(KnnConfig(**{**base.__dict__, "k": self.cfg.knn_k}))
        self.diagnostics: dict[str, dict] = {}

    @classmethod
    def from_config(cls, cfg) -> PflLocalizer:
        knn = cfg.knn if cfg is not None and isinstance(getattr(cfg, "knn", None), KnnConfig) else None
        return cls(sub_config(cfg, "pfl", PflConfig), knn)

    def fit(self, ref) -> PflLocalizer:
        self.knn.fit(as_reference(ref, self.knn.cfg.reference))
        return self

    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres in the map frame, causal per walk; NaN before the walk's first usable fix."""
        if self.knn.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.knn.ref.bssids)
        fixes = self.knn.predict_rss(q.rss_dbm)
        out = np.full((len(q), 2), np.nan)
        self.diagnostics = {}
        for wid, rows in q.walks():
            steps = None if q.steps is None else q.steps.get(wid)
            out[rows], self.diagnostics[wid] = self.track(fixes[rows], q.t_s[rows], steps)
        return out

    def summary(self) -> dict:
        fb = sorted({f for d in self.diagnostics.values() for f in d.get("fallbacks", [])})
        return {"fallbacks": fb}

    def track(self, fixes: np.ndarray, t_s: np.ndarray, steps: pd.DataFrame | None) -> tuple[np.ndarray, dict]:
        """Filter one walk: ``fixes`` (n, 2) kNN positions (NaN = none), ``t_s`` (n,) scan times, ``steps``
        the walk's step table. Returns ((n, 2) estimates, diagnostics)."""
        cfg = self.cfg
        n = len(t_s)
        if steps is None or len(steps) == 0:
            return fixes.copy(), {"fallbacks": ["steps:none"]}
        rng = np.random.default_rng(cfg.seed)
        st = steps.sort_values("t_s", kind="stable")
        ts = st["t_s"].to_numpy(dtype=float)
        ln = np.nan_to_num(st["step_length_m"].to_numpy(dtype=float))
        hd = st["heading_rad"].to_numpy(dtype=float)
        p_n = cfg.n_particles
        out = np.full((n, 2), np.nan)
        pos = None
        w = np.full(p_n, 1.0 / p_n)
        rot = rng.uniform(0, 2 * np.pi, p_n) if cfg.heading_init == "uniform" else np.zeros(p_n)
        scale = 1.0 + cfg.step_scale_sd * rng.standard_normal(p_n)
        j = 0
        inv2 = 1.0 / (2.0 * cfg.fix_sd_m ** 2)
        for i in range(n):
            while j < len(ts) and ts[j] <= t_s[i]:
                if pos is not None:
                    step = scale * ln[j] * (1.0 + cfg.step_noise * rng.standard_normal(p_n))
                    ang = hd[j] + rot
                    pos[:, 0] += step * np.cos(ang)
                    pos[:, 1] += step * np.sin(ang)
                    rot = rot + cfg.heading_noise_rad * rng.standard_normal(p_n)
                j += 1
            z = fixes[i]
            if not np.isfinite(z).all():
                if pos is not None:
                    out[i] = (w[:, None] * pos).sum(axis=0)
                continue
            if pos is None:
                pos = z + cfg.init_sd_m * rng.standard_normal((p_n, 2))
            d2 = ((pos - z) ** 2).sum(axis=1)
            lw = np.log(np.maximum(w, 1e-300)) - d2 * inv2
            w = np.exp(lw - lw.max())
            w /= w.sum()
            out[i] = (w[:, None] * pos).sum(axis=0)
            if 1.0 / (w * w).sum() < cfg.resample_ess * p_n:
                idx = np.minimum(np.searchsorted(np.cumsum(w), (rng.random() + np.arange(p_n)) / p_n), p_n - 1)
                pos, rot, scale = pos[idx].copy(), rot[idx], scale[idx]
                w = np.full(p_n, 1.0 / p_n)
        return out, {"fallbacks": []}
