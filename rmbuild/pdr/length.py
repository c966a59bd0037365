"""Step length models: fixed, linear in step frequency (He et al. 2015: S = alpha f + beta), Weinberg."""

from __future__ import annotations

import numpy as np

from rmbuild.config.pdr import PdrConfig


def step_frequency(step_t_s: np.ndarray, t0_s: float, max_interval_s: float) -> np.ndarray:
    """(k,) step frequency in Hz of each step: 1 / (time since the previous step); NaN for the first step of
    the walk (``t0_s`` is the recording start, not a step) and when the interval exceeds ``max_interval_s``
    (the walker had stopped)."""
    t = np.asarray(step_t_s, dtype=np.float64)
    dt = np.diff(t, prepend=np.nan)
    with np.errstate(divide="ignore"):
        f = 1.0 / dt
    return np.where((dt > 0) & (dt <= max_interval_s), f, np.nan)


def step_lengths(step_t_s: np.ndarray, freq_hz: np.ndarray, tu_s: np.ndarray | None, mag: np.ndarray | None,
                 cfg: PdrConfig) -> np.ndarray:
    """(k,) step lengths in m for steps at ``step_t_s`` with frequencies ``freq_hz`` (NaN = unknown, replaced
    by the walk's median, or 1.8 Hz when none is known). ``tu_s``/``mag``: the prepared magnitude signal,
    needed by "weinberg" (per step: a_max - a_min over the samples since the previous step)."""
    k = len(step_t_s)
    if cfg.step_length_model == "fixed":
        s = np.full(k, cfg.step_length_m)
    elif cfg.step_length_model == "frequency":
        f = np.asarray(freq_hz, dtype=np.float64)
        fill = float(np.nanmedian(f)) if np.isfinite(f).any() else 1.8
        s = cfg.freq_alpha * np.where(np.isfinite(f), f, fill) + cfg.freq_beta
    else:
        if tu_s is None or mag is None or len(tu_s) == 0:
            raise ValueError("the weinberg step length model needs the magnitude signal")
        t = np.asarray(step_t_s, dtype=np.float64)
        prev = np.r_[t[:1] - cfg.max_step_interval_s, t[:-1]] if k else t
        prev = np.maximum(prev, t - cfg.max_step_interval_s)
        # window (previous step, this step]: one full gait cycle including this step's peak
        lo = np.searchsorted(tu_s, prev, side="left")
        hi = np.searchsorted(tu_s, t, side="right")
        s = np.empty(k)
        for i in range(k):
            seg = mag[lo[i]:max(hi[i], lo[i] + 1)]
            s[i] = cfg.weinberg_k * max(float(seg.max() - seg.min()), 0.0) ** 0.25 if len(seg) else np.nan
        s = np.where(np.isfinite(s), s, cfg.step_length_m)
    return np.clip(s, cfg.min_step_m, cfg.max_step_m)
