"""Step detection on the acceleration magnitude (docs/formats-real.md).

Two detectors, both working on a magnitude signal resampled to a uniform rate and low-passed
(:func:`prepare_magnitude`):

- :func:`detect_steps_peak_valley` — subway-station paper: a step is a peak followed by a valley whose swing exceeds a
  threshold, consecutive steps at least 250 ms apart (so a peak followed by several valleys counts once);
- :func:`detect_steps_pan_tompkins` — Becker et al. 2015: Pan-Tompkins-style derivative (eq. 6, negative values
  dropped) and squaring (eq. 7), a step at each local maximum above a threshold, then a 300 ms pause.
"""

from __future__ import annotations

import numpy as np

from rmbuild.config.pdr import PdrConfig


def prepare_magnitude(t_s: np.ndarray, acc_mps2: np.ndarray, cfg: PdrConfig) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration magnitude resampled to ``cfg.sample_hz`` and low-passed at ``cfg.lowpass_hz``.

    ``t_s``: (n,) increasing sample times in s; ``acc_mps2``: (n, 3) specific force in m/s² (any frame).
    Returns ``(tu_s, mag_mps2)``, both (m,), on the uniform grid ``t_s[0] + k / sample_hz``.
    """
    from scipy import signal  # imported here: scipy.signal costs ~1 s at import

    t_s = np.asarray(t_s, dtype=np.float64)
    mag = np.linalg.norm(np.asarray(acc_mps2, dtype=np.float64), axis=1)
    if len(t_s) < 2:
        return t_s.copy(), mag
    dt = 1.0 / cfg.sample_hz
    tu = t_s[0] + np.arange(int(np.floor((t_s[-1] - t_s[0]) / dt)) + 1) * dt
    mu = np.interp(tu, t_s, mag)
    if cfg.lowpass_hz > 0 and len(mu) > 15:
        sos = signal.butter(2, cfg.lowpass_hz, btype="low", fs=cfg.sample_hz, output="sos")
        mu = signal.sosfiltfilt(sos, mu, padlen=min(len(mu) - 1, 3 * int(cfg.sample_hz)))
    return tu, mu


def detect_steps_peak_valley(tu_s: np.ndarray, mag: np.ndarray, cfg: PdrConfig) -> np.ndarray:
    """Seed 003 step detector. Returns int indices into ``tu_s`` of the step peaks, ascending.

    Extrema are scanned in time order; the highest peak since the last accepted valley is the candidate;
    a valley at least ``pv_min_swing_mps2`` below it, with the candidate at least ``pv_min_interval_s``
    after the previous step, accepts it.
    """
    from scipy import signal  # imported here: scipy.signal costs ~1 s at import

    if len(mag) < 3:
        return np.zeros(0, dtype=np.int64)
    peaks, _ = signal.find_peaks(mag)
    valleys, _ = signal.find_peaks(-mag)
    kind = np.r_[np.ones(len(peaks), dtype=np.int8), -np.ones(len(valleys), dtype=np.int8)]
    idx = np.r_[peaks, valleys]
    order = np.argsort(idx, kind="stable")
    kind, idx = kind[order], idx[order]
    swing = cfg.pv_min_swing_mps2
    min_dt = cfg.pv_min_interval_s
    out: list[int] = []
    cand = -1
    last_t = -np.inf
    for k, i in zip(kind.tolist(), idx.tolist()):
        if k > 0:
            if cand < 0 or mag[i] > mag[cand]:
                cand = i
        elif cand >= 0 and mag[cand] - mag[i] >= swing:
            if tu_s[cand] - last_t >= min_dt:
                out.append(cand)
                last_t = tu_s[cand]
            cand = -1
    return np.asarray(out, dtype=np.int64)


def pan_tompkins_signal(mag: np.ndarray) -> np.ndarray:
    """Seed 002 eq. 6-7: y(n) = max(0, [2x(n) + x(n-1) - x(n-3) - 2x(n-4)] / 4), then (1 + y)² - 1."""
    x = np.asarray(mag, dtype=np.float64)
    y = np.zeros_like(x)
    if len(x) > 4:
        y[4:] = (2 * x[4:] + x[3:-1] - x[1:-3] - 2 * x[:-4]) / 4.0
    y = np.maximum(y, 0.0)
    return (1.0 + y) ** 2 - 1.0


def detect_steps_pan_tompkins(tu_s: np.ndarray, mag: np.ndarray, cfg: PdrConfig) -> np.ndarray:
    """Seed 002 step detector. Returns int indices into ``tu_s`` of the detected steps, ascending.

    A sample is a step when it is a local maximum of the prepared signal (compared with its two
    neighbours, "the last three values") above ``pt_threshold``; detection then pauses
    ``pt_refractory_s``. The step time is the prepared signal's peak, i.e. the steepest rise of the
    magnitude just before its maximum.
    """
    s = pan_tompkins_signal(mag)
    if len(s) < 3:
        return np.zeros(0, dtype=np.int64)
    cand = np.flatnonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:]) & (s[1:-1] > cfg.pt_threshold)) + 1
    out: list[int] = []
    last_t = -np.inf
    for i in cand.tolist():
        if tu_s[i] - last_t >= cfg.pt_refractory_s:
            out.append(i)
            last_t = tu_s[i]
    return np.asarray(out, dtype=np.int64)


def detect_steps(t_s: np.ndarray, acc_mps2: np.ndarray, cfg: PdrConfig,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detect steps with ``cfg.step_detector``.

    Returns ``(step_t_s, tu_s, mag)``: (k,) step times in s, and the prepared uniform magnitude signal
    (for step-length models that need it).
    """
    tu, mag = prepare_magnitude(t_s, acc_mps2, cfg)
    if cfg.step_detector == "peak_valley":
        idx = detect_steps_peak_valley(tu, mag, cfg)
    else:
        idx = detect_steps_pan_tompkins(tu, mag, cfg)
    return tu[idx], tu, mag
