"""Raw phone IMU -> per-step poses in the walk's own frame (the same table the foot-IMU path produces)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.config.pdr import PdrConfig
from rmbuild.pdr.heading import gyro_yaw, interval_mean, wrap_angle
from rmbuild.pdr.length import step_frequency, step_lengths
from rmbuild.pdr.steps import detect_steps


@dataclass
class ImuSignals:
    """Raw IMU series of one walk, each sorted by time (s, one common clock).

    ``acc_mps2``: (n, 3) accelerometer (specific force, device frame). ``yaw_abs_rad``: (m,) absolute yaw
    (ENU, CCW from east) at ``t_yaw_s`` from the rotation vector / AHRS, with Android accuracy flags
    ``yaw_accuracy`` (m,) int (0..3; -1 = unknown). ``gyro_radps``: (k, 3) body rates (device frame).
    Missing series are empty arrays.
    """

    t_acc_s: np.ndarray
    acc_mps2: np.ndarray
    t_yaw_s: np.ndarray
    yaw_abs_rad: np.ndarray
    yaw_accuracy: np.ndarray
    t_gyro_s: np.ndarray
    gyro_radps: np.ndarray


@dataclass
class StepPoses:
    """Per-step poses of one walk; row 0 is the start (t0, 0, 0, heading 0), row k the pose after step k.

    All arrays (k + 1,): ``t_s`` s; ``x_m``, ``y_m`` m and ``heading_rad`` (CCW, relative to the start) in the
    walk's own frame; ``yaw_abs_rad`` absolute yaw of that step (NaN when unknown) with 1-sigma
    ``yaw_abs_sigma_rad``; ``step_freq_hz`` (NaN for row 0 and after a stop); ``step_length_m`` (0 for row 0).
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    yaw_abs_rad: np.ndarray
    yaw_abs_sigma_rad: np.ndarray
    step_freq_hz: np.ndarray
    step_length_m: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    def to_frame(self, walk_id: str) -> pd.DataFrame:
        """Table with the pose columns of the input schema (walk_id, step, t_s, x_m, ...)."""
        n = len(self.t_s)
        return pd.DataFrame({
            "walk_id": np.full(n, walk_id, dtype=object),
            "step": np.arange(n, dtype=np.int64),
            "t_s": self.t_s,
            "x_m": self.x_m,
            "y_m": self.y_m,
            "heading_rad": self.heading_rad,
            "yaw_abs_rad": self.yaw_abs_rad,
            "yaw_abs_sigma_rad": self.yaw_abs_sigma_rad,
            "step_freq_hz": self.step_freq_hz,
        })


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


def yaw_sigma(accuracy: np.ndarray, cfg: PdrConfig) -> np.ndarray:
    """1-sigma in rad of an absolute yaw reading per Android accuracy flag (unknown flags -> flag 0's)."""
    table = np.asarray(cfg.yaw_sigma_by_accuracy_rad, dtype=np.float64)
    a = np.asarray(accuracy)
    return np.where((a >= 0) & (a <= 3), table[np.clip(a, 0, 3).astype(np.int64)], table[0])


def run_pdr(imu: ImuSignals, cfg: PdrConfig) -> StepPoses:
    """Steps, heading, step length and integration for one walk of phone IMU data.

    Raises ValueError when a signal the configuration needs is missing (no accelerometer; no rotation
    vector for ``heading_source="rotation_vector"``; no gyroscope for ``"gyro"``).
    """
    if len(imu.t_acc_s) < 2:
        raise ValueError("no accelerometer samples")
    t0 = float(imu.t_acc_s[0])
    step_t, tu, mag = detect_steps(imu.t_acc_s, imu.acc_mps2, cfg)
    k = len(step_t)
    # the interval each step's heading is averaged over
    prev = np.maximum(np.r_[t0, step_t[:-1]], step_t - cfg.max_step_interval_s) if k else step_t
    has_yaw = len(imu.t_yaw_s) > 0
    if has_yaw:
        yaw_u = np.unwrap(np.asarray(imu.yaw_abs_rad, dtype=np.float64))
        yaw0 = float(np.interp(t0, imu.t_yaw_s, yaw_u))
        yaw_steps_u = interval_mean(imu.t_yaw_s, yaw_u, prev, step_t)
        yaw_abs = wrap_angle(np.r_[yaw0, yaw_steps_u])
        acc_at = np.interp(np.r_[t0, step_t], imu.t_yaw_s, np.arange(len(imu.t_yaw_s)))
        sig = yaw_sigma(np.asarray(imu.yaw_accuracy)[np.rint(acc_at).astype(np.int64)], cfg)
    else:
        yaw_abs = np.full(k + 1, np.nan)
        sig = np.full(k + 1, np.nan)
    if cfg.heading_source == "rotation_vector":
        if not has_yaw:
            raise ValueError("no rotation-vector / AHRS samples for heading_source = 'rotation_vector'")
        rel = yaw_steps_u - yaw0
    else:
        if len(imu.t_gyro_s) < 2:
            raise ValueError("no gyroscope samples for heading_source = 'gyro'")
        g = gyro_yaw(imu.t_gyro_s, imu.gyro_radps, imu.t_acc_s, imu.acc_mps2)
        g0 = float(np.interp(t0, imu.t_gyro_s, g))
        rel = interval_mean(imu.t_gyro_s, g, prev, step_t) - g0
    freq = step_frequency(step_t, t0, cfg.max_step_interval_s)
    length = step_lengths(step_t, freq, tu, mag, cfg)
    t, x, y, h = integrate_steps(t0, step_t, length, rel)
    return StepPoses(
        t_s=t, x_m=x, y_m=y, heading_rad=wrap_angle(h), yaw_abs_rad=yaw_abs, yaw_abs_sigma_rad=sig,
        step_freq_hz=np.r_[np.nan, freq], step_length_m=np.r_[0.0, length],
    )


def poses_from_increments(t0_s: float, t_s: np.ndarray, dx_m: np.ndarray, dy_m: np.ndarray,
                          dtheta_rad: np.ndarray) -> StepPoses:
    """Per-step poses from foot-IMU step increments (no absolute yaw: NaN)."""
    t, x, y, h = integrate_increments(t0_s, t_s, dx_m, dy_m, dtheta_rad)
    freq = np.r_[np.nan, step_frequency(np.asarray(t_s, dtype=np.float64), t0_s, 1.5)]
    n = len(t)
    return StepPoses(t_s=t, x_m=x, y_m=y, heading_rad=wrap_angle(h), yaw_abs_rad=np.full(n, np.nan),
                     yaw_abs_sigma_rad=np.full(n, np.nan), step_freq_hz=freq,
                     step_length_m=np.r_[0.0, np.hypot(dx_m, dy_m)])
