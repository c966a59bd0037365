"""Config of `rmbuild simulate`: the seeded synthetic venue (floor plan, radio, walkers, sensors).

Every field carries its unit and meaning in a comment. ``(lo, hi)`` tuples are uniform ranges a value is
drawn from per AP / user / walk / device. :func:`preset_config` returns the named presets (``tiny``,
``default``, ``large``, ``corridor12``); the dataclass defaults are the ``default`` preset with seed 7.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal


def _range(name: str, r: tuple[float, float], lo: float | None = None, hi: float | None = None) -> None:
    if not r[0] <= r[1]:
        raise ValueError(f"{name}: lower bound {r[0]} > upper bound {r[1]}")
    if lo is not None and r[0] < lo:
        raise ValueError(f"{name}: values must be >= {lo}, got {r[0]}")
    if hi is not None and r[1] > hi:
        raise ValueError(f"{name}: values must be <= {hi}, got {r[1]}")


def _pos(name: str, v: float, strict: bool = True) -> None:
    if (strict and not v > 0) or (not strict and not v >= 0):
        raise ValueError(f"{name} must be {'> 0' if strict else '>= 0'}, got {v}")


def _prob(name: str, v: float) -> None:
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {v}")


@dataclass(frozen=True)
class VenueConfig:
    # m; building extent along x (east). The hall takes the east end, offices + corridors the rest.
    width_m: float = 130.0
    # m; building extent along y (north).
    height_m: float = 80.0
    # count; corridors running along x through the office part (>= 1).
    n_x_corridors: int = 3
    # count; corridors running along y through the office part (0 = none).
    n_y_corridors: int = 3
    # m; clear width of every corridor.
    corridor_width_m: float = 3.0
    # m; nominal room width along its corridor (rooms are split evenly, so actual widths vary a little).
    room_width_m: float = 7.0
    # m; a block deeper than twice this holds two rows of rooms (one per corridor), else one row.
    min_room_depth_m: float = 5.0
    # m; door opening width (a gap in the room's corridor wall).
    door_width_m: float = 1.2
    # m; width (along x) of the open hall at the east end spanning the full height; 0 = no hall.
    hall_width_m: float = 38.0
    # count; small closed boxes (shops, kiosks, 3-5 m wide) standing in the hall.
    n_hall_kiosks: int = 6
    # m; spacing of the walkable grid laid over the hall (navigation graph).
    hall_grid_m: float = 5.0
    # dB; attenuation of one corridor / hall-facing wall (signal crossing it once).
    corridor_wall_atten_db: float = 5.0
    # dB; attenuation of one partition wall between rooms.
    partition_atten_db: float = 3.5
    # dB; attenuation of one kiosk wall in the hall.
    kiosk_atten_db: float = 2.5
    # dB; attenuation of the building's outer wall (only for plots: everything is inside).
    outer_wall_atten_db: float = 12.0
    # count; landmarks (corridor junctions and hall points; corridor stops if there are none) where
    # walkers press a "fix" button.
    n_landmarks: int = 8
    # m; a walker passing within this distance of a landmark records a fix.
    landmark_radius_m: float = 1.5
    # probability that a walker who passes a landmark actually records the fix.
    landmark_press_prob: float = 0.9

    def validate(self) -> None:
        _pos("venue.width_m", self.width_m)
        _pos("venue.height_m", self.height_m)
        if self.n_x_corridors < 1:
            raise ValueError("venue.n_x_corridors must be >= 1")
        if self.n_y_corridors < 0:
            raise ValueError("venue.n_y_corridors must be >= 0")
        if not 1.0 <= self.corridor_width_m <= 10.0:
            raise ValueError("venue.corridor_width_m must be in [1, 10]")
        if not 2.0 <= self.room_width_m <= 50.0:
            raise ValueError("venue.room_width_m must be in [2, 50]")
        if not 2.0 <= self.min_room_depth_m <= 50.0:
            raise ValueError("venue.min_room_depth_m must be in [2, 50]")
        if not 0.6 <= self.door_width_m <= min(self.room_width_m, self.corridor_width_m * 2):
            raise ValueError("venue.door_width_m must be in [0.6, room_width_m]")
        if not 0.0 <= self.hall_width_m <= 0.8 * self.width_m:
            raise ValueError("venue.hall_width_m must be in [0, 0.8 width_m]")
        if 0.0 < self.hall_width_m < 10.0:
            raise ValueError("venue.hall_width_m must be 0 (no hall) or >= 10 m")
        office_w = self.width_m - self.hall_width_m
        band = self.height_m / self.n_x_corridors
        if band < self.corridor_width_m + self.min_room_depth_m:
            raise ValueError("venue: too many x corridors for height_m (no room depth left)")
        if self.n_y_corridors > 0 and office_w / (self.n_y_corridors + 1) < self.corridor_width_m + 2.0:
            raise ValueError("venue: too many y corridors for the office width")
        if self.n_hall_kiosks < 0:
            raise ValueError("venue.n_hall_kiosks must be >= 0")
        if not 2.0 <= self.hall_grid_m <= 20.0:
            raise ValueError("venue.hall_grid_m must be in [2, 20]")
        for name in ("corridor_wall_atten_db", "partition_atten_db", "kiosk_atten_db", "outer_wall_atten_db"):
            v = getattr(self, name)
            if not 0.0 <= v <= 40.0:
                raise ValueError(f"venue.{name} must be in [0, 40] dB")
        if self.n_landmarks < 0:
            raise ValueError("venue.n_landmarks must be >= 0")
        _pos("venue.landmark_radius_m", self.landmark_radius_m)
        _prob("venue.landmark_press_prob", self.landmark_press_prob)


@dataclass(frozen=True)
class RadioConfig:
    # count; physical access points. Each has a 2.4 GHz radio and maybe a 5 GHz one; each radio 1-2 BSSIDs.
    n_aps: int = 60
    # probability that an AP also has a 5 GHz radio.
    dual_band_fraction: float = 0.6
    # probability that a radio broadcasts a second SSID (a second BSSID with the same signal field).
    multi_ssid_fraction: float = 0.3
    # m; minimum distance between two APs (placement by rejection sampling).
    min_ap_spacing_m: float = 6.0
    # dBm; range of the mean RSSI at 1 m of a 2.4 GHz radio (the "tx power" of the log-distance model).
    tx_power_24_dbm: tuple[float, float] = (-42.0, -34.0)
    # dBm; same for 5 GHz radios (weaker at 1 m).
    tx_power_5_dbm: tuple[float, float] = (-48.0, -40.0)
    # 1; range of the per-radio path-loss exponent n in RSS = P0 - 10 n log10(d / 1 m).
    path_loss_exp: tuple[float, float] = (2.2, 3.3)
    # 1; wall attenuation multiplier of 5 GHz radios relative to 2.4 GHz.
    wall_factor_5ghz: float = 1.5
    # dB; sigma of the spatially correlated shadowing of each radio (static: part of the true field).
    shadow_sigma_db: float = 5.0
    # m; correlation length of the shadowing (Gaussian-kernel random Fourier features).
    shadow_corr_m: float = 5.0
    # count; random Fourier features per radio for the shadowing field.
    n_shadow_features: int = 48
    # dB; sigma of the independent per-reading noise.
    noise_sigma_db: float = 4.0
    # dB; sigma of a per-(walk, radio) offset constant during a walk: the field changes between
    # recordings (people, doors, furniture, AP power control).
    walk_offset_sigma_db: float = 3.0
    # dB; extra loss when the walker's body is between phone and AP (scaled by (1 - cos angle) / 2).
    body_loss_db: float = 3.0
    # dBm; hard detection floor: readings below it are never reported.
    detect_floor_dbm: float = -100.0
    # dBm; RSSI at which a reading is detected with probability 1/2 (logistic soft floor).
    detect_mid_dbm: float = -95.0
    # dB; width (logistic scale) of the soft detection floor.
    detect_soft_db: float = 3.0
    # probability that a reading of a strong AP is nevertheless missing from a scan (missed beacons,
    # incomplete channel sweeps); with the soft floor, the main source of false RSS vicinity pairs.
    miss_prob: float = 0.15
    # s; range of a device's scan period (each scan = all detected BSSIDs at one time).
    scan_period_s: tuple[float, float] = (2.0, 4.0)
    # s; sigma of the jitter added to every scan interval.
    scan_jitter_s: float = 0.15
    # s; a scan sweeps the channels during this interval before its t_s: each reading is taken at a
    # random time in it (so at a position up to ~2 m behind the walker's position at t_s).
    scan_duration_s: float = 1.5
    # probability that a BSSID's entry of a scan is a stale copy of the previous scan's (phone scan cache).
    stale_prob: float = 0.15

    def validate(self) -> None:
        if self.n_aps < 1:
            raise ValueError("radio.n_aps must be >= 1")
        _prob("radio.dual_band_fraction", self.dual_band_fraction)
        _prob("radio.multi_ssid_fraction", self.multi_ssid_fraction)
        _pos("radio.min_ap_spacing_m", self.min_ap_spacing_m, strict=False)
        _range("radio.tx_power_24_dbm", self.tx_power_24_dbm, -80.0, 0.0)
        _range("radio.tx_power_5_dbm", self.tx_power_5_dbm, -80.0, 0.0)
        _range("radio.path_loss_exp", self.path_loss_exp, 1.5, 6.0)
        if not 0.5 <= self.wall_factor_5ghz <= 4.0:
            raise ValueError("radio.wall_factor_5ghz must be in [0.5, 4]")
        if not 0.0 <= self.shadow_sigma_db <= 20.0:
            raise ValueError("radio.shadow_sigma_db must be in [0, 20]")
        _pos("radio.shadow_corr_m", self.shadow_corr_m)
        if not 1 <= self.n_shadow_features <= 1024:
            raise ValueError("radio.n_shadow_features must be in [1, 1024]")
        if not 0.0 <= self.noise_sigma_db <= 20.0:
            raise ValueError("radio.noise_sigma_db must be in [0, 20]")
        if not 0.0 <= self.walk_offset_sigma_db <= 20.0:
            raise ValueError("radio.walk_offset_sigma_db must be in [0, 20]")
        if not 0.0 <= self.body_loss_db <= 20.0:
            raise ValueError("radio.body_loss_db must be in [0, 20]")
        if not -130.0 <= self.detect_floor_dbm <= -50.0:
            raise ValueError("radio.detect_floor_dbm must be in [-130, -50]")
        if self.detect_mid_dbm < self.detect_floor_dbm:
            raise ValueError("radio.detect_mid_dbm must be >= detect_floor_dbm")
        _pos("radio.detect_soft_db", self.detect_soft_db)
        if not 0.0 <= self.miss_prob < 1.0:
            raise ValueError("radio.miss_prob must be in [0, 1)")
        _range("radio.scan_period_s", self.scan_period_s, 0.2, 60.0)
        _pos("radio.scan_jitter_s", self.scan_jitter_s, strict=False)
        if self.scan_jitter_s > 0.25 * self.scan_period_s[0]:
            raise ValueError("radio.scan_jitter_s must be <= a quarter of the shortest scan period")
        if not 0.0 <= self.scan_duration_s <= self.scan_period_s[0]:
            raise ValueError("radio.scan_duration_s must be in [0, shortest scan period]")
        if not 0.0 <= self.stale_prob < 1.0:
            raise ValueError("radio.stale_prob must be in [0, 1)")


@dataclass(frozen=True)
class WalkersConfig:
    # count; users (people); each has its own step model S = alpha f + beta.
    n_users: int = 6
    # count; long patrol walks (visit rooms, hall, corridors; revisit places).
    n_long_walks: int = 6
    # steps; range of the length of a long walk.
    long_walk_steps: tuple[float, float] = (650.0, 900.0)
    # count; short walks that mostly cross the venue along corridors / through the hall.
    n_short_walks: int = 4
    # steps; range of the length of a short walk.
    short_walk_steps: tuple[float, float] = (50.0, 150.0)
    # "random": short walks head for random corridor/hall places; "end_to_end": along the longest
    # x corridor from one end to the other (Gu et al. 2017's straight-walk experiment).
    short_walk_route: Literal["random", "end_to_end"] = "random"
    # count; walks (the last ones) with role "test", held out for evaluation.
    n_test_walks: int = 2
    # Hz; range of a user's mean step frequency.
    step_freq_hz: tuple[float, float] = (1.5, 2.1)
    # Hz; sigma of a walk's step frequency around its user's mean.
    step_freq_walk_sd_hz: float = 0.06
    # Hz; sigma of the slow (AR(1), 0.95 per step) step-to-step variation of the step frequency.
    step_freq_step_sd_hz: float = 0.05
    # m/Hz; range of a user's alpha in the step model S = alpha f + beta.
    step_alpha: tuple[float, float] = (0.3, 0.5)
    # m; range of a user's step length at 1.8 Hz (sets beta = S(1.8) - 1.8 alpha).
    step_len_at_1p8hz_m: tuple[float, float] = (0.62, 0.78)
    # m; max |lateral offset| of a walk from the path centre line (kept per walk).
    lateral_offset_m: float = 0.4
    # m; sigma of the small smooth (AR(1)) lateral wiggle around that offset.
    wiggle_sd_m: float = 0.1
    # m; waypoints are jittered by up to this in corridors (more in the hall), so routes differ.
    waypoint_jitter_m: float = 0.4
    # probability that a long walk's next destination is a room (else a corridor/hall place).
    room_visit_prob: float = 0.35
    # probability of a pause (standing; scans go on, no steps) at a destination.
    pause_prob: float = 0.3
    # s; range of a pause's duration.
    pause_s: tuple[float, float] = (3.0, 20.0)
    # "route": the first pose faces along the first step; "random": the walker starts facing a random
    # direction and turns onto the route on the first step (Gu et al. 2017's random initial headings).
    start_facing: Literal["route", "random"] = "route"

    def validate(self) -> None:
        if self.n_users < 1:
            raise ValueError("walkers.n_users must be >= 1")
        if self.n_long_walks < 0 or self.n_short_walks < 0:
            raise ValueError("walkers.n_long_walks / n_short_walks must be >= 0")
        if self.n_long_walks + self.n_short_walks < 1:
            raise ValueError("walkers: need at least one walk")
        _range("walkers.long_walk_steps", self.long_walk_steps, 2.0, 1e6)
        _range("walkers.short_walk_steps", self.short_walk_steps, 2.0, 1e6)
        if not 0 <= self.n_test_walks <= self.n_long_walks + self.n_short_walks:
            raise ValueError("walkers.n_test_walks must be in [0, number of walks]")
        _range("walkers.step_freq_hz", self.step_freq_hz, 0.5, 4.0)
        _pos("walkers.step_freq_walk_sd_hz", self.step_freq_walk_sd_hz, strict=False)
        _pos("walkers.step_freq_step_sd_hz", self.step_freq_step_sd_hz, strict=False)
        if self.step_freq_walk_sd_hz > 0.5 or self.step_freq_step_sd_hz > 0.5:
            raise ValueError("walkers: step frequency sigmas must be <= 0.5 Hz")
        _range("walkers.step_alpha", self.step_alpha, 0.0, 2.0)
        _range("walkers.step_len_at_1p8hz_m", self.step_len_at_1p8hz_m, 0.2, 1.5)
        if not 0.0 <= self.lateral_offset_m <= 0.45 * 1.2:
            raise ValueError("walkers.lateral_offset_m must be in [0, 0.54] (doors are ~1.2 m wide)")
        if not 0.0 <= self.wiggle_sd_m <= 0.5:
            raise ValueError("walkers.wiggle_sd_m must be in [0, 0.5]")
        if not 0.0 <= self.waypoint_jitter_m <= 1.0:
            raise ValueError("walkers.waypoint_jitter_m must be in [0, 1]")
        _prob("walkers.room_visit_prob", self.room_visit_prob)
        _prob("walkers.pause_prob", self.pause_prob)
        _range("walkers.pause_s", self.pause_s, 0.0, 3600.0)


@dataclass(frozen=True)
class ImuConfig:
    # 1; sigma of a walk's step-length scale error (0.03 = 3 %).
    step_scale_sd: float = 0.03
    # m; sigma of the independent per-step step-length noise.
    step_noise_m: float = 0.02
    # deg/s; sigma of a walk's initial gyro (heading) bias.
    heading_bias_sd_dps: float = 0.02
    # deg/s/sqrt(s); random-walk intensity of the heading bias.
    heading_bias_rw_dps: float = 0.002
    # deg; sigma of the per-step heading increment noise (accumulates as a random walk).
    heading_step_noise_deg: float = 0.3

    def validate(self) -> None:
        if not 0.0 <= self.step_scale_sd <= 0.3:
            raise ValueError("imu.step_scale_sd must be in [0, 0.3]")
        if not 0.0 <= self.step_noise_m <= 0.3:
            raise ValueError("imu.step_noise_m must be in [0, 0.3]")
        if not 0.0 <= self.heading_bias_sd_dps <= 5.0:
            raise ValueError("imu.heading_bias_sd_dps must be in [0, 5]")
        if not 0.0 <= self.heading_bias_rw_dps <= 1.0:
            raise ValueError("imu.heading_bias_rw_dps must be in [0, 1]")
        if not 0.0 <= self.heading_step_noise_deg <= 20.0:
            raise ValueError("imu.heading_step_noise_deg must be in [0, 20]")


@dataclass(frozen=True)
class MagnetometerConfig:
    # probability that a device has no magnetometer (its walks get NaN yaw_abs_rad).
    missing_fraction: float = 0.0
    # deg; sigma of a walk's constant heading offset (device calibration / mounting).
    walk_offset_sd_deg: float = 4.0
    # deg; sigma of the spatially smooth indoor disturbance of the measured heading.
    disturbance_sd_deg: float = 10.0
    # m; correlation length of the disturbance field.
    disturbance_corr_m: float = 4.0
    # count; hot spots (steel, escalators) where the disturbance is amplified.
    n_hotspots: int = 6
    # 1; extra disturbance gain at a hot spot's centre (1 = doubled).
    hotspot_gain: float = 2.0
    # m; radius (Gaussian sigma) of a hot spot.
    hotspot_radius_m: float = 5.0
    # deg; sigma of the independent per-step noise.
    noise_sd_deg: float = 3.0
    # rad; the constant 1-sigma a device reports with its heading (yaw_abs_sigma_rad).
    reported_sigma_rad: float = 0.25
    # deg; rotation of the magnetometer's world frame relative to the building frame (0 = aligned).
    north_offset_deg: float = 0.0

    def validate(self) -> None:
        _prob("magnetometer.missing_fraction", self.missing_fraction)
        for name in ("walk_offset_sd_deg", "disturbance_sd_deg", "noise_sd_deg"):
            v = getattr(self, name)
            if not 0.0 <= v <= 90.0:
                raise ValueError(f"magnetometer.{name} must be in [0, 90] deg")
        _pos("magnetometer.disturbance_corr_m", self.disturbance_corr_m)
        if self.n_hotspots < 0:
            raise ValueError("magnetometer.n_hotspots must be >= 0")
        if not 0.0 <= self.hotspot_gain <= 10.0:
            raise ValueError("magnetometer.hotspot_gain must be in [0, 10]")
        _pos("magnetometer.hotspot_radius_m", self.hotspot_radius_m)
        if not 0.0 < self.reported_sigma_rad <= 3.2:
            raise ValueError("magnetometer.reported_sigma_rad must be in (0, 3.2]")
        if not -360.0 <= self.north_offset_deg <= 360.0:
            raise ValueError("magnetometer.north_offset_deg must be in [-360, 360]")


@dataclass(frozen=True)
class DevicesConfig:
    # count; phones used for the map walks.
    n_devices: int = 4
    # 1; sigma of a map device's RSS gain k around 1 (device model phi~ = k phi + b, He et al. 2015).
    k_sd: float = 0.05
    # dB; sigma of a map device's RSS offset b around 0.
    b_sd_db: float = 2.0
    # (k, b); when set, the test walks use an extra device "dtest" with this RSS model.
    test_device: tuple[float, float] | None = None

    def validate(self) -> None:
        if self.n_devices < 1:
            raise ValueError("devices.n_devices must be >= 1")
        if not 0.0 <= self.k_sd <= 0.5:
            raise ValueError("devices.k_sd must be in [0, 0.5]")
        if not 0.0 <= self.b_sd_db <= 20.0:
            raise ValueError("devices.b_sd_db must be in [0, 20]")
        if self.test_device is not None:
            k, b = self.test_device
            if not 0.1 <= k <= 6.0:
                raise ValueError("devices.test_device k must be in [0.1, 6]")
            if not -30.0 <= b <= 30.0:
                raise ValueError("devices.test_device b must be in [-30, 30] dB")


CARRY_MODES = ("texting", "calling", "swinging", "pocket")


@dataclass(frozen=True)
class PhoneImuConfig:
    """Raw phone IMU of ``simulate --raw-imu`` (rmbuild.pdr.synth): how each walk's phone is carried and
    sampled. The rotation vector's yaw error is the magnetometer's (``[magnetometer]``)."""

    # ways of carrying the phone a walk draws from (uniformly): "texting" (in front, read, pitched up),
    # "calling" (at the ear), "swinging" (in the hand, arm swinging), "pocket" (front trouser pocket).
    carry_modes: tuple[str, ...] = CARRY_MODES
    # Hz; range of a walk's IMU sampling rate (phones: 50-200 Hz).
    sample_hz: tuple[float, float] = (50.0, 200.0)
    # ms; 1-sigma jitter of the reported sample timestamps.
    jitter_ms: float = 2.0
    # 1; range of a walk's gait intensity: the vertical bounce relative to an inverted pendulum with the
    # walk's step lengths (below 1 gentle, above 1 brisk).
    bounce_scale: tuple[float, float] = (0.6, 1.4)
    # deg/s; 1-sigma of a walk's constant gyroscope bias on each axis.
    gyro_bias_sd_dps: float = 0.3
    # m/s²; 1-sigma of the accelerometer's white noise.
    acc_noise_mps2: float = 0.05
    # rad/s; 1-sigma of the gyroscope's white noise.
    gyro_noise_radps: float = 0.01

    def validate(self) -> None:
        if not self.carry_modes or any(m not in CARRY_MODES for m in self.carry_modes):
            raise ValueError(f"phone.carry_modes must be a non-empty list of {list(CARRY_MODES)}")
        _range("phone.sample_hz", self.sample_hz, 20.0, 500.0)
        if not 0.0 <= self.jitter_ms <= 20.0:
            raise ValueError("phone.jitter_ms must be in [0, 20]")
        _range("phone.bounce_scale", self.bounce_scale, 0.2, 3.0)
        if not 0.0 <= self.gyro_bias_sd_dps <= 10.0:
            raise ValueError("phone.gyro_bias_sd_dps must be in [0, 10]")
        if not 0.0 <= self.acc_noise_mps2 <= 2.0 or not 0.0 <= self.gyro_noise_radps <= 0.5:
            raise ValueError("phone.acc_noise_mps2 must be in [0, 2] and phone.gyro_noise_radps in [0, 0.5]")


@dataclass(frozen=True)
class SimulateConfig:
    # seed of the numpy Generator behind every random draw (same config + seed -> identical tables).
    seed: int = 7
    # floor plan
    venue: VenueConfig = field(default_factory=VenueConfig)
    # access points and radio propagation
    radio: RadioConfig = field(default_factory=RadioConfig)
    # people, walks and routes
    walkers: WalkersConfig = field(default_factory=WalkersConfig)
    # dead-reckoning (foot IMU) errors of the own-frame poses
    imu: ImuConfig = field(default_factory=ImuConfig)
    # absolute heading observations
    magnetometer: MagnetometerConfig = field(default_factory=MagnetometerConfig)
    # phones and their RSS models
    devices: DevicesConfig = field(default_factory=DevicesConfig)
    # raw phone IMU (only with `simulate --raw-imu`)
    phone: PhoneImuConfig = field(default_factory=PhoneImuConfig)

    def validate(self) -> None:
        if not 0 <= self.seed < 2**63:
            raise ValueError("seed must be in [0, 2**63)")
        for sub in (self.venue, self.radio, self.walkers, self.imu, self.magnetometer, self.devices, self.phone):
            sub.validate()


PRESETS = ("tiny", "default", "large", "corridor12")


def preset_config(name: str, seed: int) -> SimulateConfig:
    """The named preset with ``seed``: "tiny" (tests, ~600 steps), "default" (~10 walks, ~5,000 steps),
    "large" (~50,000 steps, benchmarks), "corridor12" (12 straight-ish walks along one long corridor,
    random initial headings: Gu et al. 2017's heading-alignment experiment). Raises ValueError for other names."""
    base = SimulateConfig(seed=seed)
    r = dataclasses.replace
    if name == "default":
        cfg = base
    elif name == "tiny":
        cfg = r(
            base,
            venue=r(base.venue, width_m=50.0, height_m=30.0, n_x_corridors=1, n_y_corridors=1,
                    hall_width_m=16.0, n_hall_kiosks=1, n_landmarks=4),
            radio=r(base.radio, n_aps=16),
            walkers=r(base.walkers, n_users=3, n_long_walks=3, long_walk_steps=(140.0, 180.0),
                      n_short_walks=2, short_walk_steps=(40.0, 70.0), n_test_walks=1),
            devices=r(base.devices, n_devices=2),
            magnetometer=r(base.magnetometer, n_hotspots=2),
        )
    elif name == "large":
        cfg = r(
            base,
            venue=r(base.venue, width_m=150.0, height_m=100.0, n_x_corridors=4, n_y_corridors=4,
                    hall_width_m=45.0, n_hall_kiosks=10, n_landmarks=14),
            radio=r(base.radio, n_aps=90),
            walkers=r(base.walkers, n_users=20, n_long_walks=40, long_walk_steps=(900.0, 1300.0),
                      n_short_walks=60, short_walk_steps=(50.0, 150.0), n_test_walks=10),
            devices=r(base.devices, n_devices=8, test_device=(0.9, -5.0)),
            magnetometer=r(base.magnetometer, missing_fraction=0.15, n_hotspots=10),
        )
    elif name == "corridor12":
        cfg = r(
            base,
            venue=r(base.venue, width_m=120.0, height_m=24.0, n_x_corridors=1, n_y_corridors=0,
                    hall_width_m=0.0, n_hall_kiosks=0, n_landmarks=4),
            radio=r(base.radio, n_aps=30),
            walkers=r(base.walkers, n_users=4, n_long_walks=0, n_short_walks=12,
                      short_walk_steps=(140.0, 160.0), short_walk_route="end_to_end", n_test_walks=0,
                      start_facing="random", pause_prob=0.0),
            devices=r(base.devices, n_devices=3),
            magnetometer=r(base.magnetometer, n_hotspots=2),
        )
    else:
        raise ValueError(f"unknown simulate preset {name!r} (known: {', '.join(PRESETS)})")
    cfg.validate()
    return cfg
