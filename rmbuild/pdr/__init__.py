"""Pedestrian dead reckoning from a carried phone: raw IMU -> per-step poses (pure numpy/scipy, no I/O).

Entry points: :func:`run_pdr` (phone IMU -> :class:`PdrResult`: poses and a per-walk report) and
:func:`poses_from_increments` (foot-IMU step increments). Settings: :class:`rmbuild.config.pdr.PdrConfig`.
Method and measured accuracy: docs/notes/formats-real.md.
"""

from __future__ import annotations

from rmbuild.pdr.core import (
    ImuSignals,
    PdrResult,
    StepPoses,
    integrate_increments,
    poses_from_increments,
    run_pdr,
)
from rmbuild.pdr.heading import accuracy_flags, rotation_vector_quat, yaw_from_azimuth_deg, yaw_from_quat
from rmbuild.pdr.quality import PdrReport
from rmbuild.pdr.timebase import ImuTimeError, TimeIssue

__all__ = [
    "accuracy_flags",
    "ImuSignals",
    "ImuTimeError",
    "PdrReport",
    "PdrResult",
    "StepPoses",
    "TimeIssue",
    "integrate_increments",
    "poses_from_increments",
    "rotation_vector_quat",
    "run_pdr",
    "yaw_from_azimuth_deg",
    "yaw_from_quat",
]
