"""Attitude of a carried phone: gyroscope bias, the gravity direction in the device frame, yaw about gravity.

The yaw that matters for walking is the rotation about the *world* vertical, whatever the phone's tilt:
``yaw_rate = up · (ω − b)`` with ``up`` the unit gravity direction in the device frame and ``b`` the gyro
bias. Two things make this hard on real phones (measured on the IPIN 2023 logfiles, docs/notes/formats-real.md):

- **Bias**: Android's "calibrated" gyroscope still carried 2-5 °/s on some Samsung walks (a 300° turn over a
  4-minute walk). :func:`gyro_bias` takes it from the rotation vector when the phone records one (the rate
  the fused orientation implies, compared sample by sample; the median difference), else from the
  stretches where the phone lies still.
- **Tilt that changes fast** (a phone swinging in the hand or in a pocket): a low-passed accelerometer lags
  behind the device's rotation. :func:`up_vectors` is a complementary filter done without a loop: the
  accelerometer is rotated into the gyro-integrated frame (where gravity stays almost fixed), averaged
  there, and rotated back.
"""

from __future__ import annotations

import numpy as np

from rmbuild.pdr.timebase import DROPOUT_S

#: s; averaging window of the accelerometer in the gyro-integrated frame (the complementary filter's time
#: constant), applied GRAVITY_PASSES times (three boxes: nearly Gaussian, so what is left of a stride's
#: periodic accelerations is ~1 %; a single box left enough, in phase with a swinging phone's rotation,
#: to drift the yaw by 3-6 °/min on the synthetic pocket and hand-swing cases)
GRAVITY_WINDOW_S = 2.0
GRAVITY_PASSES = 3
#: rad/s; samples rotating faster than this are left out of the rotation-vector bias estimate (the fused
#: orientation lags the gyro in fast motion)
BIAS_MAX_RATE_RADPS = 0.5
#: rad; typical error of a magnetometer-referenced yaw indoors (walks of ILC F1 agree to a median 6°,
#: P90 17°): the uncertainty of the vertical bias the rotation vector implies is this over the walk's span
MAG_YAW_DISTURBANCE_RAD = np.deg2rad(15.0)
#: points of the yaw-drift series the robust slope is fitted to (Theil-Sen is quadratic in them)
BIAS_SLOPE_POINTS = 400
#: minimum number of samples for a bias estimate
BIAS_MIN_SAMPLES = 100
#: rad/s and m/s²; a 1-s window is still when every gyro axis varies less than this, the mean rate is
#: small and the accelerometer magnitude varies less than this (a phone on a table or held very still)
STILL_GYRO_STD_RADPS = 0.03
STILL_GYRO_MEAN_RADPS = 0.15
STILL_ACC_STD_MPS2 = 0.15
#: s; still time needed for a bias estimate from still stretches, and the shortest stretch counted
STILL_MIN_S = 3.0
STILL_SEGMENT_MIN_S = 2.0
#: s; the orientation at each end of a still stretch is its mean over this long (single samples are noisy)
STILL_END_S = 0.5
#: rad/s; a bias estimate above this is not believed (a phone that turned steadily, not a bias)
MAX_BIAS_RADPS = 0.2


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (n, 4) quaternions (x, y, z, w)."""
    ax, ay, az, aw = (a[..., i] for i in range(4))
    bx, by, bz, bw = (b[..., i] for i in range(4))
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 3) vectors ``v`` rotated by (n, 4) unit quaternions ``q`` (x, y, z, w): q v q*."""
    u, w = q[:, :3], q[:, 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _increments(t_s: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """(n, 4) body-frame rotation increments: identity at sample 0 and across dropouts, else the rotation
    by the mean rate of the interval times its length."""
    dt = np.diff(t_s)
    dt = np.where(dt > DROPOUT_S, 0.0, dt)
    phi = 0.5 * (rate[1:] + rate[:-1]) * dt[:, None]
    ang = np.linalg.norm(phi, axis=1, keepdims=True)
    half = 0.5 * ang
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where(ang > 1e-12, phi / ang, 0.0)
    dq = np.column_stack([axis * np.sin(half), np.cos(half)])
    return np.vstack([[0.0, 0.0, 0.0, 1.0], dq])


def integrate_rates(t_s: np.ndarray, rate_radps: np.ndarray) -> np.ndarray:
    """(n, 4) orientations (device -> start frame) from body rates (n, 3) at times (n,): the ordered product
    of the increments, computed as a parallel prefix product (log2 n vectorised passes)."""
    q = _increments(np.asarray(t_s, dtype=np.float64), np.asarray(rate_radps, dtype=np.float64))
    shift = 1
    while shift < len(q):
        q[shift:] = quat_mul(q[:-shift], q[shift:])
        q[shift:] /= np.linalg.norm(q[shift:], axis=1, keepdims=True)
        shift *= 2
    return q


def _moving_mean(x: np.ndarray, t_s: np.ndarray, window_s: float) -> np.ndarray:
    """Centred moving mean of (n, k) ``x`` over ``window_s`` of time (samples need not be uniform)."""
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    lo = np.searchsorted(t_s, t_s - window_s / 2, side="left")
    hi = np.searchsorted(t_s, t_s + window_s / 2, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)[:, None]


def up_vectors(t_s: np.ndarray, rate_radps: np.ndarray, acc_mps2: np.ndarray) -> np.ndarray:
    """(n, 3) unit "up" (minus gravity, i.e. the specific force at rest) in the device frame at the gyro
    sample times ``t_s``. ``acc_mps2`` (n, 3) is the accelerometer interpolated to those times, ``rate_radps``
    the bias-corrected body rates."""
    q = integrate_rates(t_s, rate_radps)
    a_ref = quat_rotate(q, acc_mps2)
    g_ref = a_ref
    for _ in range(GRAVITY_PASSES):
        g_ref = _moving_mean(g_ref, t_s, GRAVITY_WINDOW_S)
    qc = q * np.array([-1.0, -1.0, -1.0, 1.0])
    up = quat_rotate(qc, g_ref)
    return up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)


def yaw_about_gravity(t_s: np.ndarray, rate_radps: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n,) yaw in rad, counter-clockwise seen from above, 0 at the first sample: the trapezoidal integral
    of ``up · rate``; nothing is added across dropouts (heading held)."""
    r = np.sum(np.asarray(rate_radps, dtype=np.float64) * up, axis=1)
    dt = np.diff(t_s)
    dt = np.where(dt > DROPOUT_S, 0.0, dt)
    return np.r_[0.0, np.cumsum(0.5 * (r[1:] + r[:-1]) * dt)]


def _rates_from_quats(t_s: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mid-interval times and body rates (rad/s) implied by consecutive orientations (n, 4)."""
    dt = np.diff(t_s)
    ok = (dt > 1e-3) & (dt <= DROPOUT_S)
    qc = q[:-1] * np.array([-1.0, -1.0, -1.0, 1.0])
    d = quat_mul(qc, q[1:])
    d *= np.where(d[:, 3:4] < 0, -1.0, 1.0)
    s = np.linalg.norm(d[:, :3], axis=1, keepdims=True)
    ang = 2.0 * np.arctan2(s, d[:, 3:4])
    with np.errstate(invalid="ignore", divide="ignore"):
        rv = np.where(s > 1e-12, d[:, :3] / s * ang, 0.0)
    tm = 0.5 * (t_s[1:] + t_s[:-1])
    return tm[ok], rv[ok] / dt[ok, None]


def gyro_bias(t_gyro_s: np.ndarray, gyro_radps: np.ndarray, t_quat_s: np.ndarray, quat: np.ndarray,
              t_acc_s: np.ndarray, acc_mps2: np.ndarray) -> tuple[np.ndarray, str]:
    """(3,) gyro bias in rad/s and how it was found: "still", "rotation_vector" or "none" (zero).

    ``quat`` (m, 4): the fused orientation (rotation vector, device -> ENU) at ``t_quat_s``, or empty.
    - "still", when the walk has :data:`STILL_MIN_S` of still stretches (:func:`still_mask`): the mean
      difference there between the gyro's rates and the rates the orientation implies (a standing walker's
      magnetic disturbance does not change, so the orientation follows the hand's slow wander), or without
      an orientation the gyro's own mean rate there (up to that wander over the still time);
    - "rotation_vector": across gravity the median rate difference over the whole walk, about gravity the
      drift of the rotation between the gyro's and the orientation's frames (:func:`_vertical_bias`).
    """
    tg = np.asarray(t_gyro_s, dtype=np.float64)
    w = np.asarray(gyro_radps, dtype=np.float64)
    acc = np.asarray(acc_mps2, dtype=np.float64)
    still = still_mask(tg, w, t_acc_s, acc)
    has_q = len(t_quat_s) > BIAS_MIN_SAMPLES and len(quat) == len(t_quat_s) and len(tg) > BIAS_MIN_SAMPLES
    b: np.ndarray | None = None
    how = "none"
    if has_q:
        tq, q = np.asarray(t_quat_s, dtype=np.float64), np.asarray(quat, dtype=np.float64)
        tm, wr = _rates_from_quats(tq, q)
        wg = np.column_stack([np.interp(tm, tg, w[:, j]) for j in range(3)])
        if still.any():
            b, how = still_mean(tg, w, still, tq, q), "still"
        else:
            b, how = _rotation_vector_bias(tg, w, tq, q, tm, wg - wr, acc), "rotation_vector"
    elif still.any():
        b, how = still_mean(tg, w, still), "still"
    if b is None or not np.linalg.norm(b) <= MAX_BIAS_RADPS:
        return np.zeros(3), "none"
    return b, how


def _rotation_vector_bias(t_s: np.ndarray, rate_radps: np.ndarray, t_quat_s: np.ndarray, quat: np.ndarray,
                          t_mid_s: np.ndarray, rate_diff: np.ndarray, acc_mps2: np.ndarray) -> np.ndarray | None:
    """Bias from a whole walk's orientation: across the mean gravity direction the median of ``rate_diff``
    (gyro minus orientation rates at ``t_mid_s``) over slow samples, about it :func:`_vertical_bias`."""
    up = acc_mps2.mean(axis=0)
    wg = rate_diff  # only its slow samples count: the fused orientation lags the gyro in fast motion
    slow = np.linalg.norm(np.column_stack([np.interp(t_mid_s, t_s, rate_radps[:, j]) for j in range(3)]),
                          axis=1) < BIAS_MAX_RATE_RADPS
    if slow.sum() < BIAS_MIN_SAMPLES or np.linalg.norm(up) == 0:
        return None
    up = up / np.linalg.norm(up)
    b = np.median(wg[slow], axis=0)
    b -= (b @ up) * up
    return b + _vertical_bias(t_s, rate_radps - b, t_quat_s, quat) * up


def _vertical_bias(t_s: np.ndarray, rate_radps: np.ndarray, t_quat_s: np.ndarray, quat: np.ndarray) -> float:
    """Bias about gravity (rad/s) from the drift of ``q_rv ⊗ q_gyro⁻¹``: the rotation from the gyro's start
    frame to ENU, a fixed rotation about the vertical but for the gyro's bias (a steady drift) and the
    magnetometer's errors (bounded); :func:`drift_rate` of its yaw."""
    qg = integrate_rates(t_s, rate_radps)
    qg_at = np.stack([np.interp(t_quat_s, t_s, qg[:, j]) for j in range(4)], axis=1)
    qg_at /= np.linalg.norm(qg_at, axis=1, keepdims=True)
    c = quat_mul(quat, qg_at * np.array([-1.0, -1.0, -1.0, 1.0]))
    x, y, z, w = (c[:, i] for i in range(4))
    return -drift_rate(t_quat_s, np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))))


