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

from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class MsftIlcConfig:
    # s; a TYPE_WIFI row whose last-seen time is older than its scan time by more than this is a stale
    # cache entry and is dropped (on the MS ILC floors 3 s drops 55-60 % of the rows).
    max_wifi_age_s: float = bounded(3.0, 0.0, 3600.0)

    def validate(self) -> None:
        check_ranges(self, "msft_ilc.")


@dataclass(frozen=True)
class IpinConfig:
    # degrees WGS84; origin of the local ENU frame POSI fixes are converted to. Both unset = automatic:
    # the first POSI fix of the first logfile (files in sorted order), reported in the ingest notes.
    origin_lat_deg: float | None = bounded(None, -90.0, 90.0)
    origin_lon_deg: float | None = bounded(None, -180.0, 180.0)
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

    def validate(self) -> None:
        if (self.origin_lat_deg is None) != (self.origin_lon_deg is None):
            raise ValueError("ipin.origin_lat_deg and ipin.origin_lon_deg must be given together")
        check_ranges(self, "ipin.")


@dataclass(frozen=True)
class PdrConfig:
    # --- sensor clock ---
    # s; a gap in the accelerometer's timestamps longer than this cuts a walk's IMU into blocks: a block of
    # a few samples is a bad timestamp and is dropped with a warning; two long blocks are an error (a clock
    # jump, or two recordings in one walk). Shorter gaps over 0.5 s are dropouts (no steps, heading held).
    max_gap_s: float = bounded(30.0, 1.0, 86400.0)

    # --- heading ---
    # "auto": the gyroscope about gravity (bias from the rotation vector or still periods) when the walk
    # has one, else the rotation vector; "gyro" / "rotation_vector" force one (an error when it is missing).
    # The rotation vector's yaw bends near steel indoors (docs/formats-real.md); the absolute yaw
    # (yaw_abs_rad) is always the rotation vector's.
    heading_source: Literal["auto", "gyro", "rotation_vector"] = "auto"
    # rad; 1-sigma of the absolute yaw observation per Android accuracy flag 0 (unreliable), 1 (low),
    # 2 (medium), 3 (high). Measured on ILC F1: walks agree to a median 6°, P90 17° (flag 3).
    yaw_sigma_by_accuracy_rad: tuple[float, float, float, float] = bounded((0.6, 0.45, 0.3, 0.15), 0.001, math.pi)

    # --- step length ---
    # m; step length of a walker whose steps swing the acceleration magnitude by 4 m/s² peak to valley
    # (rmbuild/pdr/length.py scales it by the gait signal; the optimizer refines one scale per walk).
    # Chosen leave-one-out over the five ILC 2.0 floors and the two IPIN 2023 phones (docs/formats-real.md).
    step_length_m: float = bounded(0.645, 0.05, 3.0)
    # m; step lengths are clipped to this range (before the shortening of turning steps).
    min_step_m: float = bounded(0.3, 0.05, 3.0)
    max_step_m: float = bounded(1.2, 0.05, 3.0)

    # --- readers ---
    msft_ilc: MsftIlcConfig = field(default_factory=MsftIlcConfig)
    ipin: IpinConfig = field(default_factory=IpinConfig)

    def validate(self) -> None:
        check_ranges(self)
        if not self.min_step_m <= self.max_step_m:
            raise ValueError("need min_step_m <= max_step_m")
        self.msft_ilc.validate()
        self.ipin.validate()
