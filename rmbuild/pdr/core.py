"""Raw phone IMU -> per-step poses in the walk's own frame (the same table the foot-IMU path produces)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rmbuild.config.pdr import PdrConfig
from rmbuild.geometry import wrap
from rmbuild.pdr.heading import interval_mean
from rmbuild.pdr.length import step_lengths, step_swings
from rmbuild.pdr.quality import PdrReport, assess
from rmbuild.pdr.signals import ImuSignals, StepPoses
from rmbuild.pdr.steps import GaitWindows, bandpassed_magnitude, gait_windows, pick_steps
from rmbuild.pdr.timebase import TimeIssue, dropouts, main_block, resample, uniform_grid, within
from rmbuild.pdr.yaw import relative_yaw

#: m/s²; RMS of the band-passed acceleration magnitude below which a gait window is standing. Measured on
#: the IPIN 2023 and ILC 2.0 phones: standing 0.02-0.1, the gentlest walking 0.5-1 (docs/notes/formats-real.md)
MIN_WALK_RMS_MPS2 = 0.25


@dataclass
class PdrResult:
    """The poses of one walk and what the PDR found on the way (:class:`rmbuild.pdr.quality.PdrReport`)."""

    poses: StepPoses
    report: PdrReport


def integrate_steps(t0_s: float, step_t_s: np.ndarray, length_m: np.ndarray, heading_rad: np.ndarray,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Dead-reckon steps: pose k = pose k-1 + length_k * (cos h_k, sin h_k), heading h_k.

    Inputs (k,); returns ``(t_s, x_m, y_m, heading_rad)``, each (k + 1,), starting at (t0, 0, 0, 0).
    """
    x = np.r_[0.0, np.cumsum(length_m * np.cos(heading_rad))]
    y = np.r_[0.0, np.cumsum(length_m * np.sin(heading_rad))]
    return np.r_[t0_s, step_t_s], x, y, np.r_[0.0, heading_rad]


