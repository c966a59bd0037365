"""Per-AP RSS clean-up along a walk: Tukey-fence outlier removal, then a 1-D Kalman filter.

UILoc (Chen, Zhang and Xue, Sensors 2018, sec. 4.3) cleans a beacon's RSS series in two levels: L1 keeps the readings of
the last ``window`` samples that lie inside Tukey's fences ``[Q1 − 1.5 IQR, Q3 + 1.5 IQR]`` and replaces
the newest reading by their mean (eq. 20-22); L2 runs a random-walk Kalman filter (F = H = 1, no control)
with process noise Q, measurement noise R and initial covariance P0 (eq. 23-24).

Here the series is one AP's readings over the scans of one walk in time order (a :class:`Query`'s rows).
A scan where the AP is not detected stays NaN (detection pattern unchanged) and does not update the
filter; the Kalman state carries over the gap. Pure functions: arrays in, arrays out.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from rmbuild.localize.base import Query

#: L1 window in samples (the paper's 10 samples at 10 Hz, eq. 20).
TUKEY_WINDOW = 10
#: Tukey fence factor k in Q1 − k·IQR, Q3 + k·IQR (eq. 21).
TUKEY_K = 1.5
#: L2 Kalman process noise Q, measurement noise R (dB²) and initial covariance P0 (sec. 4.3).
KALMAN_Q = 0.015
KALMAN_R = 1.5
KALMAN_P0 = 1.0


def tukey_window_mean(rss: np.ndarray, window: int = TUKEY_WINDOW, k: float = TUKEY_K) -> np.ndarray:
    """L1: each reading replaced by the mean of the readings inside Tukey's fences among the last ``window``
    samples (itself included). ``rss``: (n,) or (n, m) float, time along axis 0, NaN = no reading (kept)."""
    x = np.asarray(rss, dtype=np.float64)
    flat = x.reshape(len(x), -1)
    pad = np.vstack([np.full((window - 1, flat.shape[1]), np.nan), flat])
    win = np.lib.stride_tricks.sliding_window_view(pad, window, axis=0)  # (n, m, window)
    with warnings.catch_warnings():  # an AP unheard over a whole window: all-NaN slices are expected
        warnings.simplefilter("ignore", RuntimeWarning)
        q1, q3 = np.nanquantile(win, [0.25, 0.75], axis=2)
        iqr = q3 - q1
        inside = (win >= (q1 - k * iqr)[..., None]) & (win <= (q3 + k * iqr)[..., None])
        mean = np.nanmean(np.where(inside, win, np.nan), axis=2)
    out = np.where(np.isnan(flat), np.nan, mean)
    return out.reshape(x.shape)


def kalman_1d(rss: np.ndarray, q: float = KALMAN_Q, r: float = KALMAN_R, p0: float = KALMAN_P0) -> np.ndarray:
    """L2: random-walk Kalman filter per column of ``rss`` ((n,) or (n, m), time along axis 0). The state
    starts at a column's first reading; NaN readings are skipped (output NaN, state kept)."""
    x = np.asarray(rss, dtype=np.float64)
    flat = x.reshape(len(x), -1)
    out = np.full_like(flat, np.nan)
    state = np.full(flat.shape[1], np.nan)
    p = np.full(flat.shape[1], p0)
    for t in range(len(flat)):
        z = flat[t]
        ok = ~np.isnan(z)
        new = ok & np.isnan(state)
        state[new] = z[new]
        upd = ok & ~new
        pp = p[upd] + q
        gain = pp / (pp + r)
        state[upd] += gain * (z[upd] - state[upd])
        p[upd] = (1.0 - gain) * pp
        out[t, ok] = state[ok]
    return out.reshape(x.shape)


def filter_rss(rss: np.ndarray, tukey: bool = True, kalman: bool = True) -> np.ndarray:
    """L1 then L2 (either can be switched off) on one walk's scans (n, m) in time order."""
    out = np.asarray(rss, dtype=np.float64)
    if tukey:
        out = tukey_window_mean(out)
    if kalman:
        out = kalman_1d(out)
    return out


def filter_query(query: Query, tukey: bool = True, kalman: bool = True) -> Query:
    """The query with every walk's per-AP RSS series filtered in time order (rows and columns unchanged)."""
    rss = query.rss_dbm.astype(np.float64)
    for _, rows in query.walks():
        rss[rows] = filter_rss(rss[rows], tukey, kalman)
    return dataclasses.replace(query, rss_dbm=rss.astype(np.float32))

