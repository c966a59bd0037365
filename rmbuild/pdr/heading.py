"""Angles and the rotation vector: Android rotation vector -> quaternion -> yaw, interval means (the wrap is
:func:`rmbuild.geometry.wrap`).

Convention (used for every ``*_rad`` heading in rmbuild): counter-clockwise from the x axis. For the
absolute yaw the world frame is Android's ENU (x east, y north), so ``yaw_abs_rad = pi/2 - azimuth``.
"""

from __future__ import annotations

import numpy as np

from rmbuild.geometry import wrap


def rotation_vector_quat(xyz: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """(n, 4) unit quaternions (x, y, z, w) from Android rotation-vector values.

    ``xyz``: (n, 3) values[0..2] = axis * sin(angle / 2); ``w``: (n,) values[3] when recorded, else it is
    sqrt(1 - |xyz|²) as Android's own ``getQuaternionFromVector`` does.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if w is None:
        w = np.sqrt(np.clip(1.0 - np.sum(xyz**2, axis=1), 0.0, None))
    q = np.column_stack([xyz, np.asarray(w, dtype=np.float64)])
    n = np.linalg.norm(q, axis=1, keepdims=True)
    return q / np.where(n > 0, n, 1.0)


def yaw_from_quat(q: np.ndarray) -> np.ndarray:
    """(n,) ENU yaw in rad (CCW from east) of the phone's forward direction for (n, 4) quaternions (x,y,z,w).

    Forward = the horizontal projection of the device's y axis (top edge) plus its -z axis (out of the
    back): the two agree for a phone held anywhere between flat and upright, and their sum stays well
    defined in both extremes (Android's azimuth uses the y axis alone and degenerates upright).
    """
    x, y, z, w = (q[:, i] for i in range(4))
    r01 = 2 * (x * y - z * w)   # east component of device y
    r11 = 1 - 2 * (x * x + z * z)  # north component of device y
    r02 = 2 * (x * z + y * w)   # east component of device z
    r12 = 2 * (y * z - x * w)   # north component of device z
    return np.arctan2(r11 - r12, r01 - r02)


def accuracy_flags(values: np.ndarray) -> np.ndarray:
    """Android accuracy flags (0-3) as int64 from a numeric column; anything else (-1, NaN, a hostile 1e20)
    is -1, unknown."""
    v = np.asarray(values, dtype=np.float64)
    out = np.full(v.shape, -1, dtype=np.int64)
    ok = np.isin(v, (0.0, 1.0, 2.0, 3.0))
    out[ok] = v[ok].astype(np.int64)
    return out


def yaw_from_azimuth_deg(azimuth_deg: np.ndarray) -> np.ndarray:
    """ENU yaw in rad from a compass azimuth in degrees (clockwise from north)."""
    return wrap(np.pi / 2 - np.deg2rad(np.asarray(azimuth_deg, dtype=np.float64)))


def interval_mean(t_s: np.ndarray, values: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Time average of the piecewise-linear signal (t_s, values) over each [t0[i], t1[i]] (point value
    where t0 == t1). ``values`` must be continuous (unwrap angles first)."""
    t_s = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    cum = np.zeros(len(t_s))
    if len(t_s) > 1:
        cum[1:] = np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t_s))

    def integral(t: np.ndarray) -> np.ndarray:
        # integral from t_s[0] to t, linear extension beyond the ends
        tc = np.clip(t, t_s[0], t_s[-1])
        i = np.clip(np.searchsorted(t_s, tc, side="right") - 1, 0, max(len(t_s) - 2, 0))
        if len(t_s) == 1:
            return v[0] * (t - t_s[0])
        ti, vi = t_s[i], v[i]
        vt = np.interp(tc, t_s, v)
        inside = cum[i] + 0.5 * (vi + vt) * (tc - ti)
        return inside + np.where(t < t_s[0], v[0] * (t - t_s[0]), 0.0) + np.where(
            t > t_s[-1], v[-1] * (t - t_s[-1]), 0.0)

    t0 = np.asarray(t0, dtype=np.float64)
    t1 = np.asarray(t1, dtype=np.float64)
    span = t1 - t0
    point = np.interp(t1, t_s, v)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (integral(t1) - integral(t0)) / span
    return np.where(span > 1e-9, mean, point)
