"""What the PDR found on one walk, and whether it looks plausible (a per-walk report and quality flag)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rmbuild.pdr.steps import HOP_S
from rmbuild.pdr.timebase import TimeIssue

if TYPE_CHECKING:
    from rmbuild.pdr.signals import StepPoses
    from rmbuild.pdr.steps import StepDetection
    from rmbuild.pdr.yaw import YawTrack

#: Hz; cadence of walking people: about 1.4-2.2 steps/s, a slow museum pace down to 1.1 (measured on the
#: IPIN 2023 walks), running up to 3. Outside this range the step detector probably counts something else.
CADENCE_RANGE_HZ = (1.0, 3.2)
#: a walk shorter than this is not judged on its step count
MIN_JUDGED_S = 10.0


@dataclass
class PdrReport:
    """Per-walk PDR summary: ``steps``; ``walking_s``, ``handling_s`` (the phone handled, not carried: no
    steps counted) and ``duration_s`` (s); ``cadence_hz`` steps per walking
    second (NaN without walking); ``walked_m`` summed step length; ``heading_source``; ``gyro_bias_dps``
    (norm of the removed bias, °/s) and ``bias_source``; ``yaw_abs_not_in_front``: poses whose absolute
    yaw was dropped because the phone was not held in front (upright or face down); ``quality``
    "ok", "suspect" or "poor"; ``warnings`` (text); ``time_issues`` (repaired timestamp problems, located
    by stream and sample index for the caller to name file and line)."""

    steps: int
    walking_s: float
    handling_s: float
    duration_s: float
    cadence_hz: float
    walked_m: float
    heading_source: str
    gyro_bias_dps: float
    bias_source: str
    yaw_abs_not_in_front: int = 0
    quality: str = "ok"
    warnings: list[str] = field(default_factory=list)
    time_issues: list[TimeIssue] = field(default_factory=list)


def assess(poses: StepPoses, det: StepDetection, yaw: YawTrack, issues: list[TimeIssue],
           duration_s: float) -> PdrReport:
    """The report of one walk, with warnings for implausible PDR."""
    k = len(det.t_s)
    cad = k / det.walking_s if det.walking_s > 0 else float("nan")
    rep = PdrReport(
        steps=k, walking_s=round(det.walking_s, 2),
        handling_s=round(float(det.windows.handling.sum()) * HOP_S, 1), duration_s=round(duration_s, 2),
        cadence_hz=cad,
        walked_m=float(np.sum(poses.step_length_m)), heading_source=yaw.source,
        gyro_bias_dps=float(np.degrees(np.linalg.norm(yaw.bias_radps))), bias_source=yaw.bias_source,
        time_issues=list(issues),
    )
    poor, suspect = [], []
    if duration_s >= MIN_JUDGED_S and k == 0:
        poor.append(f"no steps found in {duration_s:.0f} s of IMU data")
    if k >= 10 and not CADENCE_RANGE_HZ[0] <= cad <= CADENCE_RANGE_HZ[1]:
        suspect.append(f"cadence {cad:.2f} steps/s outside the walking range {CADENCE_RANGE_HZ[0]:g}-"
                       f"{CADENCE_RANGE_HZ[1]:g}")
    if yaw.source == "rotation_vector":
        suspect.append("heading from the rotation vector (magnetometer: bends near steel)")
    elif yaw.bias_source == "none":
        suspect.append("gyroscope bias unknown (no rotation vector, never still): heading may drift")
    rep.warnings = poor + suspect
    rep.quality = "poor" if poor else "suspect" if suspect else "ok"
    return rep
