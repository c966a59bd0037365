"""Config of phone PDR (``rmbuild/pdr``) and of the real-data readers that use it (TOML section ``[pdr]``).

The readers for Microsoft ILC 2.0 traces (``[pdr.msft_ilc]``) and IPIN / GetSensorData logfiles
(``[pdr.ipin]``) turn raw phone IMU signals into per-step poses with the settings at the top level.
The defaults were measured on the Microsoft ILC 2.0 and IPIN 2023 walks and on synthetic carrying modes
(docs/formats-real.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal


@dataclass(frozen=True)
class MsftIlcConfig:
    # s; a TYPE_WIFI row whose last-seen time is older than its scan time by more than this is a stale
    # cache entry and is dropped (on the MS ILC floors 3 s drops 55-60 % of the rows).
    max_wifi_age_s: float = 3.0
    # a trace without any (fresh) Wi-Fi row is an input error (false: keep the walk, Wi-Fi-less).
    require_wifi: bool = True

    def validate(self) -> None:
        if self.max_wifi_age_s < 0:
            raise ValueError("msft_ilc.max_wifi_age_s must be >= 0")


@dataclass(frozen=True)
class IpinConfig:
    # degrees WGS84; origin of the local ENU frame POSI fixes are converted to. Both unset = automatic:
    # the first POSI fix of the first logfile (files in sorted order), reported in the ingest notes.
    origin_lat_deg: float | None = None
    origin_lon_deg: float | None = None
    # use IMUI lines (foot-mounted MIMU22BT step increments) as the walk's steps when a logfile has them;
    # false = always derive steps from the phone's ACCE/AHRS/GYRO by PDR.
    use_imui: bool = True
    # IMUI increments are in a z-down frame (OpenShoe / MIMU22BT: dy to the right, dtheta clockwise seen
    # from above); true flips dy and dtheta into rmbuild's counter-clockwise convention.
    imui_z_down: bool = True
    # also write per-step odometry sigmas (odo_sigma_x_m, odo_sigma_y_m, odo_sigma_theta_rad columns of
    # poses) from the IMUI covariance (upper triangle of the 4x4 covariance of dx, dy, dz, dtheta, row by
    # row; variances in m² and rad² assumed), for an optional data-driven odometry noise.
    imui_covariance: bool = False
    # a logfile without any WIFI line is an input error (false: keep the walk, Wi-Fi-less).
    require_wifi: bool = True

    def validate(self) -> None:
        if (self.origin_lat_deg is None) != (self.origin_lon_deg is None):
            raise ValueError("ipin.origin_lat_deg and ipin.origin_lon_deg must be given together")
        if self.origin_lat_deg is not None and not -90.0 <= self.origin_lat_deg <= 90.0:
            raise ValueError("ipin.origin_lat_deg must be in [-90, 90]")
        if self.origin_lon_deg is not None and not -180.0 <= self.origin_lon_deg <= 180.0:
            raise ValueError("ipin.origin_lon_deg must be in [-180, 180]")


@dataclass(frozen=True)
class PdrConfig:
    # --- sensor clock ---
    # s; a gap in the accelerometer's timestamps longer than this cuts a walk's IMU into blocks: a block of
    # a few samples is a bad timestamp and is dropped with a warning; two long blocks are an error (a clock
    # jump, or two recordings in one walk). Shorter gaps over 0.5 s are dropouts (no steps, heading held).
    max_gap_s: float = 30.0

    # --- heading ---
    # "auto": the gyroscope about gravity (bias from the rotation vector or still periods) when the walk
    # has one, else the rotation vector; "gyro" / "rotation_vector" force one (an error when it is missing).
    # The rotation vector's yaw bends near steel indoors (docs/formats-real.md); the absolute yaw
    # (yaw_abs_rad) is always the rotation vector's.
    heading_source: Literal["auto", "gyro", "rotation_vector"] = "auto"
    # rad; 1-sigma of the absolute yaw observation per Android accuracy flag 0 (unreliable), 1 (low),
    # 2 (medium), 3 (high). Measured on ILC F1: walks agree to a median 6°, P90 17° (flag 3).
    yaw_sigma_by_accuracy_rad: tuple[float, float, float, float] = (0.6, 0.45, 0.3, 0.15)

    # --- step length ---
    # m; step length of a walker whose steps swing the acceleration magnitude by 4 m/s² peak to valley
    # (rmbuild/pdr/length.py scales it by the gait signal; the optimizer refines one scale per walk).
    # Chosen leave-one-out over the five ILC 2.0 floors and the two IPIN 2023 phones (docs/formats-real.md).
    step_length_m: float = 0.645
    # m; step lengths are clipped to this range (before the shortening of turning steps).
    min_step_m: float = 0.3
    max_step_m: float = 1.2

    # --- readers ---
    msft_ilc: MsftIlcConfig = field(default_factory=MsftIlcConfig)
    ipin: IpinConfig = field(default_factory=IpinConfig)

    def validate(self) -> None:
        if not 1.0 <= self.max_gap_s <= 86400.0:
            raise ValueError("max_gap_s must be in [1, 86400] s")
        if any(not (0 < s <= math.pi and math.isfinite(s)) for s in self.yaw_sigma_by_accuracy_rad):
            raise ValueError("yaw_sigma_by_accuracy_rad must be in (0, pi]")
        if not 0.05 <= self.min_step_m <= self.max_step_m <= 3.0:
            raise ValueError("need 0.05 <= min_step_m <= max_step_m <= 3 m")
        if not 0.05 <= self.step_length_m <= 3.0:
            raise ValueError("step_length_m must be in [0.05, 3] m")
        self.msft_ilc.validate()
        self.ipin.validate()