def integrate_increments(t0_s: float, t_s: np.ndarray, dx_m: np.ndarray, dy_m: np.ndarray,
                         dtheta_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Compose body-frame increments (Gu et al. 2017 eq. 6-8): x_k = x_{k-1} + dx cos θ_{k-1} - dy sin θ_{k-1},
    y_k likewise, θ_k = θ_{k-1} + dθ. Inputs (k,); returns (k + 1,) arrays starting at (t0, 0, 0, 0)."""
    th = np.r_[0.0, np.cumsum(dtheta_rad)]
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    x = np.r_[0.0, np.cumsum(dx_m * c - dy_m * s)]
    y = np.r_[0.0, np.cumsum(dx_m * s + dy_m * c)]
    return np.r_[t0_s, t_s], x, y, th


#: step periods; each step's heading is the mean over [t - 1, t + 1] periods: one stride centred on the step
#: (a swinging phone's yaw oscillates once per stride; a window of the step's own interval, or one stride
#: ending at the step, did worse on the ILC 2.0 and IPIN 2023 walks, docs/notes/formats-real.md)
HEADING_WINDOW_PERIODS = (-1.0, 1.0)
# deg; the absolute yaw is kept only while the phone's screen faces at most this far from up (held in front,
# flat to pitched up: MS ILC traces 0-14°, IPIN 93 % of the samples; a phone at the ear, swinging in a hand
# or in a pocket is upright: 79-94° on the synthetic carries)
IN_FRONT_MAX_TILT_DEG = 70.0


def yaw_sigma(accuracy: np.ndarray, cfg: PdrConfig) -> np.ndarray:
    """1-sigma in rad of an absolute yaw reading per Android accuracy flag (unknown flags -> flag 0's)."""
    table = np.asarray(cfg.yaw_sigma_by_accuracy_rad, dtype=np.float64)
    a = np.asarray(accuracy)
    return np.where((a >= 0) & (a <= 3), table[np.clip(a, 0, 3).astype(np.int64)], table[0])


def clean_clock(imu: ImuSignals, cfg: PdrConfig) -> tuple[ImuSignals, list[TimeIssue]]:
    """The signals without stray timestamps (accelerometer blocks cut off by a gap > ``cfg.max_gap_s``,
    gyro / yaw samples outside the accelerometer's span) and without repeated times; the issues found.
    Raises :class:`rmbuild.pdr.timebase.ImuTimeError` on a clock jump between two long blocks."""
    keep, issues = main_block(imu.t_acc_s, cfg.max_gap_s, "acc")
    keep &= np.r_[True, np.diff(imu.t_acc_s) > 0]
    ta = imu.t_acc_s[keep]
    lo, hi = float(ta[0]), float(ta[-1])
    kg, ig = within(imu.t_gyro_s, lo, hi, "gyro", 1.0)
    kg &= np.r_[True, np.diff(imu.t_gyro_s) > 0]
    ky, iy = within(imu.t_yaw_s, lo, hi, "yaw", 1.0)
    ky &= np.r_[True, np.diff(imu.t_yaw_s) > 0]
    quat = imu.quat_xyzw[ky] if len(imu.quat_xyzw) == len(imu.t_yaw_s) else np.zeros((0, 4))
    out = replace(imu, t_acc_s=ta, acc_mps2=imu.acc_mps2[keep], t_gyro_s=imu.t_gyro_s[kg],
                  gyro_radps=imu.gyro_radps[kg], t_yaw_s=imu.t_yaw_s[ky], yaw_abs_rad=imu.yaw_abs_rad[ky],
                  yaw_accuracy=imu.yaw_accuracy[ky], quat_xyzw=quat)
    return out, issues + ig + iy + dropouts(ta, "acc")


def _absolute_yaw(imu: ImuSignals, t0: float, step_t: np.ndarray, w0: np.ndarray, w1: np.ndarray,
                  cfg: PdrConfig) -> tuple[np.ndarray, np.ndarray]:
    """(k + 1,) absolute yaw at the start and per step (mean over [w0, w1]) and its 1-sigma from the accuracy
    flags; NaN without a rotation vector."""
    k = len(step_t)
    if len(imu.t_yaw_s) == 0:
        return np.full(k + 1, np.nan), np.full(k + 1, np.nan)
    yaw_u = np.unwrap(np.asarray(imu.yaw_abs_rad, dtype=np.float64))
    yaw0 = float(np.interp(t0, imu.t_yaw_s, yaw_u))
    yaw_abs = wrap(np.r_[yaw0, interval_mean(imu.t_yaw_s, yaw_u, w0, w1) if k else np.zeros(0)])
    at = np.interp(np.r_[t0, step_t], imu.t_yaw_s, np.arange(len(imu.t_yaw_s)))
    return yaw_abs, yaw_sigma(np.asarray(imu.yaw_accuracy)[np.rint(at).astype(np.int64)], cfg)


def _not_in_front(imu: ImuSignals, t0: float, w0: np.ndarray, w1: np.ndarray) -> np.ndarray:
    """(k + 1,) true at the start and the steps where the phone is not held in front: its screen faces more
    than IN_FRONT_MAX_TILT_DEG away from up (the mean specific force over the step's interval). The
    absolute yaw is the azimuth of the phone's forward axis (:func:`rmbuild.pdr.heading.yaw_from_quat`),
    which is the walking direction only for a phone held in front; at the ear, in a swinging hand or in a
    pocket it is off by 55-168° (docs/notes/formats-real.md)."""
    t = np.asarray(imu.t_acc_s, dtype=np.float64)
    a = np.asarray(imu.acc_mps2, dtype=np.float64)
    lo, hi = np.r_[t0, w0], np.r_[min(t0 + 1.0, float(t[-1])), w1]
    m = np.column_stack([interval_mean(t, a[:, j], lo, hi) for j in range(3)])
    up_z = m[:, 2] / np.maximum(np.linalg.norm(m, axis=1), 1e-9)
    return up_z < np.cos(np.deg2rad(IN_FRONT_MAX_TILT_DEG))


def _handled_at(win: GaitWindows, t_s: np.ndarray) -> np.ndarray:
    """(k,) true where the gait window nearest to each time is one of the phone being handled."""
    if len(win.t_s) == 0:
        return np.zeros(len(t_s), dtype=bool)
    j = np.clip(np.searchsorted(win.t_s, t_s), 1, max(len(win.t_s) - 1, 1))
    if len(win.t_s) > 1:
        j = np.where(np.abs(t_s - win.t_s[j - 1]) <= np.abs(win.t_s[j] - t_s), j - 1, j)
    else:
        j = np.zeros(len(t_s), dtype=np.int64)
    return win.handling[j]


def _heading_source(imu: ImuSignals, cfg: PdrConfig) -> str:
    has_gyro, has_yaw = len(imu.t_gyro_s) >= 2, len(imu.t_yaw_s) >= 2
    if cfg.heading_source == "rotation_vector" or (cfg.heading_source == "auto" and not has_gyro):
        if not has_yaw:
            raise ValueError("no gyroscope and no rotation-vector / AHRS samples: no heading"
                             if cfg.heading_source == "auto" else
                             "no rotation-vector / AHRS samples for heading_source = 'rotation_vector'")
        return "rotation_vector"
    if not has_gyro:
        raise ValueError("no gyroscope samples for heading_source = 'gyro'")
    return "gyro"


def run_pdr(imu: ImuSignals, cfg: PdrConfig) -> PdrResult:
    """Steps, heading, step length and integration for one walk of phone IMU data.

    Raises ValueError when a signal the configuration needs is missing (no accelerometer; no heading
    source), :class:`rmbuild.pdr.timebase.ImuTimeError` (a ValueError) on a clock jump.
    """
    if len(imu.t_acc_s) < 2:
        raise ValueError("no accelerometer samples")
    imu, issues = clean_clock(imu, cfg)
    if len(imu.t_acc_s) < 2:
        raise ValueError("fewer than 2 accelerometer samples with distinct times")
    source = _heading_source(imu, cfg)
    t0 = float(imu.t_acc_s[0])
    grid = uniform_grid(imu.t_acc_s, "acc")
    s = bandpassed_magnitude(grid, imu.t_acc_s, imu.acc_mps2)
    rate = (resample(grid, imu.t_gyro_s, np.linalg.norm(imu.gyro_radps, axis=1)) if len(imu.t_gyro_s) >= 2
            else None)
    det = pick_steps(grid, s, gait_windows(grid, s, MIN_WALK_RMS_MPS2, rate), MIN_WALK_RMS_MPS2)
    step_t, period = det.t_s, det.period_s
    k = len(step_t)
    w0, w1 = step_t + HEADING_WINDOW_PERIODS[0] * period, step_t + HEADING_WINDOW_PERIODS[1] * period
    yaw = relative_yaw(imu, source, t0)
    rel = interval_mean(yaw.t_s, yaw.yaw_rad, w0, w1) if k else np.zeros(0)
    # the absolute yaw over the step's own interval: the optimizer links more ILC F1 walks with it (78 of 106)
    # than with the stride window (68), docs/formats-real.md
    yaw_abs, sig = _absolute_yaw(imu, t0, step_t, step_t - period, step_t, cfg)
    # while the phone is handled (waved, shaken) its yaw says nothing about a walking direction
    handled = _handled_at(det.windows, np.r_[t0, step_t])
    yaw_abs[handled], sig[handled] = np.nan, np.nan
    aside = _not_in_front(imu, t0, step_t - period, step_t) & np.isfinite(yaw_abs)
    yaw_abs[aside], sig[aside] = np.nan, np.nan
    turn = np.interp(step_t + period / 2, yaw.t_s, yaw.yaw_rad) - np.interp(step_t - period / 2, yaw.t_s, yaw.yaw_rad)
    length = step_lengths(step_swings(step_t, period, grid.t_s, s), turn, cfg)
    t, x, y, h = integrate_steps(t0, step_t, length, rel)
    poses = StepPoses(t_s=t, x_m=x, y_m=y, heading_rad=wrap(h), yaw_abs_rad=yaw_abs,
                      yaw_abs_sigma_rad=sig, step_freq_hz=np.r_[np.nan, 1.0 / period],
                      step_length_m=np.r_[0.0, length])
    rep = assess(poses, det, yaw, issues, float(imu.t_acc_s[-1]) - t0)
    rep.yaw_abs_not_in_front = int(aside.sum())
    return PdrResult(poses, rep)


def poses_from_increments(t0_s: float, t_s: np.ndarray, dx_m: np.ndarray, dy_m: np.ndarray,
                          dtheta_rad: np.ndarray) -> StepPoses:
    """Per-step poses from foot-IMU step increments (no absolute yaw: NaN)."""
    t, x, y, h = integrate_increments(t0_s, t_s, dx_m, dy_m, dtheta_rad)
    dt = np.diff(np.asarray(t_s, dtype=np.float64))
    f = np.where((dt > 0) & (dt <= 1.5), 1.0 / np.where(dt > 0, dt, 1.0), np.nan)
    freq = np.r_[np.nan, np.nan, f] if len(t_s) else np.full(1, np.nan)
    n = len(t)
    return StepPoses(t_s=t, x_m=x, y_m=y, heading_rad=wrap(h), yaw_abs_rad=np.full(n, np.nan),
                     yaw_abs_sigma_rad=np.full(n, np.nan), step_freq_hz=freq,
                     step_length_m=np.r_[0.0, np.hypot(dx_m, dy_m)])