def drift_rate(t_s: np.ndarray, yaw_diff_rad: np.ndarray) -> float:
    """Steady drift (rad/s) of a magnetometer-referenced yaw minus a gyro yaw (continuous, (n,) at ``t_s``):
    the robust (Theil-Sen) slope, shrunk by its significance: the yaw errors of a magnetometer indoors,
    :data:`MAG_YAW_DISTURBANCE_RAD`, over the span make its 1-sigma (James-Stein: d (1 - sigma² / d²),
    0 when not significant). 0 for fewer than :data:`BIAS_MIN_SAMPLES` samples."""
    from scipy.stats import theilslopes

    t = np.asarray(t_s, dtype=np.float64)
    if len(t) < BIAS_MIN_SAMPLES or t[-1] <= t[0]:
        return 0.0
    keep = np.linspace(0, len(t) - 1, min(len(t), BIAS_SLOPE_POINTS)).astype(np.int64)
    d = float(theilslopes(np.asarray(yaw_diff_rad)[keep], t[keep])[0])
    sigma = MAG_YAW_DISTURBANCE_RAD / float(t[-1] - t[0])
    return d * max(0.0, 1.0 - sigma**2 / d**2) if d != 0 else 0.0


def still_mask(t_s: np.ndarray, gyro_radps: np.ndarray, t_acc_s: np.ndarray, acc_mps2: np.ndarray,
               ) -> np.ndarray:
    """(n,) true for gyro samples in still stretches: 1-s windows whose rates and accelerometer magnitude
    hardly vary (the STILL_* constants), in stretches of at least :data:`STILL_SEGMENT_MIN_S` (a slow,
    steady turn on the spot looks still for a moment); all false with less than :data:`STILL_MIN_S`."""
    n = len(t_s)
    if n < BIAS_MIN_SAMPLES or len(t_acc_s) < 2:
        return np.zeros(n, dtype=bool)
    w = np.asarray(gyro_radps, dtype=np.float64)
    mu = _moving_mean(w, t_s, 1.0)
    sd = np.sqrt(np.maximum(_moving_mean(w * w, t_s, 1.0) - mu * mu, 0.0)).max(axis=1)
    mag = np.interp(t_s, t_acc_s, np.linalg.norm(np.asarray(acc_mps2, dtype=np.float64), axis=1))[:, None]
    mm = _moving_mean(mag, t_s, 1.0)
    ms = np.sqrt(np.maximum(_moving_mean(mag * mag, t_s, 1.0) - mm * mm, 0.0))[:, 0]
    still = (sd < STILL_GYRO_STD_RADPS) & (np.linalg.norm(mu, axis=1) < STILL_GYRO_MEAN_RADPS) & (
        ms < STILL_ACC_STD_MPS2)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    out = np.zeros(n, dtype=bool)
    total = 0.0
    for a, b in zip(edges[::2], edges[1::2]):
        d = float(t_s[b - 1] - t_s[a])
        if d >= STILL_SEGMENT_MIN_S:
            out[a:b] = True
            total += d
    return out if total >= STILL_MIN_S else np.zeros(n, dtype=bool)


