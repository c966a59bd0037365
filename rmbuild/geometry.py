"""Planar rigid-body geometry: the one home of SE(2) maths in rmbuild (no I/O, numpy only).

Conventions: a pose or rigid transform is ``(x, y, theta)`` [m, m, rad]; arrays of them are (n, 3). A pose
``a`` applied to a point ``p`` gives ``R(theta_a) p + t_a``; :func:`compose` is ``a · b`` (b expressed in
a's frame), :func:`between` is ``a⁻¹ · b`` (b in a's body frame). Angles come back wrapped to (-pi, pi].
A 2-D rotation as a matrix is ``R (2, 2)``, a rigid point transform ``(R, t)`` with ``dst ≈ R @ src + t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def wrap(a):
    """Angle(s) (rad) wrapped to (-pi, pi] (an angle of exactly +-pi may come back as -pi: the sign of
    sin(pi) in floating point); NaN stays NaN. The one angle wrap of rmbuild (PDR headings, the simulator,
    the SLAM back end)."""
    return np.angle(np.exp(1j * np.asarray(a, dtype=float)))


def circular_mean(a) -> float:
    """Circular mean (rad, in [-pi, pi)) of the angles ``a``: the argument of the mean resultant vector
    (Mardia & Jupp, Directional Statistics, Wiley 1999, eq. 2.2.4); NaN for none. The same floating-point
    operations as ``scipy.stats.circmean(a, high=pi, low=-pi)``, whose module costs ~1.5 s at import."""
    a = np.asarray(a, dtype=float).ravel()
    if a.size == 0:
        return float("nan")
    res = np.arctan2(np.sin(a).sum(), np.cos(a).sum())
    return float((res * 1.0 + np.pi) % (2.0 * np.pi) - np.pi)


def rot(theta: float) -> np.ndarray:
    """The (2, 2) rotation matrix of angle ``theta`` (rad)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def rotation_angle_rad(r: np.ndarray) -> float:
    """The angle (rad, in (-pi, pi]) of a 2-D rotation matrix."""
    return float(math.atan2(r[1, 0], r[0, 0]))


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a · b`` for poses (3,) or pose arrays (m, 3); a single pose broadcasts against an array."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    a2, b2 = np.broadcast_arrays(np.atleast_2d(a), np.atleast_2d(b))
    c, s = np.cos(a2[:, 2]), np.sin(a2[:, 2])
    out = np.c_[a2[:, 0] + c * b2[:, 0] - s * b2[:, 1], a2[:, 1] + s * b2[:, 0] + c * b2[:, 1],
                wrap(a2[:, 2] + b2[:, 2])]
    return out[0] if a.ndim == 1 and b.ndim == 1 else out


def inverse(a: np.ndarray) -> np.ndarray:
    """``a⁻¹`` for a pose (3,) or a pose array (m, 3)."""
    a = np.asarray(a, dtype=float)
    a2 = np.atleast_2d(a)
    c, s = np.cos(a2[:, 2]), np.sin(a2[:, 2])
    out = np.c_[-(c * a2[:, 0] + s * a2[:, 1]), s * a2[:, 0] - c * a2[:, 1], -a2[:, 2]]
    return out[0] if a.ndim == 1 else out


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a⁻¹ · b`` for pose arrays a, b (m, 3): b in a's body frame (theta wrapped)."""
    d = b[:, :2] - a[:, :2]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap(b[:, 2] - a[:, 2])]


def increments(p: np.ndarray) -> np.ndarray:
    """Body-frame increments (n-1, 3) between consecutive poses p (n, 3) (odometry, Gu et al. 2017 eq. 6)."""
    return between(p[:-1], p[1:])


