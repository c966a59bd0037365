"""Config of `rmbuild optimize` (METHOD.md §2-6; seed 001 numbers are marked "paper").

Two pipelines share these fields:
- ``pipeline = "robust"`` (default): top-k run-matched cross-walk candidates, per-walk-pair RANSAC
  verification, global initialisation of every walk's frame, realistic odometry noise, an outer loop
  that keeps only in-range pairs, fold/shrink checks.
- ``pipeline = "paper"``: seed 001 as written: every walk starts at the origin, median-window pairs
  (eq. 9), fuzzy factors (eq. 10), odometry Ω = diag(1, 1, μ), one LM solve. Get it from
  :func:`paper_config`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal


@dataclass(frozen=True)
class OdometryConfig:
    # m; per-step 1-sigma of the body-frame increment along / across the walking direction.
    # paper: 1 m (Ω = diag(1/m², 1/m², μ/rad²)); a foot IMU is good to a few cm per 0.7 m step.
    sigma_x_m: float = 0.05
    sigma_y_m: float = 0.05
    # 1/rad²; heading information per step, sigma_theta = 1/sqrt(mu). paper: 20 (0.22 rad per step).
    # 8000 = 0.64 deg per step: about twice a foot IMU's per-step heading noise (~0.3 deg), the rest
    # room for gyro-bias drift. Measured (landmark mean m / heading mean deg, twelve tuning | twelve
    # held-out synthetic venues): mu 1000 1.36 / 1.55 | 1.75 / 2.46; 8000 1.26 / 1.50 | 1.55 / 2.28;
    # 36000 (the foot IMU's own noise, no drift room) 1.40 / 1.54 | 1.54 / 2.26 (a drifted stretch
    # cannot bend back). ILC F1 (phone PDR, ~30 s walks) does not move.
    mu: float = 8000.0

    def validate(self) -> None:
        if self.sigma_x_m <= 0 or self.sigma_y_m <= 0 or self.mu <= 0:
            raise ValueError("odometry sigmas and mu must be > 0")


@dataclass(frozen=True)
class PairConfig:
    # dBm; value of a missing AP reading in the RSS distance (eq. 9). paper: -110.
    fill_dbm: float = -110.0
    # steps; L, the sliding window k-L/2..k+L/2 whose median RSS distance d_med(k) is node k's threshold.
    # The median is over d(k, q) for every other *scanned* node q of k's walk inside the window.
    L_window_steps: int = 20
    # s / m; same-walk pairs closer than this in time or in walked (PDR path) distance are not searched.
    within_min_dt_s: float = 30.0
    within_min_path_m: float = 15.0
    # pairs; at most this many vicinity pairs per node (the closest in RSS distance). 0 = no cap.
    max_pairs_per_node: int = 10
    # APs; a pair needs at least this many APs seen by both fingerprints.
    min_common_aps: int = 3
    # --- robust pipeline only ---
    # scans; consecutive scans of one walk averaged into a segment descriptor for the candidate search.
    segment_scans: int = 2
    # candidates; nearest segments of *other* walks kept per segment (top-k) before verification.
    top_k: int = 8
    # keep a segment candidate only if it is also among the other's top-k (mutual nearest neighbours).
    mutual: bool = True
    # scans; half-length r of the run of consecutive scans compared for a node pair (2r+1 scans,
    # same or opposite walking direction, the better of the two).
    run_half_scans: int = 2
    # search within-walk pairs too (loop closures), verified against the walk's own PDR geometry.
    within_walk: bool = True
    # m; a within-walk pair is kept when its PDR distance is below this plus drift_per_m times the
    # path walked between the two nodes.
    within_gate_m: float = 3.0
    within_drift_per_m: float = 0.02
    # candidates per segment are its best match in each of the top_k closest *walks* (one per walk), so
    # a node's candidates spread over many walks instead of piling onto one look-alike walk.
    # (measured on ILC F1: more walks' candidates but more look-alikes; off by default)
    per_walk: bool = False
    # fingerprint rows per block of the blocked matrix-product search (memory ~ block * n * 4 bytes).
    block_rows: int = 2048

    def validate(self) -> None:
        if self.L_window_steps < 2:
            raise ValueError("L_window_steps must be >= 2")
        if self.max_pairs_per_node < 0 or self.top_k < 1 or self.segment_scans < 1:
            raise ValueError("max_pairs_per_node >= 0, top_k >= 1, segment_scans >= 1 required")
        if self.run_half_scans < 0 or self.block_rows < 16 or self.min_common_aps < 0:
            raise ValueError("run_half_scans >= 0, block_rows >= 16, min_common_aps >= 0 required")


@dataclass(frozen=True)
class VicinityConfig:
    # m; eq. 10: zero error below d_min, linear ramp to e_max at d_max, flat beyond. paper: 2 / 30.
    d_min: float = 0.0
    d_max: float = 6.0
    # e_max (unitless) and Ω_WiFi (information of e); the plateau costs Ω_WiFi·e_max² (paper: not given).
    # Ω = 2 puts a pair's sigma at (d_max - d_min) / sqrt(Ω) = 4.2 m, about the RMS true distance of the
    # pairs the search keeps (median 2.4 m, 10-15 % beyond 5 m). Measured against Ω = 4 (twelve `default`
    # seeds, landmark mean): clean 1.42 -> 1.38 m, 30 % false pairs 1.80 -> 1.68 m; ILC F1 waypoint mean
    # 7.9 -> 7.4 m; corridor12 +0.04 m.
    e_max: float = 1.0
    omega_wifi: float = 2.0
    # how eq. 10 is expressed in GTSAM (bench/bench_optimize.py measures them):
    # "range_tls": RangeFactorPose2(measured=d_min) + TruncatedLeastSquares (exact for d >= d_min, a tiny
    #   push-apart below d_min); "range_custom": RangeFactorPose2(measured=0) + a Python m-estimator with a
    #   dead zone (exact everywhere); "custom_factor": a Python CustomFactor (exact, slowest).
    kernel: Literal["range_tls", "range_custom", "custom_factor"] = "range_tls"
    # anisotropic pairs: a pair whose two nodes walk (anti)parallel, within parallel_max_deg, keeps the
    # pair's sigma along the walking direction but across_ratio times it across (in a corridor two walks
    # that match in Wi-Fi are metres apart along it but about its width apart across it: on the synthetic
    # venues the true offsets of such pairs are 2.4-2.9 m RMS along, 0.9-1.7 m across). Its error is the
    # offset of one node from the other in that node's heading frame, truncated where eq. 10 is (at the
    # Mahalanobis radius e_max·sqrt(Ω)). 0 = estimated from the data: the first solve is isotropic,
    # then after each solve the ratio is set to RMS across / RMS along of the parallel pairs within d_max,
    # clamped to [across_ratio_min, 1], from at least across_min_pairs pairs (else 1); a change by more
    # than across_tol asks for one more solve (within the solve budget; the first switch from isotropic
    # gets one of its own). The pairs of a walk whose step-length scale moved by more than
    # solve.scale_extend_move in the last scale round stay isotropic while the rounds go on: anisotropic
    # pairs hold a walk's stretch in place and its scale stalls short of the truth (`default --raw-imu`
    # 1.38 -> 1.55 m with every pair anisotropic from the second solve). 1 = isotropic, eq. 10 for every
    # pair (the paper). Needs kernel range_tls and d_min = 0, else the pairs stay isotropic.
    # Measured (isotropic -> estimated; landmark mean m / heading mean deg): twelve tuning venues
    # 1.19 / 1.38 -> 0.91 / 1.03, twelve held-out 1.37 / 2.19 -> 1.19 / 2.01, 30 % false pairs
    # 1.40 -> 1.11 m, `large` 1.01 -> 0.86 m (max 4.7 -> 8.2 m), `--raw-imu` 1.38 -> 1.39 m; ILC F1
    # (estimate 0.50) waypoint mean 6.9 -> 6.9 m, built-map kNN median 8.8 -> 8.1 m. A fixed 0.3 from the
    # start: twelve venues 0.97 m / 1.04 deg but ILC F1 7.4-8.0 m; parallel_max_deg 5 / 20: 0.99 / 0.95 m.
    across_ratio: float = 0.0
    across_ratio_min: float = 0.25
    across_min_pairs: int = 50
    across_tol: float = 0.02
    parallel_max_deg: float = 10.0
    # deg; the along/across axes are the poses' headings. A walk whose headings differ from the direction
    # it moves in by more than this (median over its steps: e.g. a device yaw, not a step heading) keeps
    # isotropic pairs, with a warning.
    heading_motion_max_deg: float = 20.0

    def validate(self) -> None:
        if not 0 <= self.d_min < self.d_max:
            raise ValueError("need 0 <= d_min < d_max")
        if not 0 <= self.across_ratio <= 1 or not 0 < self.across_ratio_min <= 1:
            raise ValueError("need 0 <= across_ratio <= 1 and 0 < across_ratio_min <= 1")
        if not 0 <= self.heading_motion_max_deg <= 180:
            raise ValueError("need 0 <= heading_motion_max_deg <= 180")
        if not 0 <= self.parallel_max_deg < 90 or self.across_min_pairs < 1 or self.across_tol < 0:
            raise ValueError("need 0 <= parallel_max_deg < 90, across_min_pairs >= 1 and across_tol >= 0")
        if self.e_max <= 0 or self.omega_wifi <= 0:
            raise ValueError("e_max and omega_wifi must be > 0")


@dataclass(frozen=True)
class InitConfig:
    # "grow": walks placed one round at a time against the map built so far (walk-to-map RANSAC, which
    # pools the evidence of every placed walk a short walk crosses), each round followed by a robust
    # walk-level refinement (rmbuild/slam/grow.py); "ransac": walk-pair RANSAC chained over a spanning tree
    # of walk pairs (needs long shared stretches per pair); "origin": every walk at (0, 0, 0) (paper).
    method: Literal["grow", "ransac", "origin"] = "grow"
    # use yaw_abs_rad (magnetometer heading) when present: per-walk frame rotation and heading prior.
    use_abs_heading: bool = True
    # rad; floor of the 1-sigma of a walk's frame rotation from its yaw_abs (the circular mean over its
    # steps). The sigma used is max(floor, yaw_abs_sigma / sqrt(n_steps / abs_heading_corr_steps)).
    abs_heading_sigma_rad: float = 0.02
    # steps; correlation length of the magnetometer's indoor disturbance (samples this far apart count as
    # independent heading observations).
    abs_heading_corr_steps: int = 10
    # rad; yaw_abs sigma used where the poses table gives none (NaN yaw_abs_sigma_rad).
    default_yaw_sigma_rad: float = 0.25
    # m; a candidate pair is a RANSAC inlier when the hypothesis puts its two nodes within this distance.
    ransac_gate_m: float = 3.0
    # hypotheses per walk pair (unknown heading: 2-pair samples; known heading: all singles up to this).
    ransac_iterations: int = 300
    # RNG seed of the sampler (results are deterministic).
    seed: int = 0
    # a walk pair is accepted with at least this many inliers, this inlier fraction and this much shared
    # path (m; walked length of the inlier stretch on the shorter side).
    min_inliers: int = 5
    min_inlier_ratio: float = 0.2
    min_shared_path_m: float = 8.0
    # rad; when the heading is known, re-fit the rotation from the inliers only if the shared path is long
    # enough (m) to observe it; otherwise keep the magnetometer rotation.
    refit_rotation_min_path_m: float = 20.0
    # --- method "grow" ---
    # m; a pair is an inlier of a walk-to-map hypothesis when it puts its two nodes within this distance
    # (Wi-Fi's resolution plus the magnetometer's rotation error over a short walk).
    grow_gate_m: float = 4.0
    # a walk is placed with at least this many distinct inlier nodes of its own (translation-only fit /
    # SE(2) fit), this much shared path (m; SE(2) needs refit_rotation_min_path_m), and an inlier count at
    # least grow_margin times that of the best hypothesis placing it elsewhere (> 2 gates away).
    grow_min_inliers: int = 3
    grow_min_inliers_se2: int = 6
    grow_min_shared_m: float = 6.0
    grow_margin: float = 1.5
    # distinct inlier nodes; the chosen hypothesis must also lead the best one elsewhere by this many
    # (a ratio alone accepts 3 vs 2, which chance alignments of false pairs reach easily; measured on
    # `default` with 30 % injected false pairs: 0 -> 3.06 m landmark mean, 2 -> 1.38 m; costs short
    # crossing walks some links: 14 x 60-step venue 13 -> 9 linked).
    grow_min_lead: int = 2
    # m of shared path an SE(2) placement needs for a walk without a trusted magnetometer heading (none, or
    # dropped as an outlier); 0 = refit_rotation_min_path_m (as for walks whose translation-only fit failed).
    grow_se2_min_shared_m: float = 0.0
    # spread of a translation-only placement: the walked path between its first and last inlier scan must be
    # at least this fraction of the walk's length (of the fitted window on long walks), so matches clustered
    # at one place (a look-alike spot) do not place a short walk. 0 = off.
    grow_min_span_frac: float = 0.0
    # m; the spread rule applies to walks up to this walked length (long walks seed the map from one crossing).
    grow_span_max_walk_m: float = 40.0
    # rounds of placement (each round: fit every unplaced walk to the map, place all accepted, refine).
    grow_max_rounds: int = 100
    # evidence a walk is fitted with: "knn" (each scan localised on the placed map by its grow_knn_k
    # nearest placed scans in RSS distance, covered when the nearest is below grow_cover_factor x its
    # own walk's window median d_med; a walk needs grow_min_inlier_frac of its covered scans as inliers)
    # or "pairs" (the candidate pairs of the search, counted per distinct scan, with grow_margin).
    # "both": "pairs" first, then "knn" rounds extend the map it built.
    grow_evidence: Literal["knn", "pairs", "both"] = "both"
    grow_knn_k: int = 3
    grow_cover_factor: float = 1.0
    grow_min_inlier_frac: float = 0.5
    # m of walked path; a long walk is fitted on windows of this length (half-overlapping; the best
    # accepted window places it), so its dead-reckoning drift does not break the rigid fit. 0 = whole walk.
    grow_window_m: float = 60.0
    # also place a walk through an accepted walk-pair RANSAC fit (method "ransac"'s rule: min_inliers,
    # min_inlier_ratio, min_shared_path_m) to an already placed walk when its walk-to-map fit fails.
    grow_pair_edges: bool = True
    # after growth, fit each component of >= 2 walks that is not linked to the reference's map rigidly to
    # that map from the pooled candidate pairs of its walks (same acceptance rules as a single walk's fit).
    merge_components: bool = True
    # merge / kNN-growth alternations after the first growth (each merge grows the map the kNN rounds
    # place the remaining walks on); 1 = merge once.
    merge_rounds: int = 3
    # without a configured reference_walk the walk with the most cross-walk candidates seeds the map; when
    # its component ends up smaller (walked path) than another, grow again from that other component's
    # best-connected walk and keep the larger reference component. Measured on ILC F1: a look-alike corner
    # walk seeded a 3-walk component (27 components) when the scan times were shifted by ~1.3 s.
    reselect_reference: bool = True
    # walk-level refinement: m, 1-sigma of a pair's position difference; Cauchy scale in sigmas; Gauss-
    # Newton iterations; pairs within refine_gate_factor * grow_gate_m of each other are used.
    pair_sigma_m: float = 3.0
    robust_c: float = 2.0
    refine_iterations: int = 8
    refine_gate_factor: float = 1.5
    # sigmas; a placed walk whose refined rotation is further than this from its magnetometer rotation
    # has an unreliable magnetometer: its heading priors are dropped.
    heading_outlier_sigmas: float = 4.0
    # m of walked length; in the walk-level refinement a shorter walk keeps its magnetometer rotation (its
    # rotation prior's sigma times short_walk_rot_sigma_scale): over a few metres of lever arm, Wi-Fi pairs
    # metres apart turn it further from the truth than the magnetometer. ILC F1 (median walk 43 steps):
    # rotation error mean 11.2 -> 7.9 deg, waypoint mean 7.5 -> 6.9 m, built-map kNN median 9.8 -> 8.7 m;
    # twelve `default` seeds unchanged (landmark mean 1.35 -> 1.36 m). 60 m: F1 the same, seeds 1.41 m.
    # The scale is flat between 0.03 and 0.3 on F1; 0 = off.
    short_walk_m: float = 40.0
    short_walk_rot_sigma_scale: float = 0.1

    def validate(self) -> None:
        if self.short_walk_m < 0 or self.short_walk_rot_sigma_scale <= 0:
            raise ValueError("short_walk_m >= 0 and short_walk_rot_sigma_scale > 0 required")
        if self.grow_gate_m <= 0 or self.grow_min_inliers < 1 or self.grow_min_inliers_se2 < 2:
            raise ValueError("grow_gate_m > 0, grow_min_inliers >= 1, grow_min_inliers_se2 >= 2 required")
        if self.grow_se2_min_shared_m < 0 or not 0 <= self.grow_min_span_frac <= 1:
            raise ValueError("grow_se2_min_shared_m >= 0 and 0 <= grow_min_span_frac <= 1 required")
        if self.grow_margin < 1 or self.grow_max_rounds < 1 or self.refine_iterations < 1:
            raise ValueError("grow_margin >= 1, grow_max_rounds >= 1, refine_iterations >= 1 required")
        if self.pair_sigma_m <= 0 or self.robust_c <= 0 or self.refine_gate_factor <= 0:
            raise ValueError("pair_sigma_m, robust_c and refine_gate_factor must be > 0")
        if self.abs_heading_corr_steps < 1 or self.default_yaw_sigma_rad <= 0:
            raise ValueError("abs_heading_corr_steps >= 1 and default_yaw_sigma_rad > 0 required")
        if self.abs_heading_sigma_rad <= 0 or self.ransac_gate_m <= 0:
            raise ValueError("abs_heading_sigma_rad and ransac_gate_m must be > 0")
        if self.ransac_iterations < 1 or self.min_inliers < 2 or not 0 <= self.min_inlier_ratio <= 1:
            raise ValueError("ransac_iterations >= 1, min_inliers >= 2, 0 <= min_inlier_ratio <= 1 required")


@dataclass(frozen=True)
class SolveConfig:
    # Levenberg-Marquardt iterations per solve, and its relative / absolute cost-decrease stops. Each solve
    # but the last is followed by another (outer loop, scale rounds) that starts where it stopped: 10
    # instead of 15 leaves twelve tuning and twelve held-out venues and ILC F1 where they were and takes
    # `large` 47.4 -> 40.3 s (same run; 41 -> 36 iterations).
    max_iterations: int = 10
    relative_error_tol: float = 1e-3
    absolute_error_tol: float = 1e-6
    # Levenberg-Marquardt damping schedule (gtsam's LevenbergMarquardtParams): the first lambda, the factor
    # it is multiplied by after a rejected step, whether that factor stays fixed (else Nielsen's update:
    # lambda shrinks by how well the linear model predicted the decrease, the factor doubles on each
    # rejection) and whether the damping is scaled by the Hessian's diagonal.
    lm_lambda_initial: float = 1e-5
    lm_lambda_factor: float = 10.0
    lm_fixed_lambda_factor: bool = False
    lm_diagonal_damping: bool = False
    # chain reduction (slam/chains.py): steps that carry only odometry are eliminated before the solve;
    # consecutive keyframes (nodes with a vicinity pair, heading prior, anchor or gauge, each walk's ends,
    # and one node at least every keyframe_max_gap steps) are joined by the composed PDR increment with
    # its propagated covariance, and the steps between are put back after each solve. False = one node
    # per step in the solve (the literal graph).
    chain_reduction: bool = True
    keyframe_max_gap: int = 20
    # "METIS" or "COLAMD" elimination ordering (FINDINGS: METIS ~3x faster at 50k poses).
    ordering: Literal["METIS", "COLAMD"] = "METIS"
    # poses; below this COLAMD is used whatever ``ordering`` says (METIS only pays off on big graphs).
    metis_min_poses: int = 5000
    # outer loop: after each solve keep only pairs whose current distance is below d_max (the rest add
    # nothing but fill-in), then solve again; at most this many solves.
    outer_iterations: int = 3
    # graduated kernel: the first solves widen eq. 10's band by these factors (d_max and e_max times f, so
    # the slope inside the band, i.e. the pair's sigma, is unchanged; only the truncation moves out), and
    # admit every verified pair currently within f * d_max. A drifted stretch of a long walk whose true
    # partners start 6-15 m away is pulled in before the band narrows to d_max for the final solves.
    # () = off. The widened solves come before the outer_iterations ones. Off by default: measured with
    # (2.0,) it helps the `default` venue (six seeds: landmark mean 1.65 -> 1.47 m, worst max 25.6 -> 7.6 m;
    # large 1.72 -> 1.47 m) but costs the test venue of slam/testing.py (seed 3: 1.43 -> 2.26 m) and ILC F1
    # (waypoint mean 7.7 -> 8.3 m): a widened band also lets a wrong pair pull from further away.
    gnc_factors: tuple[float, ...] = ()
    # m; only pairs with a node on a walk at least this long (walked PDR length) are widened: drift is what
    # the widening is for, and short walks (phone walks of ~30 s) have little of it while their pairs are
    # the ones most often wrong.
    gnc_min_walk_m: float = 100.0
    # one walk-by-walk pass is implied by the initialisation; the joint solve uses these priors:
    # m / rad; 1-sigma of the gauge prior on the reference walk's first pose.
    gauge_sigma_m: float = 1e-3
    gauge_sigma_rad: float = 1e-4
    # m; 1-sigma of an anchor position prior.
    anchor_sigma_m: float = 0.5
    # s; an anchor may lie this far before a walk's first pose or after its last (it then fixes that end
    # pose); further out is an input error. A landmark press often comes just before the first step.
    anchor_max_gap_s: float = 2.0
    # steps; per-pose heading prior from yaw_abs in the joint solve on every n-th step (0 = off), with
    # the step's yaw_abs_sigma_rad times heading_prior_sigma_scale (n ~ the disturbance's correlation
    # length, so the priors are roughly independent). They also correct the PDR's heading drift.
    # Scale 1 (was 3): six `default` seeds heading mean 3.02 -> 2.36 deg (landmark mean 1.65 -> 1.67 m),
    # ILC F1 waypoint mean 8.1 -> 7.0 m, kNN built median 11.8 -> 10.6 m (F1 moves +-0.4 m with LM's stop).
    heading_prior_every_n: int = 10
    heading_prior_sigma_scale: float = 1.0
    # Cauchy kernel width (in sigmas) on each heading prior (0 = Gaussian): a local disturbance (steel,
    # escalators) far beyond the reported sigma then bends the walk less. 1 (with scale 1): six `default`
    # seeds landmark mean 1.64 -> 1.38 m, worst max 15.2 -> 7.1 m, heading 2.10 -> 2.01 deg.
    heading_prior_cauchy_k: float = 1.0
    # checks: a solution whose per-step odometry residual RMS exceeds this many sigmas, or a walk whose
    # extent shrinks below this fraction of its raw PDR extent, is "worse by construction": the solver
    # falls back to the initial poses for the whole map (reported in warnings).
    max_odometry_rms_sigma: float = 5.0
    min_extent_ratio: float = 0.8
    # --- per-walk step-length scale (phone PDR: uncalibrated step length per user) ---
    # estimate one scale s_w per walk: after a solve, each linked walk's solved path is fitted to its
    # in-range cross-walk pair partners with a robust scale + translation fit (about the walk's own
    # positions), s_w is updated (clamped to [scale_min, scale_max], shrunk toward 1 with scale_prior_sigma),
    # the walk's odometry increments are rescaled by s_w and the graph is solved again (up to
    # scale_iterations extra solves, until no s_w moves by more than scale_tol). Reported in walks.scale.
    # On (with mu 8000; landmark mean / median max m, heading deg): twelve tuning venues 1.26 / 3.79 /
    # 1.50 -> 1.19 / 3.21 / 1.46, twelve held-out 1.55 / 4.30 / 2.28 -> 1.37 / 3.59 / 2.24, `large`
    # 1.44 / 16.3 -> 1.06 / 7.4 m; ILC F1 unchanged (only walks spanning >= scale_min_span_m are fitted).
    estimate_scale: bool = True
    scale_min: float = 0.7
    scale_max: float = 1.4
    # 1-sigma of the prior s_w ~ 1 (relative); weighs against the pair fit's own precision.
    scale_prior_sigma: float = 0.15
    # each round is one more solve (`large`: ~6 s); 3 rounds: twelve venues 1.16 m, `large` 1.01 m in 47 s
    # instead of 39 s.
    scale_iterations: int = 2
    scale_tol: float = 0.005
    # further rounds, up to scale_max_iterations in all, while the last round still moved some s_w by more
    # than scale_extend_move: a stretch far from converged (an uncalibrated phone step length; `default
    # --raw-imu` seed 7 landmark mean 2.30 m after 2 rounds, 1.37 m after 8), where a foot IMU's few per
    # cent have settled (measured below and in docs/optimize.md). 0 = always scale_max_iterations rounds.
    scale_max_iterations: int = 8
    scale_extend_move: float = 0.03
    # a walk's scale is fitted only with at least this many in-range cross pairs spread over at least
    # scale_min_span_m of its solved path (extent of the paired nodes); otherwise s_w stays. Over a short
    # span the pairs' metres of spread swamp a few per cent of stretch: ILC F1 (~30 s walks) with 15 m
    # fitted 46 walks to 0.70-1.40 and went 6.9 -> 10.8 m waypoint mean; 40 m: 11 walks, 8.7 m; 60 m:
    # 5 walks (0.97-1.05), 6.9 m. Synthetic venues gain alike with 15-100 m.
    scale_min_pairs: int = 20
    scale_min_span_m: float = 60.0
    # m; cross pairs of the pool within this distance at the current solution feed the fit (0 = d_max, the
    # pairs of the solve).
    scale_pair_gate_m: float = 0.0
    # m; Cauchy scale of the robust (IRLS) fit of pair residuals.
    scale_robust_m: float = 3.0
    # rescale all fitted s_w so their median is 1 when no anchors fix the map scale
    # (Wi-Fi vicinity factors alone cannot observe the map's overall scale).
    scale_normalize: bool = True

    def validate(self) -> None:
        if self.max_iterations < 1 or self.outer_iterations < 1 or self.heading_prior_every_n < 0:
            raise ValueError("max_iterations >= 1, outer_iterations >= 1, heading_prior_every_n >= 0")
        if self.keyframe_max_gap < 1:
            raise ValueError("solve.keyframe_max_gap must be >= 1")
        if not (self.lm_lambda_initial > 0 and self.lm_lambda_factor > 1):
            raise ValueError("lm_lambda_initial > 0 and lm_lambda_factor > 1")
        if self.heading_prior_sigma_scale <= 0 or self.heading_prior_cauchy_k < 0:
            raise ValueError("heading_prior_sigma_scale must be > 0 and heading_prior_cauchy_k >= 0")
        if any(not 1.0 <= f <= 20.0 for f in self.gnc_factors):
            raise ValueError("solve.gnc_factors must each be in [1, 20]")
        if self.gnc_min_walk_m < 0:
            raise ValueError("solve.gnc_min_walk_m must be >= 0")
        if self.anchor_max_gap_s < 0:
            raise ValueError("solve.anchor_max_gap_s must be >= 0")
        if self.gauge_sigma_m <= 0 or self.gauge_sigma_rad <= 0 or self.anchor_sigma_m <= 0:
            raise ValueError("gauge and anchor sigmas must be > 0")
        if not 0 < self.scale_min <= 1 <= self.scale_max or self.scale_prior_sigma <= 0:
            raise ValueError("need 0 < scale_min <= 1 <= scale_max and scale_prior_sigma > 0")
        if self.scale_iterations < 0 or self.scale_tol < 0 or self.scale_min_pairs < 3 or self.scale_robust_m <= 0:
            raise ValueError("scale_iterations >= 0, scale_tol >= 0, scale_min_pairs >= 3, scale_robust_m > 0")
        if self.scale_max_iterations < self.scale_iterations or self.scale_extend_move < 0:
            raise ValueError("solve.scale_max_iterations must be >= scale_iterations and scale_extend_move >= 0")
        if self.scale_min_span_m < 0 or self.scale_pair_gate_m < 0:
            raise ValueError("solve.scale_min_span_m and solve.scale_pair_gate_m must be >= 0")


@dataclass(frozen=True)
class OptimizeConfig:
    # "robust" (rmbuild's pipeline) or "paper" (seed 001 as written; see paper_config()).
    pipeline: Literal["robust", "paper"] = "robust"
    # walk_id of the reference walk whose first pose is fixed; "" = the walk with most cross-walk links.
    reference_walk: str = ""
    # what to do with a walk of fewer than 2 poses: "error" (InputError) or "skip" (kept at its raw pose,
    # reported unlinked with a warning).
    single_step_walks: Literal["error", "skip"] = "skip"
    # test hook: fraction of vicinity pairs replaced by random false pairs before solving (robustness test).
    inject_false_pairs: float = 0.0
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    pairs: PairConfig = field(default_factory=PairConfig)
    vicinity: VicinityConfig = field(default_factory=VicinityConfig)
    init: InitConfig = field(default_factory=InitConfig)
    solve: SolveConfig = field(default_factory=SolveConfig)

    def validate(self) -> None:
        if not 0 <= self.inject_false_pairs < 1:
            raise ValueError("inject_false_pairs must be in [0, 1)")
        for sub in (self.odometry, self.pairs, self.vicinity, self.init, self.solve):
            sub.validate()


def paper_config(**overrides) -> OptimizeConfig:
    """Seed 001's model: origin start, median-window pairs, Ω_IMU = diag(1, 1, 20), d_min 2 m, d_max 30 m."""
    cfg = OptimizeConfig(
        pipeline="paper",
        odometry=OdometryConfig(sigma_x_m=1.0, sigma_y_m=1.0, mu=20.0),
        vicinity=VicinityConfig(d_min=2.0, d_max=30.0, e_max=1.0, omega_wifi=1.0, across_ratio=1.0),
        init=InitConfig(method="origin", use_abs_heading=False),
        # one node per step, as published (with the paper's weak odometry, sigma 1 m per step, the composed
        # keyframe factors linearise differently enough to move its folded solutions: twelve seeds
        # landmark mean 6.32 m as written, 6.81 m reduced)
        solve=SolveConfig(outer_iterations=1, heading_prior_every_n=0, max_iterations=50,
                          max_odometry_rms_sigma=1e9, min_extent_ratio=0.0, chain_reduction=False,
                          estimate_scale=False),
    )
    return replace(cfg, **overrides)
