"""The series the PDR works on: one walk's raw IMU signals in, its per-step poses out (plain arrays; no
logic beyond conversion to the input schema's pose table)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd


@dataclass
class ImuSignals:
    """Raw IMU series of one walk, each sorted by time (s, one common clock).

    ``acc_mps2``: (n, 3) accelerometer (specific force, device frame). ``yaw_abs_rad``: (m,) absolute yaw
    (ENU, CCW from east) at ``t_yaw_s`` from the rotation vector / AHRS, with Android accuracy flags
    ``yaw_accuracy`` (m,) int (0..3; -1 = unknown) and, when recorded, the orientation itself ``quat_xyzw``
    (m, 4) (device -> ENU; else shape (0, 4)). ``gyro_radps``: (k, 3) body rates (device frame).
    Missing series are empty arrays.
    """

    t_acc_s: np.ndarray
    acc_mps2: np.ndarray
    t_yaw_s: np.ndarray
    yaw_abs_rad: np.ndarray
    yaw_accuracy: np.ndarray
    t_gyro_s: np.ndarray
    gyro_radps: np.ndarray
    quat_xyzw: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


@dataclass
class StepPoses:
    """Per-step poses of one walk; row 0 is the start (t0, 0, 0, heading 0), row k the pose after step k.

    All arrays (k + 1,): ``t_s`` s; ``x_m``, ``y_m`` m and ``heading_rad`` (CCW, relative to the start) in the
    walk's own frame; ``yaw_abs_rad`` absolute yaw of that step (NaN when unknown) with 1-sigma
    ``yaw_abs_sigma_rad``; ``step_freq_hz`` (NaN for row 0); ``step_length_m`` (0 for row 0).
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
