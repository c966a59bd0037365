"""Settings of the paper baselines (TOML ``[evaluate.baselines.<name>]``): SLAC, MLL, PFL, SSD, SSR, naive
Bayes, SmartLocator's fusion, the RSS-histogram matchers, Kalman smoothing and the offline device
calibration (docs/baselines.md). ``rmbuild config --all`` prints them; ``rmbuild config`` leaves them out.

Every number the papers give is a field with its paper default (docs/baselines.md cites them): SLAC (He,
Chan, Yu, Liu, UbiComp 2015) and its baselines MLL, PFL, SSD, SSR and offline linear fitting; SmartLocator
(Becker, Jäger, Süß, ICONS 2015: naive Bayes, auto-adaptive fusion); the subway-station Wi-Fi + PDR paper
(RSS histograms, direction-aware fingerprints, Kalman smoothing); UILoc (Sensors 2018: particle step and
heading corrections). Fields the papers leave open carry our default and say so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from rmbuild.config.base import bounded, check_ranges

#: largest seed a localizer's random generator takes from the config (numpy accepts any non-negative int;
#: 32 bits are plenty and keep the value a plain TOML integer)
MAX_SEED = 2**32 - 1


def _ordered(name: str, r: tuple[float, float]) -> None:
    if not r[0] <= r[1]:
        raise ValueError(f"{name}: lower bound {r[0]} > upper bound {r[1]}")


@dataclass(frozen=True)
class SlacConfig:
    """SLAC: simultaneous localization and calibration (He et al. 2015, eq. 5-29, Algorithm 1)."""

    # scans; sliding window M of temporal targets jointly localized (He et al. 2015: 7).
    window_scans: int = bounded(7, 2, 1000)
    # 1; particles P over the device model [k, b] (He et al. 2015: 60).
    n_particles: int = bounded(60, 1, 10000)
    # m; σ_w, sensitivity of the particle weight to walked vs. estimated distance (eq. 22; He et al. 2015: 1).
    sigma_w_m: float = bounded(1.0, 0.001, 100.0)
    # 1; η, confidence factor of the convergence test ξ <= η sqrt(Var δ) (eq. 29; He et al. 2015: 1).
    eta: float = bounded(1.0, 0.001, 100.0)
    # m; T, Berhu loss threshold (eq. 17; He et al. 2015: 2).
    berhu_t_m: float = bounded(2.0, 0.001, 100.0)
    # 1; N, candidate RPs per scan (the N smallest Γ) and the count in λ = max Γ / Σ Γ (eq. 14; He et al. 2015: 10).
    n_candidates: int = bounded(10, 1, 1000)
    # 1; an RP sharing fewer than this fraction of a scan's detected APs is not a candidate for it (ours:
    # Γ averages over shared APs only, so RPs sharing one lucky AP would win; when no RP reaches it, the
    # RPs sharing the most APs are the candidates). 0 = He et al. 2015 as written.
    min_shared_fraction: float = bounded(0.8, 0.0, 1.0)
    # 1; g >= 1, signal bound γ = g Σ_m min_q Γ (eq. 19). Not given in He et al. 2015; ours. Raised to the
    # smallest feasible bound when the cap ω <= λ makes g Σ min Γ unreachable.
    g: float = bounded(1.3, 1.0, 100.0)
    # m/Hz; initial / allowed range of α in the step model S = α f + β (He et al. 2015: [0.1, 1]).
    alpha_range: tuple[float, float] = bounded((0.1, 1.0), 0.0, 5.0)
    # m; initial / allowed range of β (He et al. 2015: [-0.5, 0]).
    beta_range: tuple[float, float] = bounded((-0.5, 0.0), -5.0, 5.0)
    # 1; initial range of the device gain k (He et al. 2015: [0.1, 6]).
    k_range: tuple[float, float] = bounded((0.1, 6.0), 0.001, 100.0)
    # dB; initial range of the device offset b (He et al. 2015: [-10, 0]).
    b_range_db: tuple[float, float] = bounded((-10.0, 0.0), -100.0, 100.0)
    # Which way [k, b] maps signals. "device": the test device reads φ = k ψ + b for a map-device reading ψ
    # (the simulator's model; the map is compared with (φ - b) / k). "calibration": He et al. 2015, eq. 5 literally,
    # φ̃ = k φ + b is compared with the map.
    device_model: Literal["device", "calibration"] = "device"
    # Particle weight (eq. 22). "distance": He et al. 2015, walked vs. estimated window distance only;
    # "distance_signal": also the Gaussian likelihood of the scans given the weighted RPs (ours; makes
    # [k, b] identifiable when the distance test alone is not, see docs/notes/localizers.md).
    particle_weight: Literal["distance", "distance_signal"] = "distance_signal"
    # dB; per-AP noise std of the signal likelihood under particle_weight = "distance_signal" (ours).
    signal_sigma_db: float = bounded(4.0, 0.1, 100.0)
    # dBm (device units); detection floor of the detection likelihood under "distance_signal" (ours): an
    # AP of the RP is expected in the scan with probability (1 - miss_prob) Φ((k ψ̄ + b - floor) / s), and
    # its absence or presence is scored. None = score only the detected APs' values.
    detect_floor_dbm: float | None = bounded(-100.0, -200.0, 0.0)
    # 1; probability that a clearly audible AP is still missing from a scan (detection likelihood).
    miss_prob: float = bounded(0.15, 0.0, 0.99)
    # 1; roughening after resampling: jitter std = roughen * (particle spread) * P^(-1/2) per parameter
    # (not in He et al. 2015: without it, [k, b] can never be finer than the initial draw).
    roughen: float = bounded(0.3, 0.0, 10.0)
    # "frequency": δ = Σ (α f_c + β) with [α, β] calibrated (He et al. 2015); "pdr": δ = Σ PDR step lengths
    # (α, β not calibrated; also the fallback, named in the result, when a walk has no step frequencies).
    step_source: Literal["frequency", "pdr"] = "frequency"
    # What to do with a walk that has no step events: "error" (InputError) or "fingerprint_only" (no
    # distance term: each scan's weights from Γ alone, no calibration; named in the result).
    no_steps: Literal["error", "fingerprint_only"] = "error"
    # What replaces a missing σ (T < 2 readings, or a map without std): "median" (median σ of the map,
    # 0 when it has none; named in the result), "zero", or "error" (InputError when the map has no std).
    missing_std: Literal["median", "zero", "error"] = "median"
    # After ξ <= η sqrt(Var δ): continue with P = 1 and fixed [k, b, α, β] (He et al. 2015). False: never.
    converge: bool = True
    # scans; the convergence test runs only once at least this many scans of the walk were seen (ours;
    # with fewer, the particles collapse on little evidence and the test passes too early:
    # docs/notes/localizers.md). 0 = the window size M (He et al. 2015).
    min_scans_to_converge: int = bounded(30, 0, 100000)
    # 1; projected-gradient iterations of the joint optimisation per window (warm-started).
    solver_iters: int = bounded(60, 1, 10000)
    # m; smoothing of |z| and of ‖x_m - x_n‖ near 0 in the joint optimisation (their kinks).
    solver_eps_m: float = bounded(0.05, 0.0001, 10.0)
    # 1; seed of the particle draws and resampling.
    seed: int = bounded(0, 0, MAX_SEED)

    def validate(self) -> None:
        check_ranges(self, "slac.")
        for name in ("alpha_range", "beta_range", "k_range", "b_range_db"):
            _ordered(f"slac.{name}", getattr(self, name))


@dataclass(frozen=True)
class BayesConfig:
    """Naive Bayes with a Gaussian kernel per AP (Becker et al. 2015 eq. 1-5)."""

    # dB; kernel bandwidth σ of eq. 4 (Becker et al. 2015 gives none; ours). The per-RP kernel density of eq. 3 is
    # taken as N(ψ̄, σ² + σ_q²) with σ_q the RP's std when the map has it.
    kernel_sigma_db: float = bounded(4.0, 0.1, 100.0)
    # dBm; a reading missing on one side counts as this value (Gu et al. 2017, eq. 9: -110).
    fill_dbm: float = bounded(-110.0, -200.0, 0.0)
    # 1; position interpolated from the K most probable RPs (eq. 5; Becker et al. 2015: 3).
    k: int = bounded(3, 1, 1000)
    # "cells" or "nodes": which view of a radio map the RPs are.
    reference: Literal["cells", "nodes"] = "cells"

    def validate(self) -> None:
        check_ranges(self, "nb.")


@dataclass(frozen=True)
class SsdConfig:
    """Signal-strength-difference fingerprints (He et al. 2015's online calibration baseline [26]).

    The mean over AP pairs of the squared difference of pairwise differences equals twice the variance of
    the per-AP residual φ - ψ over the shared APs, so a constant offset b cancels exactly.
    """

    # 1; K nearest RPs by SSD distance, mean position (He et al. 2015's FL uses 15).
    k: int = bounded(15, 1, 1000)
    # 1; RPs sharing fewer detected APs with the scan are never neighbours (>= 2: one pair).
    min_shared_aps: int = bounded(3, 2, 1000)
    # 1; and sharing fewer than this fraction of the scan's detected APs.
    min_shared_fraction: float = bounded(0.5, 0.0, 1.0)
    # "cells" or "nodes".
    reference: Literal["cells", "nodes"] = "cells"

    def validate(self) -> None:
        check_ranges(self, "ssd.")


@dataclass(frozen=True)
class PflConfig:
    """PFL: particle filter fusing PDR steps with fingerprint fixes (He et al. 2015's baseline; Chen et al. 2018's
    particle corrections of step length and heading)."""

    # 1; particles.
    n_particles: int = bounded(500, 1, 100000)
    # m; σ of the initial position spread around the first scan's fingerprint fix.
    init_sd_m: float = bounded(5.0, 0.001, 1000.0)
    # m; σ of the fingerprint fix (kNN position) in the measurement likelihood.
    fix_sd_m: float = bounded(6.0, 0.001, 1000.0)
    # 1; K of the kNN fix (He et al. 2015's FL: 15).
    knn_k: int = bounded(15, 1, 1000)
    # 1; σ of the per-particle step-length scale around 1 (Chen et al. 2018: step length bias per particle).
    step_scale_sd: float = bounded(0.1, 0.0, 1.0)
    # 1; σ of the per-step random step-length noise (relative).
    step_noise: float = bounded(0.05, 0.0, 1.0)
    # rad; σ of the per-step heading noise added to the particles' heading offset (Chen et al. 2018: heading bias).
    heading_noise_rad: float = bounded(0.03, 0.0, math.pi)
    # "uniform": the walk frame's rotation into the map frame is unknown (uniform in [0, 2π));
    # "zero": the walk frame is the map frame's orientation.
    heading_init: Literal["uniform", "zero"] = "uniform"
    # 1; resample when the effective sample size falls below this fraction of the particles.
    resample_ess: float = bounded(0.5, 0.0, 1.0)
    # 1; seed.
    seed: int = bounded(0, 0, MAX_SEED)

    def validate(self) -> None:
        check_ranges(self, "pfl.")


@dataclass(frozen=True)
class SmoothingConfig:
    """Kalman post-filter of a localizer's track using PDR displacements (the subway-station paper §C)."""

    # m; σ of a localizer position (measurement noise R = σ²).
    measurement_sd_m: float = bounded(4.0, 0.001, 1000.0)
    # m; process noise per scan interval, added to the PDR-predicted displacement (Q = (σ0 + σ1 d)², d =
    # PDR distance walked).
    process_sd_m: float = bounded(0.5, 0.0, 100.0)
    # 1; process noise growing with the PDR distance walked in the interval (σ1).
    process_sd_per_m: float = bounded(0.1, 0.0, 10.0)
    # scans; the rotation of the walk's PDR frame into the map frame is the least-squares angle between
    # PDR and localizer displacements over the last this many scans (causal).
    rotation_window_scans: int = bounded(15, 2, 10000)
    # "filter": causal Kalman filter (the subway-station paper); "rts": plus a Rauch-Tung-Striebel
    # backward pass (offline).
    mode: Literal["filter", "rts"] = "filter"

    def validate(self) -> None:
        check_ranges(self, "smoothing.")
        if self.process_sd_m == 0 and self.process_sd_per_m == 0:
            raise ValueError("smoothing: process noise must not be 0")


@dataclass(frozen=True)
class SsrConfig:
    """Signal-strength-ratio fingerprints (SLAC's online-calibration baseline SSR): the pairwise ratios
    φ_i / φ_j of the RSSI values in dBm, compared as log-ratios, so a device gain k cancels exactly."""

    # 1; K nearest RPs by SSR distance, mean position (SLAC's FL uses 15).
    k: int = bounded(15, 1, 1000)
    # 1; RPs sharing fewer detected APs with the scan are never neighbours (>= 2: one pair).
    min_shared_aps: int = bounded(3, 2, 1000)
    # 1; and sharing fewer than this fraction of the scan's detected APs.
    min_shared_fraction: float = bounded(0.5, 0.0, 1.0)
    # "cells" or "nodes".
    reference: Literal["cells", "nodes"] = "cells"

    def validate(self) -> None:
        check_ranges(self, "ssr.")


@dataclass(frozen=True)
class MllConfig:
    """MLL: maximum likelihood of the Wi-Fi fingerprints and the walked distances over a window of scans
    (SLAC's baseline MLL; conditional independence between scans and steps, as the paper describes it)."""

    # scans; the window over which the likelihood product is maximised (SLAC's window M = 7; MLL's own is
    # not given).
    window_scans: int = bounded(7, 1, 1000)
    # 1; RPs per scan kept as states (the most likely by Wi-Fi alone; ours, bounds the cost).
    n_candidates: int = bounded(30, 1, 1000)
    # m; σ of the walked-distance likelihood N(‖r_m − r_{m−1}‖ − δ_m; 0, σ²) (SLAC's T = 2 m, its measured
    # walked-distance error).
    motion_sd_m: float = bounded(2.0, 0.001, 100.0)
    # dB; σ of the per-AP Gaussian Wi-Fi likelihood (as naive Bayes: N(ψ̄, σ² + σ_q²); ours).
    kernel_sigma_db: float = bounded(4.0, 0.1, 100.0)
    # dBm; a reading missing on one side counts as this value.
    fill_dbm: float = bounded(-110.0, -200.0, 0.0)
    # "cells" or "nodes".
    reference: Literal["cells", "nodes"] = "cells"

    def validate(self) -> None:
        check_ranges(self, "mll.")


@dataclass(frozen=True)
class SmartLocatorConfig:
    """SmartLocator's auto-adaptive dead reckoning (Becker et al. 2015 eq. 8-9): each naive-Bayes fix is
    blended into the PDR-propagated position with weight α = min(Q + α_t, 1)."""

    # 1; the largest accuracy factor Q a Wi-Fi fix gets (paper Fig. 6: 0.3); Q rises linearly from 0 to it
    # over aps_range APs in the scan.
    q_max: float = bounded(0.3, 0.0, 1.0)
    # APs; Q = 0 at the lower count, q_max at the upper (paper Fig. 6: 2 and 5).
    aps_range: tuple[float, float] = bounded((2.0, 5.0), 0.0, 1000.0)
    # 1/s; the time-dependent factor α_t grows by this per second since the last fix (paper Fig. 4: 0.04).
    time_gain_per_s: float = bounded(0.04, 0.0, 10.0)
    # 1; and stops growing here (paper Fig. 4: 0.4 at 10 s).
    time_gain_max: float = bounded(0.4, 0.0, 1.0)
    # 1; α of the static-weight variant `smartloc_static` (the paper's comparison: 0.5).
    static_weight: float = bounded(0.5, 0.001, 1.0)
    # scans; the walk's PDR frame is rotated into the map frame by the least-squares angle between PDR and
    # fix displacements over the last this many scans (ours: the paper's PDR heading is a compass heading).
    rotation_window_scans: int = bounded(15, 2, 10000)

    def validate(self) -> None:
        check_ranges(self, "smartloc.")
        _ordered("smartloc.aps_range", self.aps_range)
        if self.aps_range[0] == self.aps_range[1]:
            raise ValueError("smartloc.aps_range needs two different bounds")


@dataclass(frozen=True)
class HistogramLocConfig:
    """Matching single scans against per-cell RSS histograms (the subway-station paper's §III-B),
    optionally with the walking direction (`hist_dir`)."""

    # How an RP is scored. "mark": the paper's feature matching and probability mark (an RP is a candidate
    # when match_fraction of the scan's APs fall into occupied bins; mark = D · mean of Pr · R over them;
    # the best marks holding mark_share of the total are averaged). "likelihood" (ours): the product over
    # the scan's APs of the bin probabilities (floor_prob where the RP's histogram has none), times D;
    # the k most probable RPs averaged, posterior-weighted.
    scoring: Literal["mark", "likelihood"] = "likelihood"
    # dB; each map reading is spread over the neighbouring bins by a Gaussian of this σ before matching
    # (ours; 0 = the paper's plain histograms, whose bins a single scan rarely hits when a cell holds only
    # a few readings per AP).
    smooth_db: float = bounded(4.0, 0.0, 20.0)
    # 1; "mark": an RP is a candidate when at least this fraction of the scan's APs fall into an occupied
    # bin of its histograms (paper: 70 %); when none reaches it, those matching the most APs are.
    match_fraction: float = bounded(0.7, 0.0, 1.0)
    # 1; "mark": the best-marked candidates whose marks add up to this share of all candidates' marks are
    # averaged, weighted by mark (paper: 5 %).
    mark_share: float = bounded(0.05, 0.0001, 1.0)
    # 1; "likelihood": probability of a reading in a bin where the RP's histogram of that AP has none.
    floor_prob: float = bounded(0.01, 1e-9, 0.99)
    # 1; "likelihood": the position is the posterior-weighted mean of the k most probable RPs.
    k: int = bounded(3, 1, 1000)
    # 1; D, the score's gain when the RP's walking direction is the walker's (paper: 1.2).
    direction_gain: float = bounded(1.2, 1.0, 100.0)
    # scans; `hist_dir` rotates the walk's PDR directions into the map frame by the least-squares angle
    # between PDR and its own direction-free fix displacements over the last this many scans (ours).
    rotation_window_scans: int = bounded(15, 2, 10000)

    def validate(self) -> None:
        check_ranges(self, "hist.")


@dataclass(frozen=True)
class OfflineCalibrationConfig:
    """`offline_cal`: a localizer run on scans mapped back by a device model fitted offline (SLAC's
    comparison case), φ_device = k ψ_map + b; see rmbuild.baselines.calibration.fit_device_model."""

    # 1; the test device's gain k against the map's device (1 = same device).
    k: float = bounded(1.0, 0.001, 100.0)
    # dB; the test device's offset b (0 = same device).
    b_db: float = bounded(0.0, -100.0, 100.0)
    # registry name of the localizer that runs on the mapped scans (a single-scan one: knn, wknn, nb, ...).
    base: str = "knn"

    def validate(self) -> None:
        check_ranges(self, "offline_cal.")
        if self.base == "offline_cal":
            raise ValueError("offline_cal.base must name another localizer")


@dataclass(frozen=True)
class BaselinesConfig:
    """Every baseline's settings, one table each (``[evaluate.baselines.slac]``, ...)."""

    # SLAC (He et al. 2015) and its comparison cases MLL, PFL, SSD, SSR and offline linear fitting
    slac: SlacConfig = field(default_factory=SlacConfig)
    mll: MllConfig = field(default_factory=MllConfig)
    pfl: PflConfig = field(default_factory=PflConfig)
    ssd: SsdConfig = field(default_factory=SsdConfig)
    ssr: SsrConfig = field(default_factory=SsrConfig)
    offline_cal: OfflineCalibrationConfig = field(default_factory=OfflineCalibrationConfig)
    # SmartLocator (Becker et al. 2015): naive Bayes and its fusion with PDR
    nb: BayesConfig = field(default_factory=BayesConfig)
    smartloc: SmartLocatorConfig = field(default_factory=SmartLocatorConfig)
    # the subway-station paper: RSS histograms and the Kalman post-filter of the *_kf variants
    hist: HistogramLocConfig = field(default_factory=HistogramLocConfig)
    smoothing: SmoothingConfig = field(default_factory=SmoothingConfig)

    def validate(self) -> None:
        for sub in (self.slac, self.mll, self.pfl, self.ssd, self.ssr, self.offline_cal, self.nb, self.smartloc,
                    self.hist, self.smoothing):
            sub.validate()
