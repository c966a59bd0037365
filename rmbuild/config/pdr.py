"""Config of phone PDR (``rmbuild/pdr``, TOML section ``[pdr]``): how the raw phone IMU of the Microsoft
ILC 2.0 traces and IPIN / GetSensorData logfiles becomes per-step poses. The readers' own options are
``[ingest.msft_ilc]`` and ``[ingest.ipin]`` (:mod:`rmbuild.config.ingest`). The defaults were chosen on the
Microsoft ILC 2.0 and IPIN 2023 walks and on synthetic carrying modes (docs/notes/formats-real.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from rmbuild.config.base import bounded, check_ranges


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
    # 2 (medium), 3 (high) (how walks agree by flag: docs/notes/formats-real.md).
    yaw_sigma_by_accuracy_rad: tuple[float, float, float, float] = bounded((0.6, 0.45, 0.3, 0.15), 0.001, math.pi)

    # --- step length ---
    # m; step length of a walker whose steps swing the acceleration magnitude by 4 m/s² peak to valley
    # (rmbuild/pdr/length.py scales it by the gait signal; the optimizer refines one scale per walk).
    # Chosen leave-one-out on real phone walks (docs/notes/formats-real.md).
    step_length_m: float = bounded(0.645, 0.05, 3.0)
    # m; step lengths are clipped to this range (before the shortening of turning steps).
    min_step_m: float = bounded(0.3, 0.05, 3.0)
    max_step_m: float = bounded(1.2, 0.05, 3.0)

    def validate(self) -> None:
        check_ranges(self)
        if not self.min_step_m <= self.max_step_m:
            raise ValueError("need min_step_m <= max_step_m")
