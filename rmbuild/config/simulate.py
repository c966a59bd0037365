"""Config of `rmbuild simulate`: the seeded synthetic venue (floor plan, radio, walkers, sensors).

Every field carries its unit and meaning in a comment. ``(lo, hi)`` tuples are uniform ranges a value is
drawn from per AP / user / walk / device. :func:`preset_config` returns the named presets (``tiny``,
``default``, ``large``, ``corridor12``); the dataclass defaults are the ``default`` preset with seed 7.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

from rmbuild.config.base import bounded, check_ranges

#: steps; the most a simulation may draw (n_long_walks x long max + n_short_walks x short max): "large" has
#: ~61,000, "year" ~2,440,000 (its ~2,000,000 steps simulate and ingest within ~6 GB)
MAX_SIMULATED_STEPS = 2_500_000


def _ordered(name: str, r: tuple[float, float]) -> None:
    if not r[0] <= r[1]:
        raise ValueError(f"{name}: lower bound {r[0]} > upper bound {r[1]}")


@dataclass(frozen=True)
class VenueConfig:
    # m; building extent along x (east). The hall takes the east end, offices + corridors the rest.
    width_m: float = bounded(130.0, 10.0, 1000.0)
    # m; building extent along y (north).
    height_m: float = bounded(80.0, 10.0, 1000.0)
    # count; corridors running along x through the office part (>= 1).
    n_x_corridors: int = bounded(3, 1, 50)
    # count; corridors running along y through the office part (0 = none).
    n_y_corridors: int = bounded(3, 0, 50)
    # m; clear width of every corridor.
    corridor_width_m: float = bounded(3.0, 1.0, 10.0)
    # m; nominal room width along its corridor (rooms are split evenly, so actual widths vary a little).
    room_width_m: float = bounded(7.0, 2.0, 50.0)
    # m; a block deeper than twice this holds two rows of rooms (one per corridor), else one row.
    min_room_depth_m: float = bounded(5.0, 2.0, 50.0)
    # m; door opening width (a gap in the room's corridor wall).
    door_width_m: float = bounded(1.2, 0.6, 20.0)
    # m; width (along x) of the open hall at the east end spanning the full height; 0 = no hall.
    hall_width_m: float = bounded(38.0, 0.0, 800.0)
    # count; small closed boxes (shops, kiosks, 3-5 m wide) standing in the hall.
    n_hall_kiosks: int = bounded(6, 0, 100)
    # m; spacing of the walkable grid laid over the hall (navigation graph).
    hall_grid_m: float = bounded(5.0, 2.0, 20.0)
    # dB; attenuation of one corridor / hall-facing wall (signal crossing it once).
    corridor_wall_atten_db: float = bounded(5.0, 0.0, 40.0)
    # dB; attenuation of one partition wall between rooms.
    partition_atten_db: float = bounded(3.5, 0.0, 40.0)
    # dB; attenuation of one kiosk wall in the hall.
    kiosk_atten_db: float = bounded(2.5, 0.0, 40.0)
    # dB; attenuation of the building's outer wall (only for plots: everything is inside).
    outer_wall_atten_db: float = bounded(12.0, 0.0, 40.0)
    # count; landmarks (corridor junctions and hall points; corridor stops if there are none) where
    # walkers press a "fix" button.
    n_landmarks: int = bounded(8, 0, 1000)
    # m; a walker passing within this distance of a landmark records a fix.
    landmark_radius_m: float = bounded(1.5, 0.1, 20.0)
    # probability that a walker who passes a landmark actually records the fix.
    landmark_press_prob: float = bounded(0.9, 0.0, 1.0)

    def validate(self) -> None:
        check_ranges(self, "venue.")
        if self.door_width_m > min(self.room_width_m, self.corridor_width_m * 2):
            raise ValueError("venue.door_width_m must be <= room_width_m and <= 2 corridor_width_m")
        if self.hall_width_m > 0.8 * self.width_m:
            raise ValueError("venue.hall_width_m must be in [0, 0.8 width_m]")
        if 0.0 < self.hall_width_m < 10.0:
            raise ValueError("venue.hall_width_m must be 0 (no hall) or >= 10 m")
        office_w = self.width_m - self.hall_width_m
        band = self.height_m / self.n_x_corridors
        if band < self.corridor_width_m + self.min_room_depth_m:
            raise ValueError("venue: too many x corridors for height_m (no room depth left)")
        if self.n_y_corridors > 0 and office_w / (self.n_y_corridors + 1) < self.corridor_width_m + 2.0:
            raise ValueError("venue: too many y corridors for the office width")



@dataclass(frozen=True)
class RadioConfig:
    # count; physical access points. Each has a 2.4 GHz radio and maybe a 5 GHz one; each radio 1-2 BSSIDs.
    n_aps: int = bounded(60, 1, 5000)
    # probability that an AP also has a 5 GHz radio.
    dual_band_fraction: float = bounded(0.6, 0.0, 1.0)
    # probability that a radio broadcasts a second SSID (a second BSSID with the same signal field).
    multi_ssid_fraction: float = bounded(0.3, 0.0, 1.0)
    # m; minimum distance between two APs (placement by rejection sampling).
    min_ap_spacing_m: float = bounded(6.0, 0.0, 100.0)
    # dBm; range of the mean RSSI at 1 m of a 2.4 GHz radio (the "tx power" of the log-distance model).
    tx_power_24_dbm: tuple[float, float] = bounded((-42.0, -34.0), -80.0, 0.0)
    # dBm; same for 5 GHz radios (weaker at 1 m).
    tx_power_5_dbm: tuple[float, float] = bounded((-48.0, -40.0), -80.0, 0.0)
    # 1; range of the per-radio path-loss exponent n in RSS = P0 - 10 n log10(d / 1 m).
    path_loss_exp: tuple[float, float] = bounded((2.2, 3.3), 1.5, 6.0)
    # 1; wall attenuation multiplier of 5 GHz radios relative to 2.4 GHz.
    wall_factor_5ghz: float = bounded(1.5, 0.5, 4.0)
    # dB; sigma of the spatially correlated shadowing of each radio (static: part of the true field).
    shadow_sigma_db: float = bounded(5.0, 0.0, 20.0)
    # m; correlation length of the shadowing (Gaussian-kernel random Fourier features).
    shadow_corr_m: float = bounded(5.0, 0.5, 100.0)
    # count; random Fourier features per radio for the shadowing field.
    n_shadow_features: int = bounded(48, 1, 1024)
    # dB; sigma of the independent per-reading noise.
    noise_sigma_db: float = bounded(4.0, 0.0, 20.0)
    # dB; sigma of a per-(walk, radio) offset constant during a walk: the field changes between
    # recordings (people, doors, furniture, AP power control).
    walk_offset_sigma_db: float = bounded(3.0, 0.0, 20.0)
    # dB; extra loss when the walker's body is between phone and AP (scaled by (1 - cos angle) / 2).
    body_loss_db: float = bounded(3.0, 0.0, 20.0)
    # dBm; hard detection floor: readings below it are never reported.
    detect_floor_dbm: float = bounded(-100.0, -130.0, -50.0)
    # dBm; RSSI at which a reading is detected with probability 1/2 (logistic soft floor).
    detect_mid_dbm: float = bounded(-95.0, -130.0, -30.0)
    # dB; width (logistic scale) of the soft detection floor.
    detect_soft_db: float = bounded(3.0, 0.1, 20.0)
    # probability that a reading of a strong AP is nevertheless missing from a scan (missed beacons,
    # incomplete channel sweeps); with the soft floor, the main source of false RSS vicinity pairs.
    miss_prob: float = bounded(0.15, 0.0, 0.99)
    # s; range of a device's scan period (each scan = all detected BSSIDs at one time).
    scan_period_s: tuple[float, float] = bounded((2.0, 4.0), 0.2, 60.0)
    # s; sigma of the jitter added to every scan interval.
    scan_jitter_s: float = bounded(0.15, 0.0, 15.0)
    # s; a scan sweeps the channels during this interval before its t_s: each reading is taken at a
    # random time in it (so at a position up to ~2 m behind the walker's position at t_s).
    scan_duration_s: float = bounded(1.5, 0.0, 60.0)
    # probability that a BSSID's entry of a scan is a stale copy of the previous scan's (phone scan cache).
    stale_prob: float = bounded(0.15, 0.0, 0.99)

    def validate(self) -> None:
        check_ranges(self, "radio.")
        for name in ("tx_power_24_dbm", "tx_power_5_dbm", "path_loss_exp", "scan_period_s"):
            _ordered(f"radio.{name}", getattr(self, name))
        if self.detect_mid_dbm < self.detect_floor_dbm:
            raise ValueError("radio.detect_mid_dbm must be >= detect_floor_dbm")
        if self.scan_jitter_s > 0.25 * self.scan_period_s[0]:
            raise ValueError("radio.scan_jitter_s must be <= a quarter of the shortest scan period")
        if self.scan_duration_s > self.scan_period_s[0]:
            raise ValueError("radio.scan_duration_s must be in [0, shortest scan period]")



@dataclass(frozen=True)
class WalkersConfig:
    # count; users (people); each has its own step model S = alpha f + beta.
    n_users: int = bounded(6, 1, 1000)
    # count; long patrol walks (visit rooms, hall, corridors; revisit places).
    n_long_walks: int = bounded(6, 0, 5000)
    # steps; range of the length of a long walk.
    long_walk_steps: tuple[float, float] = bounded((650.0, 900.0), 2.0, 100000.0)
    # count; short walks that mostly cross the venue along corridors / through the hall.
    n_short_walks: int = bounded(4, 0, 5000)
    # steps; range of the length of a short walk.
    short_walk_steps: tuple[float, float] = bounded((50.0, 150.0), 2.0, 100000.0)
    # "random": short walks head for random corridor/hall places; "end_to_end": along the longest
    # x corridor from one end to the other (Gu et al. 2017's straight-walk experiment).
    short_walk_route: Literal["random", "end_to_end"] = "random"
    # count; walks (the last ones) with role "test", held out for evaluation.
    n_test_walks: int = bounded(2, 0, 10000)
    # Hz; range of a user's mean step frequency.
    step_freq_hz: tuple[float, float] = bounded((1.5, 2.1), 0.5, 4.0)
    # Hz; sigma of a walk's step frequency around its user's mean.
    step_freq_walk_sd_hz: float = bounded(0.06, 0.0, 0.5)
    # Hz; sigma of the slow (AR(1), 0.95 per step) step-to-step variation of the step frequency.
    step_freq_step_sd_hz: float = bounded(0.05, 0.0, 0.5)
    # m/Hz; range of a user's alpha in the step model S = alpha f + beta.
    step_alpha: tuple[float, float] = bounded((0.3, 0.5), 0.0, 2.0)
    # m; range of a user's step length at 1.8 Hz (sets beta = S(1.8) - 1.8 alpha).
    step_len_at_1p8hz_m: tuple[float, float] = bounded((0.62, 0.78), 0.2, 1.5)
    # m; max |lateral offset| of a walk from the path centre line (kept per walk).
    lateral_offset_m: float = bounded(0.4, 0.0, 0.54)
    # m; sigma of the small smooth (AR(1)) lateral wiggle around that offset.
    wiggle_sd_m: float = bounded(0.1, 0.0, 0.5)
    # m; waypoints are jittered by up to this in corridors (more in the hall), so routes differ.
    waypoint_jitter_m: float = bounded(0.4, 0.0, 1.0)
    # probability that a long walk's next destination is a room (else a corridor/hall place).
    room_visit_prob: float = bounded(0.35, 0.0, 1.0)
    # probability of a pause (standing; scans go on, no steps) at a destination.
    pause_prob: float = bounded(0.3, 0.0, 1.0)
    # s; range of a pause's duration.
    pause_s: tuple[float, float] = bounded((3.0, 20.0), 0.0, 3600.0)
    # "route": the first pose faces along the first step; "random": the walker starts facing a random
    # direction and turns onto the route on the first step (Gu et al. 2017's random initial headings).
    start_facing: Literal["route", "random"] = "route"

    def validate(self) -> None:
        check_ranges(self, "walkers.")
        for name in ("long_walk_steps", "short_walk_steps", "step_freq_hz", "step_alpha", "step_len_at_1p8hz_m",
                     "pause_s"):
            _ordered(f"walkers.{name}", getattr(self, name))
        n_walks = self.n_long_walks + self.n_short_walks
        if n_walks < 1:
            raise ValueError("walkers: need at least one walk")
        if self.n_test_walks > n_walks:
            raise ValueError("walkers.n_test_walks must be in [0, number of walks]")
        steps = self.n_long_walks * self.long_walk_steps[1] + self.n_short_walks * self.short_walk_steps[1]
        if steps > MAX_SIMULATED_STEPS:
            raise ValueError(f"walkers: up to {steps:,.0f} steps in all; at most {MAX_SIMULATED_STEPS:,}")



@dataclass(frozen=True)
class ImuConfig:
    # 1; sigma of a walk's step-length scale error (0.03 = 3 %).
    step_scale_sd: float = bounded(0.03, 0.0, 0.3)
    # m; sigma of the independent per-step step-length noise.
    step_noise_m: float = bounded(0.02, 0.0, 0.3)
    # deg/s; sigma of a walk's initial gyro (heading) bias.
    heading_bias_sd_dps: float = bounded(0.02, 0.0, 5.0)
    # deg/s/sqrt(s); random-walk intensity of the heading bias.
    heading_bias_rw_dps: float = bounded(0.002, 0.0, 1.0)
    # deg; sigma of the per-step heading increment noise (accumulates as a random walk).
    heading_step_noise_deg: float = bounded(0.3, 0.0, 20.0)

    def validate(self) -> None:
        check_ranges(self, "imu.")



@dataclass(frozen=True)
class MagnetometerConfig:
    # probability that a device has no magnetometer (its walks get NaN yaw_abs_rad).
    missing_fraction: float = bounded(0.0, 0.0, 1.0)
    # deg; sigma of a walk's constant heading offset (device calibration / mounting).
    walk_offset_sd_deg: float = bounded(4.0, 0.0, 90.0)
    # deg; sigma of the spatially smooth indoor disturbance of the measured heading.
    disturbance_sd_deg: float = bounded(10.0, 0.0, 90.0)
    # m; correlation length of the disturbance field.
    disturbance_corr_m: float = bounded(4.0, 0.5, 100.0)
    # count; hot spots (steel, escalators) where the disturbance is amplified.
    n_hotspots: int = bounded(6, 0, 1000)
    # 1; extra disturbance gain at a hot spot's centre (1 = doubled).
    hotspot_gain: float = bounded(2.0, 0.0, 10.0)
    # m; radius (Gaussian sigma) of a hot spot.
    hotspot_radius_m: float = bounded(5.0, 0.1, 100.0)
    # deg; sigma of the independent per-step noise.
    noise_sd_deg: float = bounded(3.0, 0.0, 90.0)
    # rad; the constant 1-sigma a device reports with its heading (yaw_abs_sigma_rad).
    reported_sigma_rad: float = bounded(0.25, 0.001, 3.2)
    # deg; rotation of the magnetometer's world frame relative to the building frame (0 = aligned).
    north_offset_deg: float = bounded(0.0, -360.0, 360.0)

    def validate(self) -> None:
        check_ranges(self, "magnetometer.")



@dataclass(frozen=True)
class DevicesConfig:
    # count; phones used for the map walks.
    n_devices: int = bounded(4, 1, 1000)
    # 1; sigma of a map device's RSS gain k around 1 (device model phi~ = k phi + b, He et al. 2015).
    k_sd: float = bounded(0.05, 0.0, 0.5)
    # dB; sigma of a map device's RSS offset b around 0.
    b_sd_db: float = bounded(2.0, 0.0, 20.0)
    # (k, b); when set, the test walks use an extra device "dtest" with this RSS model.
    test_device: tuple[float, float] | None = bounded(None, -30.0, 30.0)

    def validate(self) -> None:
        check_ranges(self, "devices.")
        if self.test_device is not None and not 0.1 <= self.test_device[0] <= 6.0:
            raise ValueError("devices.test_device k must be in [0.1, 6]")



CARRY_MODES = ("texting", "calling", "swinging", "pocket")


@dataclass(frozen=True)
class PhoneImuConfig:
    """Raw phone IMU of ``simulate --raw-imu`` (rmbuild.pdr.synth): how each walk's phone is carried and
    sampled. The rotation vector's yaw error is the magnetometer's (``[magnetometer]``)."""

    # ways of carrying the phone a walk draws from (uniformly): "texting" (in front, read, pitched up),
    # "calling" (at the ear), "swinging" (in the hand, arm swinging), "pocket" (front trouser pocket).
    carry_modes: tuple[str, ...] = CARRY_MODES
    # Hz; range of a walk's IMU sampling rate (phones: 50-200 Hz).
    sample_hz: tuple[float, float] = bounded((50.0, 200.0), 20.0, 500.0)
    # ms; 1-sigma jitter of the reported sample timestamps.
    jitter_ms: float = bounded(2.0, 0.0, 20.0)
    # 1; range of a walk's gait intensity: the vertical bounce relative to an inverted pendulum with the
    # walk's step lengths (below 1 gentle, above 1 brisk).
    bounce_scale: tuple[float, float] = bounded((0.6, 1.4), 0.2, 3.0)
    # deg/s; 1-sigma of a walk's constant gyroscope bias on each axis.
    gyro_bias_sd_dps: float = bounded(0.3, 0.0, 10.0)
    # m/s²; 1-sigma of the accelerometer's white noise.
    acc_noise_mps2: float = bounded(0.05, 0.0, 2.0)
    # rad/s; 1-sigma of the gyroscope's white noise.
    gyro_noise_radps: float = bounded(0.01, 0.0, 0.5)

    def validate(self) -> None:
        if not self.carry_modes or any(m not in CARRY_MODES for m in self.carry_modes):
            raise ValueError(f"phone.carry_modes must be a non-empty list of {list(CARRY_MODES)}")
        check_ranges(self)
        _ordered("phone.sample_hz", self.sample_hz)
        _ordered("phone.bounce_scale", self.bounce_scale)


@dataclass(frozen=True)
class BuildingConfig:
    # 1; floors stacked in the building, each a venue of its own (same outline; its own layout, APs and
    # walks); more than 1 writes a `floor` column, and `rmbuild ingest` makes a building workspace.
    floors: int = bounded(1, 1, 20)
    # dB; extra path loss per floor between an AP and a scan on another floor (the floor attenuation
    # factor: about 13-16 dB through one floor in Seidel & Rappaport 1992).
    floor_attenuation_db: float = bounded(15.0, 0.0, 60.0)
    # walks per pair of adjacent floors that change floor: map walks passing the stairs or the lift swap
    # their parts after it (one goes up, the other down), half of the pairs by the stairs, half by the lift.
    floor_change_walks: int = bounded(4, 0, 100)
    # m; height of a storey (~0.42 hPa of air pressure)
    storey_m: float = bounded(3.5, 2.5, 8.0)
    # hPa; 1-sigma white noise of a phone barometer's reading (0.01-0.06 hPa in phone datasheets)
    baro_noise_hpa: float = bounded(0.03, 0.0, 1.0)
    # hPa/h; 1-sigma of a walk's weather trend (a front moves pressure by 1-3 hPa in hours)
    baro_drift_hpa_per_h: float = bounded(1.0, 0.0, 20.0)

    def validate(self) -> None:
        check_ranges(self)


@dataclass(frozen=True)
class BleConfig:
    """BLE beacons, a second radio modality written as ``ble`` (rmbuild/synthetic/ble.py); none by default."""

    # count; beacons, each at a navigation node of the floor (0 = no BLE readings; one floor only).
    n_beacons: int = bounded(0, 0, 1000)
    # dBm; mean RSSI at 1 m (an iBeacon's "measured power").
    rssi_at_1m_dbm: float = bounded(-59.0, -100.0, 0.0)
    # 1; path-loss exponent n in RSS = P1 - 10 n log10(d / 1 m): beacons fade faster than Wi-Fi (2.2-3.3).
    path_loss_exp: float = bounded(3.0, 1.5, 6.0)
    # dB; sigma of the independent per-reading noise.
    noise_sigma_db: float = bounded(3.0, 0.0, 20.0)
    # s; a phone reports each beacon it hears once per period (its phase drawn per walk and beacon).
    period_s: float = bounded(1.0, 0.1, 60.0)
    # dBm; readings below it are never reported.
    detect_floor_dbm: float = bounded(-95.0, -130.0, -30.0)

    def validate(self) -> None:
        check_ranges(self, "ble.")


@dataclass(frozen=True)
class SimulateConfig:
    # seed of the numpy Generator behind every random draw (same config + seed -> identical tables).
    seed: int = bounded(7, 0, 2**63 - 1)
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
    # several floors, stairs, a lift and barometers (docs/floors.md)
    building: BuildingConfig = field(default_factory=BuildingConfig)
    # BLE beacons (none by default)
    ble: BleConfig = field(default_factory=BleConfig)

    def validate(self) -> None:
        check_ranges(self)
        for sub in (self.venue, self.radio, self.walkers, self.imu, self.magnetometer, self.devices, self.phone,
                    self.building, self.ble):
            sub.validate()
        if self.ble.n_beacons and self.building.floors > 1:
            raise ValueError("ble.n_beacons: BLE beacons are simulated on one floor only (building.floors = 1)")



PRESETS = ("tiny", "default", "large", "month", "year", "corridor12", "short")


def preset_config(name: str, seed: int) -> SimulateConfig:
    """The named preset with ``seed``: "tiny" (tests, ~600 steps), "default" (~10 walks, ~5,000 steps),
    "large" (~50,000 steps, benchmarks), "month" (large's venue walked ten times as much: ~500,000 steps,
    1,000 walks, a month of a venue's staff walks; the scaling benchmark), "year" (four months of it: ~2,000,000
    steps, 4,000 walks), "corridor12" (12 straight-ish
    walks along one long corridor, random initial headings: Gu et al. 2017's heading-alignment experiment),
    "short" (the default venue crossed by 160 short phone walks of ~15-20 m and ~10 scans each, two long
    walks among them: a mall's visitors). Raises ValueError for other names."""
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
    elif name == "month":
        lg = preset_config("large", seed)
        cfg = r(lg, walkers=r(lg.walkers, n_users=100, n_long_walks=400, n_short_walks=600, n_test_walks=100))
    elif name == "year":
        lg = preset_config("large", seed)
        cfg = r(lg, walkers=r(lg.walkers, n_users=400, n_long_walks=1600, n_short_walks=2400, n_test_walks=400))
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
    elif name == "short":
        cfg = r(
            base,
            radio=r(base.radio, scan_period_s=(1.5, 2.2)),
            walkers=r(base.walkers, n_users=24, n_long_walks=2, n_short_walks=160, short_walk_steps=(22.0, 30.0),
                      n_test_walks=10),
        )
    else:
        raise ValueError(f"unknown simulate preset {name!r} (known: {', '.join(PRESETS)})")
    cfg.validate()
    return cfg
