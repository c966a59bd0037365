"""Raw phone-IMU signals for the simulated walks, so the PDR front end can be run on synthetic data.

Each walk's accelerometer, gyroscope and rotation-vector yaw are synthesised from its *true* step times and
headings (rmbuild.pdr.synth); the PDR run at ingest then has to find the steps and integrate the heading
itself, as on a real phone.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.pdr.synth import synthesize_phone_imu

#: columns of the raw-IMU input table (docs/data-format.md)
IMU_COLUMNS = ("walk_id", "t_s", "acc_x_mps2", "acc_y_mps2", "acc_z_mps2", "gyro_x_radps", "gyro_y_radps",
               "gyro_z_radps", "yaw_abs_rad", "yaw_accuracy")


def phone_imu_table(truth_poses: pd.DataFrame, seed: int, fs_hz: float = 50.0) -> pd.DataFrame:
    """One row per IMU sample of every walk (50 Hz), in the raw-IMU input schema."""
    parts = []
    for i, (wid, g) in enumerate(truth_poses.groupby("walk_id", sort=False)):
        rng = np.random.default_rng([seed, 7919, i])
        imu = synthesize_phone_imu(g["t_s"].to_numpy(float), g["heading_rad"].to_numpy(float), rng,
                                   fs_hz=fs_hz, yaw_offset_rad=float(rng.normal(0.0, 0.05)))
        n = len(imu.t_acc_s)
        parts.append(pd.DataFrame({
            "walk_id": np.full(n, wid, dtype=object), "t_s": np.round(imu.t_acc_s, 4),
            "acc_x_mps2": imu.acc_mps2[:, 0], "acc_y_mps2": imu.acc_mps2[:, 1], "acc_z_mps2": imu.acc_mps2[:, 2],
            "gyro_x_radps": imu.gyro_radps[:, 0], "gyro_y_radps": imu.gyro_radps[:, 1],
            "gyro_z_radps": imu.gyro_radps[:, 2], "yaw_abs_rad": imu.yaw_abs_rad,
            "yaw_accuracy": imu.yaw_accuracy.astype(np.int64),
        }))
    return pd.concat(parts, ignore_index=True)[list(IMU_COLUMNS)]
