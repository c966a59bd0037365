"""Config of phone PDR (``rmbuild/pdr``) and of the real-data readers that use it (TOML section ``[pdr]``).

The readers for Microsoft ILC 2.0 traces (``[pdr.msft_ilc]``) and IPIN / GetSensorData logfiles
(``[pdr.ipin]``) turn raw phone IMU signals into per-step poses with the settings at the top level.
Numbers credited to a paper (author and year; docs/references.md) are that paper's defaults; the rest were
measured on the ``msft-ilc20`` traces (docs/formats-real.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal


@dataclass(frozen=True)
class MsftIlcConfig:
    # s; a TYPE_WIFI row whose last-seen time is older than its scan time by more than this is a stale
    # cache entry and is dropped (on MS ILC 2.0 traces 3 s drops 55-60 % of the rows).
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
    # --- step detection on the acceleration magnitude ---
    # "peak_valley": subway-station paper, a peak followed by a valley, deeper than pv_min_swing_mps2, >= 250 ms apart;
    # "pan_tompkins": Becker et al. 2015, derivative (eq. 6) + squaring (eq. 7), peaks above pt_threshold with a
    # 300 ms pause. The default was chosen by step-count accuracy (docs/formats-real.md).
    step_detector: Literal["peak_valley", "pan_tompkins"] = "peak_valley"
    # Hz; the magnitude is resampled to this uniform rate before detection (phone timestamps jitter).
    sample_hz: float = 50.0
    # Hz; low-pass (2nd-order Butterworth, zero phase) cut-off applied to the magnitude. 0 = none.
    lowpass_hz: float = 2.5
    # s; subway-station paper: minimum time between a peak and its valley (and between two steps).
    pv_min_interval_s: float = 0.25
    # m/s²; subway-station paper: minimum peak-to-valley swing of one step ("threshold from offline training").
    pv_min_swing_mps2: float = 2.5
    # (m/s²)²-ish; Becker et al. 2015: threshold on the squared derivative signal (1 + y)² - 1 for a peak.
    pt_threshold: float = 2.0
    # s; Becker et al. 2015: detection pause after a step.
    pt_refractory_s: float = 0.3
    # s; a gap between steps longer than this counts as standing: the step frequency after it is
    # unknown (the walk's median is used for the step length model).
    max_step_interval_s: float = 1.5

    # --- heading ---
    # "rotation_vector": yaw of the (magnetometer-referenced) rotation vector / AHRS, made relative to the
    # start; "gyro": integrated gyroscope projected on the vertical (needs GYRO/TYPE_GYROSCOPE and
    # gravity from the accelerometer); the absolute yaw is always taken from the rotation vector.
    heading_source: Literal["gyro", "rotation_vector"] = "gyro"
    # rad; 1-sigma of the absolute yaw observation per Android accuracy flag 0 (unreliable), 1 (low),
    # 2 (medium), 3 (high). Measured on ILC F1: walks agree to a median 6°, P90 17° (flag 3).
    yaw_sigma_by_accuracy_rad: tuple[float, float, float, float] = (0.6, 0.45, 0.3, 0.15)

    # --- step length ---
    # "fixed": step_length_m; "frequency": S = freq_alpha * f + freq_beta (He et al. 2015);
    # "weinberg": S = weinberg_k * (a_max - a_min)^(1/4) over the step's magnitude samples.
    # Default chosen by waypoint error on ILC F1 and F4 (docs/formats-real.md).
    step_length_model: Literal["weinberg", "fixed", "frequency"] = "weinberg"
    # m; fixed step length (also the fallback of "weinberg"). Calibrated on ILC site1/F1 with the default
    # detector: 0.72 m (site2/F4: 0.73 m).
    step_length_m: float = 0.72
    # m·s; m; He et al. 2015's linear model (SLAC searches alpha in [0.1, 1], beta in [-0.5, 0]).
    freq_alpha: float = 0.3
    freq_beta: float = 0.1
    # m/(m/s²)^(1/4); Weinberg's constant for a handheld phone, on the low-passed magnitude (calibrated on
    # ILC site1/F1 with the default detector; site2/F4 gives 0.45).
    weinberg_k: float = 0.44
    # m; step lengths are clipped to this range whatever the model.
    min_step_m: float = 0.3
    max_step_m: float = 1.2

    # --- readers ---
    msft_ilc: MsftIlcConfig = field(default_factory=MsftIlcConfig)
    ipin: IpinConfig = field(default_factory=IpinConfig)

    def validate(self) -> None:
        if self.sample_hz <= 0:
            raise ValueError("sample_hz must be > 0")
        if self.lowpass_hz < 0 or self.lowpass_hz >= self.sample_hz / 2:
            raise ValueError("lowpass_hz must be >= 0 and below sample_hz / 2")
        if self.pv_min_interval_s <= 0 or self.pt_refractory_s <= 0:
            raise ValueError("pv_min_interval_s and pt_refractory_s must be > 0")
        if self.pv_min_swing_mps2 < 0 or self.pt_threshold < 0:
            raise ValueError("pv_min_swing_mps2 and pt_threshold must be >= 0")
        if self.max_step_interval_s <= 0:
            raise ValueError("max_step_interval_s must be > 0")
        if any(not (s > 0 and math.isfinite(s)) for s in self.yaw_sigma_by_accuracy_rad):
            raise ValueError("yaw_sigma_by_accuracy_rad must be > 0")
        if not 0 < self.min_step_m <= self.max_step_m:
            raise ValueError("need 0 < min_step_m <= max_step_m")
        if self.step_length_m <= 0 or self.weinberg_k <= 0:
            raise ValueError("step_length_m and weinberg_k must be > 0")
        self.msft_ilc.validate()
        self.ipin.validate()
