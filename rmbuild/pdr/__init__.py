"""Pedestrian dead reckoning from a handheld phone: raw IMU -> per-step poses (pure numpy/scipy, no I/O).

Entry points: :func:`run_pdr` (phone IMU) and :func:`poses_from_increments` (foot-IMU step increments),
both returning :class:`StepPoses`; :func:`detect_steps` for step detection alone. Settings:
:class:`rmbuild.config.pdr.PdrConfig`. Method and measured accuracy: docs/formats-real.md.
"""

from __future__ import annotations

from rmbuild.pdr.core import ImuSignals, StepPoses, integrate_increments, poses_from_increments, run_pdr
from rmbuild.pdr.heading import rotation_vector_quat, wrap_angle, yaw_from_azimuth_deg, yaw_from_quat
from rmbuild.pdr.steps import detect_steps

__all__ = [
    "ImuSignals",
    "StepPoses",
    "detect_steps",
    "integrate_increments",
    "poses_from_increments",
    "rotation_vector_quat",
    "run_pdr",
    "wrap_angle",
    "yaw_from_azimuth_deg",
    "yaw_from_quat",
]
