"""Floor changes within a walk from a phone barometer: sustained height changes of a storey or so.

The pressure is turned into a relative height (the barometric formula's slope near the ground,
:data:`M_PER_HPA`), smoothed with a running median (a phone barometer's noise is a few hundredths of a
hPa, i.e. tens of centimetres), then followed by a level with hysteresis: while the height stays within
:data:`MIN_CHANGE_M` of the level, the level follows it slowly (weather drift: about 1 hPa in hours); once
it leaves, a change has begun where the height last left the level's band, and ends when the height is
still again (within :data:`STILL_RANGE_M` over :data:`STILL_S`), where the level settles anew. A change of at
least :data:`MIN_CHANGE_M` is a floor change. The band makes the start it finds lag by up to :data:`BAND_M` of
climb and the stillness test makes the end late, so a found change is then located by a least-squares fit
of a ramp (level, linear change, level) to the raw readings around it (:data:`FIT_MARGIN_S` either side):
its start, end and height come from the fit, and its *midpoint*, where a walk is cut, is the ramp's middle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: m per hPa: the slope of the standard atmosphere's height vs pressure near sea level (~8.3 m/hPa at
#: 1013 hPa, 15 °C; 8.8 at 960 hPa)
M_PER_HPA = 8.4
#: s; running-median window of the smoothed height
SMOOTH_S = 5.0
#: m; the smallest floor change (storeys are 3-5 m; a ramp or a mezzanine of less is not a floor)
MIN_CHANGE_M = 2.0
#: m; the band around the level within which the height counts as "on the level" (noise + short drift)
BAND_M = 0.6
#: s; time constant of the level following the height inside the band (weather drift)
DRIFT_TAU_S = 120.0
#: s, m; the height is "still" again once it stays within STILL_RANGE_M over STILL_S (stairs and lifts
#: climb 0.1-2 m/s: 0.5 m or more in 5 s)
STILL_S = 5
STILL_RANGE_M = 0.3
#: s; the ramp fit looks this far before the found start and after the found end (the band's lag is a few s)
FIT_MARGIN_S = 10.0
#: s; the grid of the ramp's start and end times tried by the fit
FIT_GRID_S = 0.25


@dataclass(frozen=True)
class FloorChange:
    """A floor change: start, end and midpoint time (s) and the height change (m, up positive)."""

    t_start_s: float
    t_end_s: float
    dh_m: float
    t_mid_s: float


def smoothed_height(t_s: np.ndarray, p_hpa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(1-s grid times, relative height in m on that grid): per-second medians of the pressure, running
    median over :data:`SMOOTH_S`, converted to height (0 at the start). A second's median stands at the
    middle of that second."""
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(p_hpa, dtype=float)
    ok = np.isfinite(t) & np.isfinite(p)
    t, p = t[ok], p[ok]
    if len(t) < 2:
        return np.zeros(0), np.zeros(0)
    sec = np.floor(t - t[0]).astype(np.int64)
    grid = np.unique(sec)
    per_s = np.array([np.median(p[sec == s]) for s in grid])
    half = int(SMOOTH_S // 2)
    sm = np.array([np.median(per_s[max(0, i - half):i + half + 1]) for i in range(len(per_s))])
    return t[0] + grid.astype(float) + 0.5, -(sm - sm[0]) * M_PER_HPA


def floor_changes(t_s: np.ndarray, p_hpa: np.ndarray) -> list[FloorChange]:
    """The floor changes of one walk's barometer readings (times in s, pressure in hPa)."""
    t, h = smoothed_height(t_s, p_hpa)
    out: list[FloorChange] = []
    if len(t) < 3:
        return out
    level, left, i = h[0], t[0], 1
    while i < len(t):
        dt = t[i] - t[i - 1]
        if abs(h[i] - level) <= BAND_M:
            level += (h[i] - level) * min(1.0, dt / DRIFT_TAU_S)
            left = t[i]
            i += 1
            continue
        j = i  # off the level: follow the height until it is still again
        while j + STILL_S < len(t) and np.ptp(h[j:j + STILL_S + 1]) >= STILL_RANGE_M:
            j += 1
        new = float(np.median(h[j:j + STILL_S + 1]))
        if abs(new - level) >= MIN_CHANGE_M:
            out.append(_fit_ramp(t_s, p_hpa, float(left), float(t[j])))
        level, left = new, float(t[j])  # still again: the new level (a smaller step: drift, a ramp)
        i = j + 1
    return out


def _fit_ramp(t_s: np.ndarray, p_hpa: np.ndarray, t0: float, t1: float) -> FloorChange:
    """The least-squares ramp (level, linear change from ta to tb, level) through the raw readings within
    :data:`FIT_MARGIN_S` of [t0, t1]; ta, tb on a :data:`FIT_GRID_S` grid, the two levels solved for."""
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(p_hpa, dtype=float)
    m = np.isfinite(t) & np.isfinite(p) & (t >= t0 - FIT_MARGIN_S) & (t <= t1 + FIT_MARGIN_S)
    t, h = t[m], -(p[m] - np.median(p[m])) * M_PER_HPA
    grid = np.arange(max(t0 - FIT_MARGIN_S, t[0]), min(t1 + FIT_MARGIN_S, t[-1]) + FIT_GRID_S / 2, FIT_GRID_S)
    ia, ib = np.triu_indices(len(grid), k=1)
    ta, tb = grid[ia], grid[ib]
    best = (np.inf, t0, t1, 0.0)
    for s in range(0, len(ta), _FIT_BLOCK):
        a, b = ta[s:s + _FIT_BLOCK, None], tb[s:s + _FIT_BLOCK, None]
        r = np.clip((t[None, :] - a) / (b - a), 0.0, 1.0)  # h = L0 (1 - r) + L1 r
        s00, s01, s11 = ((1 - r) ** 2).sum(1), ((1 - r) * r).sum(1), (r ** 2).sum(1)
        y0, y1 = ((1 - r) * h).sum(1), (r * h).sum(1)
        det = s00 * s11 - s01 ** 2
        ok = det > 1e-9
        det = np.where(ok, det, 1.0)
        l0, l1 = (s11 * y0 - s01 * y1) / det, (s00 * y1 - s01 * y0) / det
        sse = np.where(ok, ((h[None, :] - l0[:, None] * (1 - r) - l1[:, None] * r) ** 2).sum(1), np.inf)
        k = int(np.argmin(sse))
        if sse[k] < best[0]:
            best = (float(sse[k]), float(a[k, 0]), float(b[k, 0]), float(l1[k] - l0[k]))
    _, fa, fb, dh = best
    return FloorChange(fa, fb, dh, 0.5 * (fa + fb))


#: ramp candidates per block of the fit (bounds memory: block x readings floats)
_FIT_BLOCK = 2000