def align_se2(
    src_xy: np.ndarray, dst_xy: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid 2-D transform (rotation R (2, 2), translation t (2,)) with dst ≈ R @ src + t.

    ``src_xy``, ``dst_xy``: (n, 2) metres; ``weights``: (n,) non-negative or None. Umeyama without scale.
    With a single point (or all weight on one point) the rotation is the identity.
    """
    src = np.asarray(src_xy, dtype=float).reshape(-1, 2)
    dst = np.asarray(dst_xy, dtype=float).reshape(-1, 2)
    if len(src) != len(dst) or len(src) == 0:
        raise ValueError("align_se2 needs two non-empty point sets of the same length")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    if w.sum() <= 0:
        raise ValueError("align_se2 needs positive total weight")
    w = w / w.sum()
    mu_s = w @ src
    mu_d = w @ dst
    cov = ((dst - mu_d) * w[:, None]).T @ (src - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    r = u @ np.diag([1.0, d]) @ vt
    t = mu_d - r @ mu_s
    return r, t


def fit_rigid(src_xy: np.ndarray, dst_xy: np.ndarray, theta: float | None = None) -> np.ndarray:
    """Least-squares T = (x, y, theta) with dst ≈ R(theta) src + t: SE(2) when ``theta`` is None, else the
    translation for that fixed rotation."""
    if theta is None:
        R, t = align_se2(src_xy, dst_xy)
        return np.array([t[0], t[1], rotation_angle_rad(R)])
    t = np.mean(np.asarray(dst_xy, float) - np.asarray(src_xy, float) @ rot(theta).T, axis=0)
    return np.array([t[0], t[1], float(theta)])


@dataclass
class Hypotheses:
    """Rigid hypotheses src → dst: ``theta`` (h,) rad, ``t`` (h, 2) m, and every src point mapped by each
    (``px``, ``py``: (h, n))."""

    theta: np.ndarray
    t: np.ndarray
    px: np.ndarray
    py: np.ndarray

    def residuals(self, dst_xy: np.ndarray) -> np.ndarray:
        """(h, n) distance (m) of each mapped src point from its dst point."""
        return np.hypot(self.px - dst_xy[None, :, 0], self.py - dst_xy[None, :, 1])


def two_point_hypotheses(dst_xy: np.ndarray, src_xy: np.ndarray, min_span_m: float, n: int,
                         rng: np.random.Generator) -> Hypotheses | None:
    """SE(2) hypotheses src → dst from ``n`` random pairs of correspondences whose two points lie more
    than ``min_span_m`` apart on both sides (RANSAC's minimal sample in 2-D); None when no sample does."""
    m = len(dst_xy)
    i1, i2 = rng.integers(0, m, n), rng.integers(0, m, n)
    va, vb = dst_xy[i2] - dst_xy[i1], src_xy[i2] - src_xy[i1]
    ok = (np.linalg.norm(va, axis=1) > min_span_m) & (np.linalg.norm(vb, axis=1) > min_span_m)
    if not ok.any():
        return None
    i1, i2, va, vb = i1[ok], i2[ok], va[ok], vb[ok]
    ths = np.arctan2(va[:, 1], va[:, 0]) - np.arctan2(vb[:, 1], vb[:, 0])
    c, s = np.cos(ths), np.sin(ths)
    mb, ma = (src_xy[i1] + src_xy[i2]) / 2, (dst_xy[i1] + dst_xy[i2]) / 2
    ts = ma - np.c_[c * mb[:, 0] - s * mb[:, 1], s * mb[:, 0] + c * mb[:, 1]]
    px = c[:, None] * src_xy[None, :, 0] - s[:, None] * src_xy[None, :, 1] + ts[:, 0:1]
    py = s[:, None] * src_xy[None, :, 0] + c[:, None] * src_xy[None, :, 1] + ts[:, 1:2]
    return Hypotheses(ths, ts, px, py)


def refine_on_inliers(src_xy: np.ndarray, dst_xy: np.ndarray, T: np.ndarray, gate_m: float,
                      se2: bool, rounds: int = 3, min_se2: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Refit a rigid T (3,) on its inliers (residual < ``gate_m``) ``rounds`` times: SE(2) with at least
    ``min_se2`` inliers when ``se2``, else the translation only. Returns (T, final inlier mask)."""
    th, t = float(T[2]), np.asarray(T[:2], float)
    for _ in range(rounds):
        cur = np.linalg.norm(dst_xy - (src_xy @ rot(th).T + t), axis=1) < gate_m
        if cur.sum() < 1:
            break
        if se2 and cur.sum() >= min_se2:
            R, t = align_se2(src_xy[cur], dst_xy[cur])
            th = rotation_angle_rad(R)
        else:
            t = np.mean(dst_xy[cur] - src_xy[cur] @ rot(th).T, axis=0)
    inl = np.linalg.norm(dst_xy - (src_xy @ rot(th).T + t), axis=1) < gate_m
    return np.array([t[0], t[1], th]), inl


def extent_m(xy: np.ndarray) -> float:
    """RMS distance (m) of positions (n, 2) from their centroid (0 for none)."""
    return float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1)))) if len(xy) else 0.0
