"""Seeded synthetic phone IMU for a walk with known steps (tests, and raw signals for `simulate`).

The phone is held in front, top edge forward, pitched up by ``pitch_rad``; its forward direction follows
the walking heading. The vertical acceleration is a gait waveform with one cycle per step (peak at the
step time), plus sensor noise; standing still (long gaps between steps) gives gravity and noise only.
"""

from __future__ import annotations

import numpy as np

from rmbuild.pdr.core import ImuSignals

G_MPS2 = 9.80665


def _quat_zx(psi: np.ndarray, pitch: float) -> np.ndarray:
    """(n, 4) quaternions (x, y, z, w) of Rz(psi) @ Rx(pitch), w >= 0."""
    cp, sp = np.cos(psi / 2), np.sin(psi / 2)
    cf, sf = np.cos(pitch / 2), np.sin(pitch / 2)
    q = np.column_stack([cp * sf, sp * sf, sp * cf, cp * cf])
    return q * np.where(q[:, 3:4] < 0, -1.0, 1.0)


def _rot_zx(psi: np.ndarray, pitch: float) -> np.ndarray:
    """(n, 3, 3) device->world rotations Rz(psi) @ Rx(pitch)."""
    c, s = np.cos(psi), np.sin(psi)
    cf, sf = np.cos(pitch), np.sin(pitch)
    r = np.zeros((len(psi), 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 0, 2] = c, -s * cf, s * sf
    r[:, 1, 0], r[:, 1, 1], r[:, 1, 2] = s, c * cf, -c * sf
    r[:, 2, 1], r[:, 2, 2] = sf, cf
    return r


def synthesize_phone_imu(step_t_s: np.ndarray, heading_rad: np.ndarray, rng: np.random.Generator, *,
                         t_start_s: float | None = None, t_end_s: float | None = None, fs_hz: float = 50.0,
                         amp_mps2: float = 2.5, acc_noise_mps2: float = 0.3, gyro_noise_radps: float = 0.02,
                         yaw_noise_rad: float = 0.05, yaw_offset_rad: float = 0.0, pitch_rad: float = 0.5,
                         max_gap_s: float = 1.5) -> ImuSignals:
    """Phone IMU signals for steps at ``step_t_s`` (k,) walked in ENU headings ``heading_rad`` (k,).

    Returns :class:`ImuSignals` sampled at ``fs_hz`` (with 2 ms timestamp jitter) from ``t_start_s``
    (default: 1 s before the first step) to ``t_end_s`` (default: 1 s after the last). The absolute
    yaw gets ``yaw_offset_rad`` (a magnetic bias) and white noise ``yaw_noise_rad``.
    """
    st = np.asarray(step_t_s, dtype=np.float64)
    hd = np.unwrap(np.asarray(heading_rad, dtype=np.float64))
    t_a = st[0] - 1.0 if t_start_s is None else t_start_s
    t_b = st[-1] + 1.0 if t_end_s is None else t_end_s
    t = t_a + np.arange(int((t_b - t_a) * fs_hz)) / fs_hz
    t = np.sort(t + rng.uniform(-0.002, 0.002, len(t)))
    # gait phase: 0 at each step, +2 pi per step; amplitude 0 when standing
    i = np.searchsorted(st, t, side="right")  # steps at or before t
    walking = np.zeros(len(t), dtype=bool)
    phase = np.zeros(len(t))
    inner = (i > 0) & (i < len(st))
    gap = np.where(inner, st[np.minimum(i, len(st) - 1)] - st[np.maximum(i - 1, 0)], np.inf)
    walking[inner] = gap[inner] <= max_gap_s
    prev_t = st[np.maximum(i - 1, 0)]
    phase[inner] = 2 * np.pi * (t[inner] - prev_t[inner]) / gap[inner]
    # half a cycle of ramp-in/out around the first/last step of each walking bout
    amp = np.where(walking, amp_mps2, 0.0)
    near = np.min(np.abs(t[:, None] - st[None, :]), axis=1) < 0.25
    amp = np.where(near & ~walking, amp_mps2, amp)
    vert = amp * (np.cos(phase) + 0.35 * np.cos(2 * phase + 0.6))
    fwd = 0.4 * amp * np.sin(phase)
    # heading at each sample: the heading of the step being walked (interpolated between steps)
    h = np.interp(t, st, hd)
    psi = h - np.pi / 2
    rot = _rot_zx(psi, pitch_rad)
    f_world = np.column_stack([fwd * np.cos(h), fwd * np.sin(h), G_MPS2 + vert])
    acc = np.einsum("nji,nj->ni", rot, f_world) + rng.normal(0, acc_noise_mps2, (len(t), 3))
    rate = np.gradient(h, t)
    gyro = np.einsum("nji,nj->ni", rot, np.column_stack([np.zeros_like(t), np.zeros_like(t), rate]))
    gyro += rng.normal(0, gyro_noise_radps, gyro.shape)
    q = _quat_zx(psi + yaw_offset_rad + rng.normal(0, yaw_noise_rad, len(t)), pitch_rad)
    from rmbuild.pdr.heading import yaw_from_quat

    return ImuSignals(
        t_acc_s=t, acc_mps2=acc, t_yaw_s=t, yaw_abs_rad=yaw_from_quat(q),
        yaw_accuracy=np.full(len(t), 3, dtype=np.int64), t_gyro_s=t, gyro_radps=gyro,
    )


def rotation_vector_samples(psi: np.ndarray, pitch_rad: float) -> np.ndarray:
    """(n, 4) Android rotation-vector quaternions (x, y, z, w) for device yaw ``psi`` (rad, 0 = top edge
    pointing north) and pitch ``pitch_rad`` — for writing synthetic trace files."""
    return _quat_zx(np.asarray(psi, dtype=np.float64), pitch_rad)
