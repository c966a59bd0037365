"""Raw phone-IMU signals for the simulated walks, so the PDR front end can be run on synthetic data.

Each walk's accelerometer, gyroscope and rotation vector are synthesised (:mod:`rmbuild.pdr.synth`) from its
*true* step times, step lengths and headings, with the phone carried in a way drawn from
``[phone] carry_modes`` and sampled at a rate drawn from ``[phone] sample_hz``; the rotation vector's yaw
error is the simulated magnetometer's. The PDR run at ingest then has to find the steps and integrate the
heading itself, as on a real phone.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.config.simulate import PhoneImuConfig
from rmbuild.geometry import wrap
from rmbuild.pdr.synth import synthesize_phone_imu

#: columns of the raw-IMU input table (docs/data-format.md)
IMU_COLUMNS = ("walk_id", "t_s", "acc_x_mps2", "acc_y_mps2", "acc_z_mps2", "gyro_x_radps", "gyro_y_radps",
               "gyro_z_radps", "yaw_abs_rad", "yaw_accuracy")


def _walk_imu(truth: pd.DataFrame, yaw_abs: np.ndarray, rng: np.random.Generator, cfg: PhoneImuConfig,
              ) -> tuple[pd.DataFrame, dict]:
    """One walk's IMU table and what was drawn for it (carrying mode, rate, gyro bias, bounce)."""
    t = truth["t_s"].to_numpy(float)
    xy = truth[["x_m", "y_m"]].to_numpy(float)
    hd = truth["heading_rad"].to_numpy(float)
    mode = str(rng.choice(list(cfg.carry_modes)))
    fs = float(rng.uniform(*cfg.sample_hz))
    bounce = float(rng.uniform(*cfg.bounce_scale))
    bias = np.deg2rad(rng.normal(0.0, cfg.gyro_bias_sd_dps, 3))
    err = wrap(yaw_abs - hd)   # the simulated magnetometer's error at each step (NaN: none)
    imu = synthesize_phone_imu(
        t[1:], hd[1:], rng, mode=mode, step_length_m=np.hypot(*np.diff(xy, axis=0).T), fs_hz=fs,
        t_start_s=t[0], t_end_s=t[-1] + 1.0, jitter_s=cfg.jitter_ms / 1000.0, acc_noise_mps2=cfg.acc_noise_mps2,
        gyro_noise_radps=cfg.gyro_noise_radps, gyro_bias_radps=bias, yaw_error=(t, err), bounce_scale=bounce,
    )
    n = len(imu.t_acc_s)
    yaw = np.full(n, np.nan)
    flag = np.full(n, np.nan)
    has = np.isin(imu.t_acc_s, imu.t_yaw_s)
    yaw[has], flag[has] = imu.yaw_abs_rad, imu.yaw_accuracy
    wid = truth["walk_id"].iat[0]
    table = pd.DataFrame({
        "walk_id": np.full(n, wid, dtype=object), "t_s": np.round(imu.t_acc_s, 4),
        "acc_x_mps2": imu.acc_mps2[:, 0], "acc_y_mps2": imu.acc_mps2[:, 1], "acc_z_mps2": imu.acc_mps2[:, 2],
        "gyro_x_radps": imu.gyro_radps[:, 0], "gyro_y_radps": imu.gyro_radps[:, 1],
        "gyro_z_radps": imu.gyro_radps[:, 2], "yaw_abs_rad": yaw, "yaw_accuracy": flag,
    })
    return table, {"walk_id": wid, "carry_mode": mode, "imu_hz": round(fs, 2), "bounce_scale": round(bounce, 3),
                   "gyro_bias_x_dps": np.degrees(bias[0]), "gyro_bias_y_dps": np.degrees(bias[1]),
                   "gyro_bias_z_dps": np.degrees(bias[2])}


def phone_imu_table(truth_poses: pd.DataFrame, poses: pd.DataFrame, seed: int, cfg: PhoneImuConfig,
                    ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per IMU sample of every walk, in the raw-IMU input schema, and one row per walk with what
    was drawn for it (``carry_mode``, ``imu_hz``, ``bounce_scale``, ``gyro_bias_*_dps``: truth).

    ``poses`` (row-aligned with ``truth_poses``) gives the simulated magnetometer yaw (``yaw_abs_rad``).
    """
    parts, drawn = [], []
    yaw = poses["yaw_abs_rad"].to_numpy(float)
    for i, (_, rows) in enumerate(truth_poses.groupby("walk_id", sort=False).indices.items()):
        rng = np.random.default_rng([seed, 7919, i])
        table, info = _walk_imu(truth_poses.iloc[rows], yaw[rows], rng, cfg)
        parts.append(table)
        drawn.append(info)
    return pd.concat(parts, ignore_index=True)[list(IMU_COLUMNS)], pd.DataFrame(drawn)
