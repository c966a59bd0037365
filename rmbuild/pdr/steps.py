"""Step detection that adapts to the phone, the walker and the way the phone is carried.

Everything works on the accelerometer *magnitude*, which does not depend on how the phone is oriented:

1. The magnitude is put on a uniform grid per run (:mod:`rmbuild.pdr.timebase`: dropouts split runs) and
   band-passed (:data:`BAND_HZ`).
2. **Gait windows** (:func:`gait_windows`): in overlapping windows the normalised autocorrelation gives the
   periodicity and the step period, the RMS the gait intensity. A window is walking when it is periodic
   and moves more than sensor noise (stance / stop detection). The step period is told from the stride
   period by looking at half the strongest lag: a phone in a pocket or a swinging hand sees one leg more
   than the other, so its strongest period is the stride (Rai et al., "Zee: zero-effort crowdsourcing for
   indoor localization", MobiCom 2012, use the same autocorrelation for walk detection and step period).
3. **Steps** (:func:`pick_steps`): peaks of the band-passed magnitude inside walking stretches whose
   prominence is a multiple of the window's RMS (a threshold from the signal itself, so gentle and brisk
   gaits and different phones count alike), at least :data:`MIN_STEP_FRACTION` of the local step period
   apart (the higher of two closer peaks is the step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild.pdr.timebase import Grid, resample

#: Hz; band-pass of the magnitude (2nd-order Butterworth, zero phase): below 0.5 Hz is posture and
#: gravity, above 3 Hz heel-strike detail (a 2.5 Hz fundamental is the fastest walking cadence)
BAND_HZ = (0.5, 3.0)
#: s; gait window length and hop
WINDOW_S, HOP_S = 4.0, 0.5
#: s; the lags searched for a step or stride period (step periods 0.25-1.25 s: cadence 0.8-4 Hz)
MIN_LAG_S, MAX_LAG_S = 0.25, 2.5
#: s; a strongest lag longer than this is a stride, never a step
MAX_STEP_S = 1.25
#: normalised autocorrelation a window needs at its period to count as walking
MIN_PERIODICITY = 0.4
#: a local maximum of the autocorrelation within this many percent of half the strongest lag, with a
#: positive value, makes that half lag the step period (the strongest lag being a stride)
HALF_LAG_TOLERANCE = 0.15
#: a peak within this fraction of the step period of the previous step is the same step
MIN_STEP_FRACTION = 0.6
#: a peak needs a prominence of this multiple of its window's RMS of the band-passed magnitude (a sine has
#: 2.8; chosen on the ILC 2.0 and IPIN 2023 walks and the synthetic carrying modes, docs/notes/formats-real.md)
MIN_PROMINENCE_RMS = 1.5
#: rad/s; RMS rotation rate above which a window is the phone being handled, not carried: a phone swinging
#: in a walker's hand turns at up to ~3.5 rad/s RMS; the IPIN 2023 walks' compass calibration (waving the
#: phone for their first minute) at 3-7 rad/s (median 3.2), walking after it at <= 1.4; ILC 2.0 <= 2.8
HANDLING_RATE_RADPS = 4.0
#: a window's RMS and autocorrelation clip the band-passed magnitude at this many times its median absolute
#: value (a sine's peak is 1.4 times it, heel strikes 2-4 times; 3 cost 0.04 m on ILC F1, 5 about 0.01 m:
#: docs/notes/formats-real.md)
CLIP_MEDIANS = 5.0
#: s; a grid point is moving when the RMS over this window reaches LOCAL_RMS_FRACTION of its gait window's
#: RMS (a walker who stops for a second inside a walking window is standing there)
LOCAL_RMS_S = 1.0
LOCAL_RMS_FRACTION = 0.5


@dataclass(frozen=True)
class GaitWindows:
    """Per gait window (w,): centre time ``t_s``, ``walking`` flag, ``period_s`` step period (NaN when not
    walking), ``rms_mps2`` of the band-passed magnitude, ``periodicity`` (autocorrelation at the period),
    ``handling`` (the phone turning too fast to be carried by a walker)."""

    t_s: np.ndarray
    walking: np.ndarray
    period_s: np.ndarray
    rms_mps2: np.ndarray
    periodicity: np.ndarray
    handling: np.ndarray


@dataclass(frozen=True)
class StepDetection:
    """Detected steps: ``t_s`` (k,) step times; ``period_s`` (k,) local step period; ``walking_s`` total
    walking time (s); ``windows`` the gait windows."""

    t_s: np.ndarray
    period_s: np.ndarray
    walking_s: float
    windows: GaitWindows


def bandpassed_magnitude(grid: Grid, t_s: np.ndarray, acc_mps2: np.ndarray) -> np.ndarray:
    """(m,) band-passed acceleration magnitude on ``grid`` (each run filtered on its own)."""
    from scipy import signal  # imported here: scipy.signal costs ~1 s at import

    mag = np.linalg.norm(np.asarray(acc_mps2, dtype=np.float64), axis=1)
    m = resample(grid, t_s, mag)
    out = np.zeros_like(m)
    hi = min(BAND_HZ[1], 0.45 * grid.fs_hz)
    sos = signal.butter(2, [BAND_HZ[0], hi], btype="band", fs=grid.fs_hz, output="sos")
    for r in grid.runs():
        x = m[r] - m[r].mean() if r.stop > r.start else m[r]
        if len(x) > 15:
            out[r] = signal.sosfiltfilt(sos, x, padlen=min(len(x) - 1, int(3 * grid.fs_hz)))
    return out


def _acf(frames: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation (w, max_lag + 1) of each row of ``frames`` (w, n): at lag L the correlation
    coefficient of the first n - L and the last n - L samples (Zee's normalisation)."""
    x = frames - frames.mean(axis=1, keepdims=True)
    n = x.shape[1]
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(x, nfft, axis=1)
    ac = np.fft.irfft(f * np.conj(f), nfft, axis=1)[:, : max_lag + 1]
    e = np.cumsum(x * x, axis=1)
    lags = np.arange(max_lag + 1)
    head = e[:, n - 1 - lags]                                   # sum of x[0 : n - L]^2
    tail = e[:, -1:] - np.where(lags > 0, e[:, np.maximum(lags - 1, 0)], 0.0)   # sum of x[L:]^2
    return ac / np.sqrt(np.maximum(head * tail, 1e-18))


