"""The walk's relative heading over time: the gyroscope about gravity with its bias removed, or the
rotation vector's yaw when there is no gyroscope."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rmbuild.pdr.attitude import drift_rate, gyro_bias, up_vectors, yaw_about_gravity

if TYPE_CHECKING:
    from rmbuild.pdr.signals import ImuSignals


@dataclass(frozen=True)
class YawTrack:
    """Relative yaw (rad, CCW seen from above, continuous) ``yaw_rad`` (n,) at ``t_s`` (n,), 0 at the walk's
    start; ``source`` "gyro" or "rotation_vector"; the gyro bias removed ``bias_radps`` (3,) and how it was
    found ``bias_source`` ("still", "rotation_vector" (the orientation), "yaw_drift" (the absolute yaw alone),
    "none"; "" for the rotation-vector heading)."""

    t_s: np.ndarray
    yaw_rad: np.ndarray
    source: str
    bias_radps: np.ndarray
    bias_source: str


def relative_yaw(imu: ImuSignals, source: str, t0_s: float) -> YawTrack:
    """The yaw track of ``imu`` from ``source`` ("gyro" or "rotation_vector"), zero at ``t0_s``."""
    if source == "rotation_vector":
        t = np.asarray(imu.t_yaw_s, dtype=np.float64)
        y = np.unwrap(np.asarray(imu.yaw_abs_rad, dtype=np.float64))
        return YawTrack(t, y - float(np.interp(t0_s, t, y)), source, np.zeros(3), "")
    t = np.asarray(imu.t_gyro_s, dtype=np.float64)
    w = np.asarray(imu.gyro_radps, dtype=np.float64)
    b, how = gyro_bias(t, w, imu.t_yaw_s, imu.quat_xyzw, imu.t_acc_s, imu.acc_mps2)
    rate = w - b
    acc = np.column_stack([np.interp(t, imu.t_acc_s, imu.acc_mps2[:, j]) for j in range(3)])
    up = up_vectors(t, rate, acc)
    yaw = yaw_about_gravity(t, rate, up)
    if how == "none" and len(imu.t_yaw_s) >= 2:
        # no orientation, no still stretch, but an absolute yaw: the drift of (yaw - gyro yaw) is the bias
        # about gravity
        ty = np.asarray(imu.t_yaw_s, dtype=np.float64)
        d = np.unwrap(np.asarray(imu.yaw_abs_rad, dtype=np.float64)) - np.interp(ty, t, yaw)
        bv = -drift_rate(ty, d)
        yaw = yaw - bv * (t - t[0])
        b = bv * up.mean(axis=0) / max(float(np.linalg.norm(up.mean(axis=0))), 1e-9)
        how = "yaw_drift"
    return YawTrack(t, yaw - float(np.interp(t0_s, t, yaw)), source, b, how)
