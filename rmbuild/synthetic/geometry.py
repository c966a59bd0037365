"""Vectorised 2-D segment geometry: which walls a straight line of sight crosses."""

from __future__ import annotations

import numpy as np


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def segments_cross(p0: np.ndarray, p1: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """bool (n, m): whether segment ``p0[i] -> p1[i]`` properly crosses wall j.

    p0, p1: (n, 2) segment end points in m; walls: (m, 4) rows ``x0, y0, x1, y1``. Touching an end point
    or running collinear counts as no crossing (door gaps stay open).
    """
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    w = np.asarray(walls, dtype=np.float64)
    if len(w) == 0 or len(p0) == 0:
        return np.zeros((len(p0), len(w)), dtype=bool)
    ax, ay = p0[:, 0:1], p0[:, 1:2]
    dx, dy = p1[:, 0:1] - ax, p1[:, 1:2] - ay
    qx0, qy0, qx1, qy1 = w[None, :, 0], w[None, :, 1], w[None, :, 2], w[None, :, 3]
    ex, ey = qx1 - qx0, qy1 - qy0
    o1 = _cross(dx, dy, qx0 - ax, qy0 - ay)
    o2 = _cross(dx, dy, qx1 - ax, qy1 - ay)
    o3 = _cross(ex, ey, ax - qx0, ay - qy0)
    o4 = _cross(ex, ey, ax + dx - qx0, ay + dy - qy0)
    return (o1 * o2 < 0) & (o3 * o4 < 0)


def wall_loss_from_point(
    src: np.ndarray, pts: np.ndarray, walls: np.ndarray, atten_db: np.ndarray, chunk: int = 512
) -> np.ndarray:
    """float (n,) summed attenuation in dB of the walls crossed by the sight lines ``src -> pts[i]``.

    src: (2,) one source (an AP); pts: (n, 2) receivers; walls: (m, 4); atten_db: (m,) per-wall loss.
    The wall-side sign of every receiver is computed once per wall, so each (receiver, wall) costs only
    the two orientation tests of the wall end points against the sight line. Walls are culled to the
    bounding box of the receivers and the source first.
    """
    pts = np.asarray(pts, dtype=np.float64)
    n = len(pts)
    out = np.zeros(n, dtype=np.float64)
    if n == 0 or len(walls) == 0:
        return out
    sx, sy = float(src[0]), float(src[1])
    lo = np.minimum(pts.min(axis=0), (sx, sy))
    hi = np.maximum(pts.max(axis=0), (sx, sy))
    w = np.asarray(walls, dtype=np.float64)
    keep = (
        (np.maximum(w[:, 0], w[:, 2]) >= lo[0]) & (np.minimum(w[:, 0], w[:, 2]) <= hi[0])
        & (np.maximum(w[:, 1], w[:, 3]) >= lo[1]) & (np.minimum(w[:, 1], w[:, 3]) <= hi[1])
    )
    w = w[keep]
    a = np.asarray(atten_db, dtype=np.float64)[keep]
    if len(w) == 0:
        return out
    qx0, qy0, qx1, qy1 = w[:, 0], w[:, 1], w[:, 2], w[:, 3]
    ex, ey = qx1 - qx0, qy1 - qy0
    # side of the source w.r.t. each wall line; receivers must be on the other side. Folding the source's
    # sign into the receiver's side function makes "other side" a plain "< 0".
    side_src = np.sign(_cross(ex, ey, sx - qx0, sy - qy0))  # (m,)
    ka, kb, kc = -ey * side_src, ex * side_src, (ey * qx0 - ex * qy0) * side_src
    # o(Q) = cross(P - S, Q - S) = Px (Qy - Sy) - Py (Qx - Sx) + (Sy Qx - Sx Qy)  (linear in P)
    u0, v0, c0 = qy0 - sy, qx0 - sx, sy * qx0 - sx * qy0
    u1, v1, c1 = qy1 - sy, qx1 - sx, sy * qx1 - sx * qy1
    # receivers sorted by bearing from the source: a chunk then spans a narrow wedge, and only the walls
    # whose bearing interval overlaps it (and that are not beyond its farthest receiver) are tested
    bearing = np.arctan2(pts[:, 1] - sy, pts[:, 0] - sx)
    order = np.argsort(bearing, kind="stable")
    rng_p = np.hypot(pts[:, 0] - sx, pts[:, 1] - sy)
    b0 = np.arctan2(qy0 - sy, qx0 - sx)
    span = (np.arctan2(qy1 - sy, qx1 - sx) - b0 + np.pi) % (2 * np.pi) - np.pi
    w_lo = np.where(span >= 0, b0, b0 + span)
    w_width = np.abs(span)
    # distance from the source to each wall segment
    tt = np.clip(((sx - qx0) * ex + (sy - qy0) * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
    w_dist = np.hypot(qx0 + tt * ex - sx, qy0 + tt * ey - sy)
    f32 = np.float32
    coef = np.stack([ka, kb, kc, u0, v0, c0, u1, v1, c1]).astype(f32)  # (9, m)
    a32 = a.astype(f32)
    p32 = pts.astype(f32)
    for s in range(0, n, chunk):
        idx = order[s:s + chunk]
        lo, hi = bearing[idx[0]], bearing[idx[-1]]
        sel = w_dist <= rng_p[idx].max()
        ov = np.zeros(len(w), dtype=bool)
        for shift in (-2 * np.pi, 0.0, 2 * np.pi):
            ov |= (w_lo + shift <= hi) & (w_lo + shift + w_width >= lo)
        sel &= ov & (side_src != 0)
        if not sel.any():
            continue
        ka_, kb_, kc_, u0_, v0_, c0_, u1_, v1_, c1_ = coef[:, sel]
        px = p32[idx, 0:1]
        py = p32[idx, 1:2]
        hit = px * ka_ + py * kb_ + kc_ < 0
        o1 = px * u0_ - py * v0_ + c0_
        o1 *= px * u1_ - py * v1_ + c1_
        hit &= o1 < 0
        out[idx] = hit @ a32[sel]
    return out