def _period(r: np.ndarray, fs: float) -> tuple[float, float]:
    """Step period (s) and periodicity of one window's autocorrelation ``r`` (lags 0..L); NaN period when
    there is no local maximum in the searched lags."""
    lo = max(int(round(MIN_LAG_S * fs)), 1)
    hi = min(int(round(MAX_LAG_S * fs)), len(r) - 2)
    if hi <= lo:
        return np.nan, 0.0
    i = np.arange(lo, hi + 1)
    peaks = i[(r[i] >= r[i - 1]) & (r[i] > r[i + 1])]
    if len(peaks) == 0:
        return np.nan, 0.0
    best = float(r[peaks].max())
    first = int(peaks[np.argmax(r[peaks] >= 0.8 * best)])   # the shortest lag nearly as strong as the best
    near = peaks[np.abs(peaks - first / 2) <= HALF_LAG_TOLERANCE * first / 2]
    near = near[r[near] > 0]
    if len(near):
        return float(near[np.argmax(r[near])]) / fs, float(r[first])
    if first / fs > MAX_STEP_S:
        return first / (2 * fs), float(r[first])
    return first / fs, float(r[first])


def _clip(frames: np.ndarray) -> np.ndarray:
    """Each row clipped at ± CLIP_MEDIANS times its median absolute value: a gait's waveform without the one
    jolt of a turn on the spot or a knock (which would otherwise dominate a whole window's RMS and
    autocorrelation and hide the steps around it)."""
    cap = CLIP_MEDIANS * np.median(np.abs(frames), axis=1, keepdims=True)
    return np.clip(frames, -cap, cap)


