"""Seeded synthetic phone IMU for a walk with known steps, carried in one of several ways (tests, and the raw
signals of ``rmbuild simulate --raw-imu``).

A small physical model, built on a fine uniform grid (:data:`FINE_HZ`) and sampled at the phone's rate with
jittered timestamps:

- the **body** moves along the step positions (piecewise linear, smoothed), bounces vertically once per step
  as an inverted pendulum (Zijlstra & Hof, "Displacement of the pelvis during human walking", Gait & Posture
  1997: excursion ``l - sqrt(l² - (S/2)²)`` for leg length ``l`` and step length ``S``), sways its yaw once
  per stride and takes a heel-strike jolt at every step; it turns on the spot at the end of a pause;
- the **phone** hangs off the body by a carrying mode (:data:`CARRY_MODES`): held in front and read
  ("texting", pitched up and wobbling), at the ear ("calling"), in a swinging hand (a pendulum of the arm
  about the shoulder, once per stride) or in a trouser pocket (the thigh's swing about the hip, the pocket
  leg's heel strike much harder than the other's);
- the **sensors**: accelerometer (specific force) and gyroscope in the device frame with white noise and a
  constant gyro bias; a rotation vector (device -> ENU) whose yaw carries a slowly varying magnetic error.

The truth of a case is its step times and headings: the tests count steps and measure heading drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rmbuild.config.simulate import CARRY_MODES
from rmbuild.pdr.signals import ImuSignals

G_MPS2 = 9.80665
#: Hz; the grid the motion is built on before sampling at the phone's rate
FINE_HZ = 400.0
#: s; a gap between steps longer than this is a pause (standing, then turning on the spot)
PAUSE_GAP_S = 1.5
#: s; the turn at the end of a pause takes this long
TURN_S = 1.5
#: s; a walking stretch's bounce builds up over RAMP_IN_S from its first step and dies out over RAMP_OUT_S
RAMP_IN_S, RAMP_OUT_S = 1.0, 0.6
#: s; an arm's or a thigh's swing builds up over this
SWING_RAMP_IN_S = 1.2
#: s; the build-up starts this long before the first step (the push-off)
RAMP_LEAD_S = 0.3
#: s; reported timestamps are at least this far apart
MIN_REPORTED_DT_S = 5e-4
#: rad; 1-sigma of the slow tremor of the phone's attitude (rates of about 0.01 rad/s when standing)
TREMOR_RAD = np.deg2rad(0.3)


@dataclass(frozen=True)
class Carry:
    """How one walk carries its phone (drawn by :func:`draw_carry`): the ``mode``; ``mount`` (3, 3) device ->
    body rotation at rest (body: x forward, y left, z up); the pendulum amplitude ``swing_rad`` (arm or thigh,
    about the body's lateral axis, once per stride); ``lever_m`` (3,) the pivot and ``arm_m`` the length of
    the pendulum; ``damping`` of the body's vertical bounce at the phone (a hand absorbs part of it);
    ``jolt_mps2`` (2,) heel-strike peak on the near and the far leg's steps."""

    mode: str
    mount: np.ndarray
    swing_rad: float
    lever_m: np.ndarray
    arm_m: float
    damping: float
    jolt_mps2: tuple[float, float]


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    r = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def _axes(x: tuple, y: tuple, z: tuple) -> np.ndarray:
    """Device -> body rotation whose columns are the device's x, y, z axes in body coordinates."""
    return np.array([x, y, z], dtype=np.float64).T


def draw_carry(mode: str, rng: np.random.Generator) -> Carry:
    """A random instance of carrying ``mode`` (one of :data:`CARRY_MODES`)."""
    jitter = _rot(0, rng.normal(0, 0.1)) @ _rot(1, rng.normal(0, 0.1)) @ _rot(2, rng.normal(0, 0.1))
    if mode == "texting":   # screen up, top forward, pitched up by 20-60°
        m = _rot(1, -rng.uniform(0.35, 1.05)) @ _axes((0, -1, 0), (1, 0, 0), (0, 0, 1))
        return Carry(mode, m @ jitter, np.deg2rad(2.0), np.array([0.3, 0.0, 1.2]), 0.0,
                     rng.uniform(0.3, 0.7), (1.0, 1.0))
    if mode == "calling":   # upright at the right or left ear, screen toward the head, tilted forward
        side = rng.choice([-1.0, 1.0])
        m = _rot(1, rng.uniform(0.2, 0.5)) @ _axes((-side, 0, 0), (0, 0, 1), (0, side, 0))
        return Carry(mode, m @ jitter, np.deg2rad(2.0), np.array([0.05, -0.1 * side, 1.6]), 0.0,
                     rng.uniform(0.5, 0.9), (1.0, 1.0))
    if mode == "swinging":   # in the hand, arm hanging, top down, screen toward the thigh
        m = _axes((1, 0, 0), (0, 0, -1), (0, 1, 0))
        return Carry(mode, m @ jitter, np.deg2rad(rng.uniform(20, 40)), np.array([0.0, -0.2, 1.4]), 0.65,
                     1.0, (1.5, 1.5))
    if mode == "pocket":   # front trouser pocket, top up or down, screen forward or back
        up, fwd = rng.choice([-1.0, 1.0]), rng.choice([-1.0, 1.0])
        m = _axes(tuple(np.cross((0, 0, up), (fwd, 0, 0))), (0, 0, up), (fwd, 0, 0))
        return Carry(mode, m @ jitter, np.deg2rad(rng.uniform(20, 30)), np.array([0.0, -0.1, 0.9]), 0.25,
                     1.0, (4.0, 1.5))
    raise ValueError(f"unknown carrying mode {mode!r} (known: {', '.join(CARRY_MODES)})")


def _gait(t: np.ndarray, st: np.ndarray, ramp_in_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Gait phase (rad, +2 pi per step, 0 at each step) and walking amplitude in [0, 1] on the grid ``t``,
    reaching 1 ``ramp_in_s`` after the start of a walking stretch."""
    i = np.searchsorted(st, t, side="right")
    prev = st[np.maximum(i - 1, 0)]
    nxt = st[np.minimum(i, len(st) - 1)]
    gap = np.where((i > 0) & (i < len(st)), nxt - prev, np.inf)
    walking = gap <= PAUSE_GAP_S
    per = np.where(walking, gap, np.median(np.diff(st)) if len(st) > 1 else 0.55)
    # outside a walking stretch the phase stays at the nearest step's (the swing dies out, or starts, without
    # another cycle)
    frac = np.where(walking, (t - prev) / per, 0.0)
    phase = 2 * np.pi * (i + frac)
    # each walking stretch ramps in from its first step and out over RAMP_OUT_S after its last
    brk = np.flatnonzero(np.diff(st) > PAUSE_GAP_S)
    first, last = st[np.r_[0, brk + 1]], st[np.r_[brk, len(st) - 1]]
    k = np.clip(np.searchsorted(first, t, side="right") - 1, 0, len(first) - 1)
    rise = np.clip((t - first[k] + RAMP_LEAD_S) / ramp_in_s, 0.0, 1.0)
    fall = np.clip(1.0 - (t - last[k]) / RAMP_OUT_S, 0.0, 1.0)
    smooth = lambda x: x * x * (3 - 2 * x)  # noqa: E731  (smoothstep)
    return phase, smooth(rise) * smooth(fall)


def _body_yaw(t: np.ndarray, st: np.ndarray, hd: np.ndarray) -> np.ndarray:
    """Walking yaw on the grid: interpolated across each step, held in a pause until :data:`TURN_S` before
    the next step (a turn on the spot)."""
    knots_t, knots_h = [st[0]], [hd[0]]
    for k in range(1, len(st)):
        if st[k] - st[k - 1] > PAUSE_GAP_S:
            knots_t.append(max(st[k] - TURN_S, st[k - 1] + 1e-3))
            knots_h.append(hd[k - 1])
        knots_t.append(st[k])
        knots_h.append(hd[k])
    return np.interp(t, knots_t, knots_h)


def _smooth(x: np.ndarray, sigma_s: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(x, sigma_s * FINE_HZ, axis=0, mode="nearest")


def _motion(t: np.ndarray, st: np.ndarray, hd: np.ndarray, length: np.ndarray, carry: Carry,
            leg_m: float, bounce_scale: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 3) device -> world rotations and (n, 3) world accelerations of the phone on the grid ``t``."""
    from scipy.spatial.transform import Rotation

    phase, amp = _gait(t, st, RAMP_IN_S)          # the body: bounce and sway
    _, swing = _gait(t, st, SWING_RAMP_IN_S)      # an arm or a leg takes a step or two to reach its swing
    yaw = _smooth(_body_yaw(t, st, hd), 0.15) + amp * np.deg2rad(4.0) * np.sin(phase / 2)
    # horizontal path: step positions, linear in time, smoothed
    pos = np.vstack([[0.0, 0.0], np.cumsum(length[:, None] * np.c_[np.cos(hd), np.sin(hd)], axis=0)])
    kt = np.r_[st[0] - 0.5, st]
    ph = _smooth(np.column_stack([np.interp(t, kt, pos[:, j]) for j in range(2)]), 0.08)
    excursion = leg_m - np.sqrt(leg_m**2 - (np.interp(t, st, length) / 2) ** 2)
    z = -0.5 * bounce_scale * excursion * amp * carry.damping * np.cos(phase)
    theta = swing * carry.swing_rad * np.sin(phase / 2)
    if carry.mode == "pocket":   # the thigh swings forward faster than back
        theta = theta + swing * 0.3 * carry.swing_rad * np.sin(phase + 0.5)
    wobble = amp * carry.swing_rad * np.sin(phase + 1.0) if carry.arm_m == 0 else 0.0
    r_body = Rotation.from_euler("z", yaw[:, None])
    r_swing = Rotation.from_rotvec(np.column_stack([np.zeros_like(t), theta + wobble, np.zeros_like(t)]))
    # a hand (or a body) is never perfectly still: a slow tremor of about TREMOR_RAD on every axis
    tremor = _smooth(rng.normal(0.0, 1.0, (len(t), 3)), 0.3)
    tremor *= TREMOR_RAD / max(float(tremor.std()), 1e-12)
    r_dev = r_body * r_swing * Rotation.from_rotvec(tremor) * Rotation.from_matrix(carry.mount)
    lever = carry.lever_m + r_swing.apply(np.array([0.0, 0.0, -carry.arm_m]))
    p = np.column_stack([ph, z]) + r_body.apply(lever)
    acc = np.gradient(np.gradient(p, t, axis=0), t, axis=0)
    # heel strikes: a short upward jolt and a braking jolt at every step, harder on the near leg
    jolt = np.zeros(len(t))
    for k, tk in enumerate(st):
        lo, hi = np.searchsorted(t, [tk - 0.1, tk + 0.1])
        jolt[lo:hi] += carry.jolt_mps2[k % 2] * np.exp(-0.5 * ((t[lo:hi] - tk) / 0.025) ** 2)
    jolt *= carry.damping
    acc[:, 2] += jolt
    acc[:, 0] -= 0.4 * jolt * np.cos(yaw)
    acc[:, 1] -= 0.4 * jolt * np.sin(yaw)
    return r_dev.as_matrix(), acc


def _walked(t: np.ndarray, st: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Distance walked (m) at times ``t``: growing over each step, constant through a pause."""
    cum = np.cumsum(length)
    kt, kd = [st[0] - 0.5], [0.0]
    for k in range(len(st)):
        if k and st[k] - st[k - 1] > PAUSE_GAP_S:
            kt.append(st[k] - 0.5)
            kd.append(cum[k - 1])
        kt.append(st[k])
        kd.append(cum[k])
    return np.interp(t, kt, kd)


def _magnetic_error(walked_m: np.ndarray, rng: np.random.Generator, amplitude_rad: float) -> np.ndarray:
    """A yaw error that varies along the walk: a sum of random sinusoids of the distance walked, with
    wavelengths of 5-60 m (steel in walls and floors)."""
    out = np.zeros(len(walked_m))
    for _ in range(6):
        out += amplitude_rad / np.sqrt(3) * np.sin(2 * np.pi * walked_m / rng.uniform(5, 60) + rng.uniform(0, 6.3))
    return out


def synthesize_phone_imu(step_t_s: np.ndarray, heading_rad: np.ndarray, rng: np.random.Generator, *,
                         mode: str = "texting", step_length_m: np.ndarray | float = 0.7, fs_hz: float = 50.0,
                         t_start_s: float | None = None, t_end_s: float | None = None,
                         jitter_s: float = 0.002, acc_noise_mps2: float = 0.05,
                         gyro_noise_radps: float = 0.01, gyro_bias_radps: np.ndarray | None = None,
                         yaw_offset_rad: float = 0.0, yaw_noise_rad: float = 0.02,
                         magnetic_error_rad: float = 0.1, yaw_error: tuple[np.ndarray, np.ndarray] | None = None,
                         leg_m: float = 0.9, bounce_scale: float = 1.0, carry: Carry | None = None) -> ImuSignals:
    """Phone IMU signals for steps at ``step_t_s`` (k,) walked in ENU headings ``heading_rad`` (k,).

    ``mode``: carrying mode (or an explicit ``carry``); ``step_length_m`` per step or one value (sets the
    bounce); ``bounce_scale`` multiplies it (gentle < 1 < brisk). Sampled at ``fs_hz`` with timestamp jitter
    ``jitter_s`` (1-sigma) from ``t_start_s`` (default 1 s before the first step) to ``t_end_s`` (1 s after
    the last). ``gyro_bias_radps`` (3,) constant bias (default none); the rotation vector's yaw carries
    ``yaw_offset_rad`` + a slowly varying error of about ``magnetic_error_rad`` (or, when given, ``yaw_error``
    = (times, errors in rad) interpolated; NaN errors: no rotation vector at all) + white ``yaw_noise_rad``.
    """
    from scipy.spatial.transform import Rotation

    st = np.asarray(step_t_s, dtype=np.float64)
    hd = np.unwrap(np.asarray(heading_rad, dtype=np.float64))
    length = np.broadcast_to(np.asarray(step_length_m, dtype=np.float64), st.shape)
    carry = carry if carry is not None else draw_carry(mode, rng)
    t_a = st[0] - 1.0 if t_start_s is None else t_start_s
    t_b = st[-1] + 1.0 if t_end_s is None else t_end_s
    tf = t_a + np.arange(int((t_b - t_a) * FINE_HZ) + 2) / FINE_HZ
    r_dw, acc_w = _motion(tf, st, hd, length, carry, leg_m, bounce_scale, rng)
    rot = Rotation.from_matrix(r_dw)
    # body rates: the rotation between neighbouring grid points, at the midpoints
    w_mid = (rot[:-1].inv() * rot[1:]).as_rotvec() * FINE_HZ
    tm = 0.5 * (tf[1:] + tf[:-1])
    f_dev = rot.inv().apply(acc_w + np.array([0.0, 0.0, G_MPS2]))
    # sample at the phone's rate; the reported times jitter
    ts = t_a + np.arange(int((t_b - t_a) * fs_hz)) / fs_hz
    rep = np.sort(ts + rng.normal(0.0, jitter_s, len(ts))) if jitter_s > 0 else ts
    step = np.arange(len(rep)) * MIN_REPORTED_DT_S   # reported times strictly increase, as a phone's do
    rep = np.maximum.accumulate(rep - step) + step
    at = lambda x, tt: np.column_stack([np.interp(ts, tt, x[:, j]) for j in range(x.shape[1])])  # noqa: E731
    acc = at(f_dev, tf) + rng.normal(0.0, acc_noise_mps2, (len(ts), 3))
    bias = np.zeros(3) if gyro_bias_radps is None else np.asarray(gyro_bias_radps, dtype=np.float64)
    gyro = at(w_mid, tm) + bias + rng.normal(0.0, gyro_noise_radps, (len(ts), 3))
    # the magnetic error belongs to places, not times: a function of the distance walked (constant while
    # standing)
    walked = _walked(ts, st, length)
    if yaw_error is None:
        slow = _magnetic_error(walked, rng, magnetic_error_rad)
    else:
        slow = np.interp(walked, _walked(yaw_error[0], st, length), yaw_error[1])
    err = yaw_offset_rad + slow + rng.normal(0, yaw_noise_rad, len(ts))
    q_true = Rotation.from_matrix(np.stack([np.column_stack([np.interp(ts, tf, r_dw[:, i, j]) for j in range(3)])
                                            for i in range(3)], axis=1))
    q = (Rotation.from_euler("z", np.nan_to_num(err)[:, None]) * q_true).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    from rmbuild.pdr.heading import yaw_from_quat

    has = np.isfinite(err)
    return ImuSignals(
        t_acc_s=rep, acc_mps2=acc, t_yaw_s=rep[has], yaw_abs_rad=yaw_from_quat(q[has]),
        yaw_accuracy=np.full(int(has.sum()), 3, dtype=np.int64), t_gyro_s=rep, gyro_radps=gyro, quat_xyzw=q[has],
    )


def rotation_vector_samples(psi: np.ndarray, pitch_rad: float) -> np.ndarray:
    """(n, 4) Android rotation-vector quaternions (x, y, z, w) for device yaw ``psi`` (rad, 0 = top edge
    pointing north) and pitch ``pitch_rad`` — for writing synthetic trace files."""
    psi = np.asarray(psi, dtype=np.float64)
    cp, sp = np.cos(psi / 2), np.sin(psi / 2)
    cf, sf = np.cos(pitch_rad / 2), np.sin(pitch_rad / 2)
    q = np.column_stack([cp * sf, sp * sf, sp * cf, cp * cf])
    return q * np.where(q[:, 3:4] < 0, -1.0, 1.0)
