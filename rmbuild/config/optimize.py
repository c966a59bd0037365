"""Config of `rmbuild optimize`: one table per part of the back end (docs/optimize.md).

``[optimize.odometry]`` the dead reckoning along each walk, ``[optimize.wifi]`` the Wi-Fi vicinity
evidence, ``[optimize.compass]`` the phone's absolute heading, ``[optimize.continuity]`` walks recorded one
after the other by one device, ``[optimize.anchors]`` known positions,
``[optimize.placement]`` how walks get their initial frames, ``[optimize.solve]`` the joint solve.
"paper" marks the value of Gu et al.'s published model where it has one (docs/references.md);
:func:`paper_config` builds that model from the same fields. The measurements that chose the defaults
are in docs/optimize.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class OdometryConfig:
    # m; per-step 1-sigma of the dead-reckoned increment along / across the walking direction. paper: 1.
    sigma_x_m: float = bounded(0.05, 0.001, 10.0)
    sigma_y_m: float = bounded(0.05, 0.001, 10.0)
    # 1/rad²; heading information per step (sigma = 1/sqrt(mu); 8000 = 0.64 deg). paper: 20.
    mu: float = bounded(8000.0, 0.1, 1e7)
    # estimate one step-length scale per walk between solves (uncalibrated phone step lengths).
    estimate_scale: bool = True
    # bounds of a walk's step-length scale.
    scale_min: float = bounded(0.7, 0.1, 1.0)
    scale_max: float = bounded(1.4, 1.0, 10.0)

    def validate(self) -> None:
        check_ranges(self, "odometry.")


@dataclass(frozen=True)
class WifiConfig:
    # candidate pair search: "run_matched" (runs of consecutive scans matched across walks) or
    # "median_window" (paper: d(k, q) below the median distance in k's window of window_steps steps).
    search: Literal["run_matched", "median_window"] = "run_matched"
    # dBm; value of a missing AP in the RSS distance. paper: -110.
    fill_dbm: float = bounded(-110.0, -200.0, 0.0)
    # steps; L, the window of a scan's own walk whose median RSS distance is its similarity threshold. paper: 20.
    window_steps: int = bounded(20, 2, 10000)
    # APs a pair's two fingerprints must share.
    min_common_aps: int = bounded(3, 0, 1000)
    # also search pairs within one walk (loop closures), checked against its own dead reckoning.
    within_walk: bool = True
    # m; eq. 10's fuzzy band: no error below d_min, a linear ramp to e_max at d_max, flat beyond. paper: 2 / 30.
    d_min: float = bounded(0.0, 0.0, 100.0)
    d_max: float = bounded(6.0, 0.1, 1000.0)
    # eq. 10's Ω_WiFi, the weight of a pair (its sigma is (d_max - d_min) / sqrt(Ω); e_max is fixed at the
    # paper's 1). paper: not given.
    omega: float = bounded(2.0, 0.01, 1000.0)
    # sigma across / along the walking direction of pairs of (anti)parallel nodes: 1 = isotropic (paper),
    # 0 = estimated from the solved pairs after each solve.
    across_ratio: float = bounded(0.0, 0.0, 1.0)
    # remove each device's RSS offset against the most common device (estimated from the data, reported
    # in optimize.json) before fingerprints are compared; off when all phones read alike. paper: off.
    calibrate_devices: bool = True
    # β of the powed representation fill + 80 dB·((rss − fill) / 80 dB)^β the fingerprints are compared in
    # (strong readings weigh more as β grows); 0 = chosen per data set among 1-2.5 by how well it tells a
    # walk's near scan pairs from its far ones (1 unless another is clearly better); 1 = dBm as read (paper).
    rss_exponent: float = bounded(0.0, 0.0, 5.0)

    def validate(self) -> None:
        check_ranges(self, "wifi.")
        if not self.d_min < self.d_max:
            raise ValueError("need d_min < d_max")


@dataclass(frozen=True)
class CompassConfig:
    # use the phone's absolute heading (poses column yaw_abs_rad) for walk rotations and heading priors.
    use: bool = True
    # rad; 1-sigma of yaw_abs where the poses table gives none (yaw_abs_sigma_rad).
    default_sigma_rad: float = bounded(0.25, 0.001, math.pi)

    def validate(self) -> None:
        check_ranges(self, "compass.")


@dataclass(frozen=True)
class ContinuityConfig:
    # tie a walk's last pose to the first pose of the same device's next walk (walks recorded one after the
    # other by one surveyor); off automatically for a device whose walks overlap in time (relative clocks).
    use: bool = True
    # s; longest gap between one walk's end and the next one's start that still ties them.
    max_gap_s: float = bounded(60.0, 0.0, 86400.0)
    # m/s; the tie's 1-sigma grows by this per second of gap (2 m at no gap): how far the surveyor may
    # have moved between the two recordings.
    speed_m_s: float = bounded(0.4, 0.0, 10.0)

    def validate(self) -> None:
        check_ranges(self, "continuity.")


@dataclass(frozen=True)
class AnchorConfig:
    # m; 1-sigma of an anchor's position prior.
    sigma_m: float = bounded(0.5, 0.001, 100.0)
    # s; an anchor may lie this far outside its walk's time span (it then fixes that end pose).
    max_gap_s: float = bounded(2.0, 0.0, 3600.0)

    def validate(self) -> None:
        check_ranges(self, "anchors.")


@dataclass(frozen=True)
class FloorPlanConfig:
    # use the workspace's floor plan when it has one (`rmbuild ingest --floorplan`, or the plan an ILC floor
    # brings): the map in the plan's frame where its place on the plan is distinct, wall priors on poses
    # outside walkable space; false = ignore the plan (docs/optimize.md, step 14).
    use: bool = True

    def validate(self) -> None:
        pass


@dataclass(frozen=True)
class PlacementConfig:
    # "grow": walks fitted one round at a time to the map placed so far; "origin": every walk at (0, 0, 0)
    # in its own frame (paper).
    method: Literal["grow", "origin"] = "grow"
    # m; a correspondence is an inlier of a placement when it puts its two nodes this close.
    gate_m: float = bounded(4.0, 0.1, 100.0)
    # distinct inlier scans a placement with the compass rotation needs (with a fitted rotation: twice).
    min_inliers: int = bounded(3, 1, 10000)
    # m of walked path the inliers must cover: with the compass rotation / with a fitted rotation.
    min_shared_m: float = bounded(6.0, 0.0, 10000.0)
    min_shared_se2_m: float = bounded(20.0, 0.0, 10000.0)
    # a placement must lead the best one elsewhere by this factor and by min_lead inlier scans.
    margin: float = bounded(1.5, 1.0, 100.0)
    min_lead: int = bounded(2, 0, 10000)
    # m of walked path; a long walk is fitted on half-overlapping windows of this length (0 = whole walk).
    window_m: float = bounded(60.0, 0.0, 10000.0)

    def validate(self) -> None:
        check_ranges(self, "placement.")


@dataclass(frozen=True)
class SolveConfig:
    # Levenberg-Marquardt iterations per solve.
    max_iterations: int = bounded(10, 1, 1000)
    # solves that re-select the Wi-Fi pairs within d_max (scale rounds add theirs).
    outer_iterations: int = bounded(3, 1, 100)
    # solve only the steps that carry more than odometry (exact for the chains between them).
    chain_reduction: bool = True
    # the solution is rejected (initial poses kept) when the odometry residual RMS exceeds this many
    # sigmas or the median walk shrinks below this fraction of its dead-reckoned extent.
    max_odometry_rms_sigma: float = bounded(5.0, 0.1, 1e9)
    min_extent_ratio: float = bounded(0.8, 0.0, 0.99)

    def validate(self) -> None:
        check_ranges(self, "solve.")


@dataclass(frozen=True)
class OptimizeConfig:
    # walk_id of the walk whose frame is the map's; "" = the walk with the most cross-walk candidates.
    reference_walk: str = ""
    # a walk of fewer than 2 poses: "skip" (kept at its raw pose, unlinked, with a warning) or "error".
    single_step_walks: Literal["error", "skip"] = "skip"
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    wifi: WifiConfig = field(default_factory=WifiConfig)
    compass: CompassConfig = field(default_factory=CompassConfig)
    continuity: ContinuityConfig = field(default_factory=ContinuityConfig)
    anchors: AnchorConfig = field(default_factory=AnchorConfig)
    floorplan: FloorPlanConfig = field(default_factory=FloorPlanConfig)
    placement: PlacementConfig = field(default_factory=PlacementConfig)
    solve: SolveConfig = field(default_factory=SolveConfig)

    def validate(self) -> None:
        for sub in (self.odometry, self.wifi, self.compass, self.continuity, self.anchors, self.floorplan,
                    self.placement, self.solve):
            sub.validate()


def paper_config(**overrides) -> OptimizeConfig:
    """Gu et al.'s published model: every walk at the origin, median-window pairs over the readings as heard,
    Ω_IMU = diag(1, 1, 20), d_min 2 m, d_max 30 m, one LM solve over every step, no compass, no scale, no
    floor plan, no checks."""
    cfg = OptimizeConfig(
        odometry=OdometryConfig(sigma_x_m=1.0, sigma_y_m=1.0, mu=20.0, estimate_scale=False),
        wifi=WifiConfig(search="median_window", d_min=2.0, d_max=30.0, omega=1.0, across_ratio=1.0,
                        calibrate_devices=False, rss_exponent=1.0),
        compass=CompassConfig(use=False),
        continuity=ContinuityConfig(use=False),
        floorplan=FloorPlanConfig(use=False),
        placement=PlacementConfig(method="origin"),
        # one node per step, as published (with the paper's weak odometry the composed keyframe factors
        # linearise differently enough to move its folded solutions)
        solve=SolveConfig(outer_iterations=1, max_iterations=50, chain_reduction=False,
                          max_odometry_rms_sigma=1e9, min_extent_ratio=0.0),
    )
    return replace(cfg, **overrides)
