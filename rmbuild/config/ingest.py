"""Config of `rmbuild ingest` (TOML ``[ingest]``) and of the format readers (``[ingest.msft_ilc]``,
``[ingest.ipin]``); phone PDR has its own section, ``[pdr]`` (:mod:`rmbuild.config.pdr`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class MsftIlcConfig:
    # s; a TYPE_WIFI row whose last-seen time is older than its scan time by more than this is a stale
    # cache entry and is dropped (on the MS ILC floors 3 s drops about half of the rows).
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
class IngestConfig:
    # How Wi-Fi readings attach to pose nodes (docs/data-format.md): "interval" gives node k the readings with
    # t_k <= t < t_{k+1}; "nearest" gives each reading to the node nearest in time.
    attach: Literal["interval", "nearest"] = "interval"
    # s; readings farther than this (in time) from the walk's first/last pose are dropped, not attached.
    max_attach_gap_s: float = bounded(2.0, 0.0, 3600.0)
    # dBm; the valid RSSI range. Readings outside it are an input error.
    rssi_min_dbm: float = bounded(-120.0, -200.0, 30.0)
    rssi_max_dbm: float = bounded(0.0, -200.0, 30.0)
    # the options of the Microsoft ILC 2.0 and IPIN / GetSensorData readers
    msft_ilc: MsftIlcConfig = field(default_factory=MsftIlcConfig)
    ipin: IpinConfig = field(default_factory=IpinConfig)

    def validate(self) -> None:
        check_ranges(self)
        if not self.rssi_min_dbm < self.rssi_max_dbm:
            raise ValueError("rssi_min_dbm must be < rssi_max_dbm")
        self.msft_ilc.validate()
        self.ipin.validate()