def still_mean(t_s: np.ndarray, gyro_radps: np.ndarray, still: np.ndarray, t_quat_s: np.ndarray | None = None,
               quat: np.ndarray | None = None) -> np.ndarray:
    """(3,) duration-weighted median over the still stretches of their mean rate minus, when the orientation
    ``quat`` (m, 4) at ``t_quat_s`` is given, the rotation it makes over the stretch divided by its duration
    (the hand's slow wander, which the orientation sees: a standing walker's magnetic disturbance does not
    change). Without it, a stretch's mean rate is the bias up to that wander / duration."""
    w = np.asarray(gyro_radps, dtype=np.float64)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    starts, ends = edges[::2], edges[1::2]
    dur = t_s[ends - 1] - t_s[starts]
    c = np.vstack([np.zeros((1, 3)), np.cumsum(w, axis=0)])
    means = (c[ends] - c[starts]) / (ends - starts)[:, None]
    if t_quat_s is not None and quat is not None and len(quat):
        qa = _mean_quat(t_quat_s, quat, t_s[starts], t_s[starts] + STILL_END_S)
        qb = _mean_quat(t_quat_s, quat, t_s[ends - 1] - STILL_END_S, t_s[ends - 1])
        # the gyro's mean rate over the same end windows' centres
        ca = np.searchsorted(t_s, t_s[starts] + STILL_END_S / 2)
        cb = np.searchsorted(t_s, t_s[ends - 1] - STILL_END_S / 2)
        dur = np.maximum(t_s[cb] - t_s[ca], 1e-9)
        means = (c[cb] - c[ca]) / np.maximum(cb - ca, 1)[:, None]
        d = quat_mul(qa * np.array([-1.0, -1.0, -1.0, 1.0]), qb)
        d *= np.where(d[:, 3:4] < 0, -1.0, 1.0)
        # the orientation takes the wander out: what is left is noise, so all stretches count by duration
        return (means * dur[:, None] - 2.0 * d[:, :3]).sum(axis=0) / max(float(dur.sum()), 1e-9)
    return np.array([_weighted_median(means[:, j], dur) for j in range(3)])


def _mean_quat(t_s: np.ndarray, quat: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """(k, 4) mean orientation over each [t0, t1] (normalised sum, sign-aligned: fine for nearby
    orientations), the nearest sample where the window holds none."""
    lo = np.clip(np.searchsorted(t_s, t0), 0, len(t_s) - 1)
    hi = np.maximum(np.searchsorted(t_s, t1, side="right"), lo + 1)
    out = np.empty((len(lo), 4))
    for i, (a, b) in enumerate(zip(lo, hi)):
        q = quat[a:b] * np.where(quat[a:b] @ quat[a] < 0, -1.0, 1.0)[:, None]
        m = q.sum(axis=0)
        out[i] = m / np.linalg.norm(m)
    return out


def _weighted_median(x: np.ndarray, weight: np.ndarray) -> float:
    o = np.argsort(x)
    c = np.cumsum(weight[o])
    return float(x[o][np.searchsorted(c, 0.5 * c[-1])])