def gait_windows(grid: Grid, s: np.ndarray, min_rms_mps2: float, rate_radps: np.ndarray | None = None,
                 ) -> GaitWindows:
    """Walking flag, step period and intensity of overlapping windows over each run of ``s`` (on ``grid``).

    ``min_rms_mps2``: RMS of the band-passed magnitude below which a window is standing (sensor noise and
    hand tremor stay well below it). ``rate_radps``: the gyro's rotation rate magnitude on the grid, when
    there is a gyro: a window turning faster than :data:`HANDLING_RATE_RADPS` (RMS) is the phone being
    handled (waved to calibrate the compass, picked up, shaken), not walked with, whatever its rhythm.
    """
    from numpy.lib.stride_tricks import sliding_window_view

    fs = grid.fs_hz
    n_win, hop = int(round(WINDOW_S * fs)), max(int(round(HOP_S * fs)), 1)
    max_lag = int(round(MAX_LAG_S * fs)) + 1
    t_c, per, rho, rms, rot = [], [], [], [], []
    for r in grid.runs():
        x = s[r]
        if len(x) < max(int(1.5 * fs), 8):
            continue
        w = min(n_win, len(x))
        starts = np.arange(0, len(x) - w + 1, hop)
        if starts[-1] != len(x) - w:
            starts = np.r_[starts, len(x) - w]
        frames = sliding_window_view(x, w)[starts]
        frames = _clip(frames)
        ac = _acf(frames, min(max_lag, w - 2))
        for k in range(len(starts)):
            p, q = _period(ac[k], fs)
            per.append(p)
            rho.append(q)
        rms.append(np.sqrt(np.mean(frames**2, axis=1)))
        t_c.append(grid.t_s[r][starts + w // 2])
        if rate_radps is not None:
            rot.append(np.sqrt(np.mean(sliding_window_view(rate_radps[r], w)[starts] ** 2, axis=1)))
    if not t_c:
        z = np.zeros(0)
        return GaitWindows(z, np.zeros(0, dtype=bool), z, z, z, np.zeros(0, dtype=bool))
    t_c_a, rms_a = np.concatenate(t_c), np.concatenate(rms)
    per_a, rho_a = np.asarray(per), np.asarray(rho)
    handling = np.concatenate(rot) > HANDLING_RATE_RADPS if rot else np.zeros(len(t_c_a), dtype=bool)
    walking = np.isfinite(per_a) & (rho_a >= MIN_PERIODICITY) & (rms_a >= min_rms_mps2) & ~handling
    return GaitWindows(t_c_a, walking, np.where(walking, per_a, np.nan), rms_a, rho_a, handling)


def _local_rms(grid: Grid, s: np.ndarray) -> np.ndarray:
    """RMS of ``s`` over a centred :data:`LOCAL_RMS_S` window (within each run)."""
    out = np.zeros_like(s)
    h = max(int(round(LOCAL_RMS_S * grid.fs_hz / 2)), 1)
    for r in grid.runs():
        c = np.r_[0.0, np.cumsum(s[r] ** 2)]
        i = np.arange(r.stop - r.start)
        lo, hi = np.maximum(i - h, 0), np.minimum(i + h + 1, len(i))
        out[r] = np.sqrt(np.maximum(c[hi] - c[lo], 0.0) / (hi - lo))
    return out


def _walking_on_grid(grid: Grid, s: np.ndarray, win: GaitWindows, min_rms_mps2: float,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per grid point: walking flag (inside a walking window and moving there: local RMS above the floor
    and a fraction of the window's), the step period and RMS of the nearest walking window."""
    m = len(grid.t_s)
    if not win.walking.any():
        return np.zeros(m, dtype=bool), np.full(m, np.nan), np.full(m, np.nan)
    tw, pw, rw = win.t_s[win.walking], win.period_s[win.walking], win.rms_mps2[win.walking]
    j = _nearest(tw, grid.t_s)
    local = _local_rms(grid, s)
    walking = (np.abs(grid.t_s - tw[j]) <= WINDOW_S / 2) & (local >= np.maximum(min_rms_mps2,
                                                                                 LOCAL_RMS_FRACTION * rw[j]))
    # where the nearest window of all is one of handling, nobody is walking
    walking &= ~win.handling[_nearest(win.t_s, grid.t_s)]
    return walking, pw[j], rw[j]


def _nearest(sorted_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index into ``sorted_t`` (non-empty) of the value nearest to each of ``t``."""
    if len(sorted_t) == 1:
        return np.zeros(len(t), dtype=np.int64)
    j = np.clip(np.searchsorted(sorted_t, t), 1, len(sorted_t) - 1)
    return np.where(np.abs(t - sorted_t[j - 1]) <= np.abs(sorted_t[j] - t), j - 1, j)


def pick_steps(grid: Grid, s: np.ndarray, win: GaitWindows, min_rms_mps2: float) -> StepDetection:
    """Step times from the band-passed magnitude ``s`` on ``grid`` and its gait windows."""
    from scipy import signal  # imported here: scipy.signal costs ~1 s at import

    walking, period, rms = _walking_on_grid(grid, s, win, min_rms_mps2)
    t_out: list[np.ndarray] = []
    p_out: list[np.ndarray] = []
    walking_s = 0.0
    for r in grid.runs():
        tr, sr, wr = grid.t_s[r], s[r], walking[r]
        walking_s += float(wr.sum()) / grid.fs_hz
        pk, props = signal.find_peaks(sr, prominence=0.0)
        ok = wr[pk] & (props["prominences"] >= MIN_PROMINENCE_RMS * rms[r][pk]) & (sr[pk] > 0)
        pk = _thin(tr, sr, pk[ok], period[r])
        t_out.append(tr[pk])
        p_out.append(period[r][pk])
    return StepDetection(_cat(t_out, np.float64), _cat(p_out, np.float64), walking_s, win)


def _thin(t: np.ndarray, s: np.ndarray, pk: np.ndarray, period: np.ndarray) -> np.ndarray:
    """Peaks closer than MIN_STEP_FRACTION of the local step period to the previous kept peak: the higher
    one of the two is kept."""
    out: list[int] = []
    for i in pk.tolist():
        if out and t[i] - t[out[-1]] < MIN_STEP_FRACTION * period[i]:
            if s[i] > s[out[-1]]:
                out[-1] = i
            continue
        out.append(i)
    return np.asarray(out, dtype=np.int64)


def _cat(parts: list[np.ndarray], dtype: type) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
