"""Walks that change floor in the synthetic building, by the stairs or the lift, and every walk's barometer.

The stairs and the lift stand where the map walks of every floor pass most (the same x, y on each floor).
Two map walks of adjacent floors that both pass one of them swap their parts after it: one walks its own
floor up to it, climbs (or rides) and carries on as the other walk did on the floor above; the other comes
down. The stairs are two flights of :data:`STAIR_STEPS` steps with a landing; the lift is a wait, a ride at
:data:`LIFT_SPEED_MPS` and no steps. The dead-reckoned steps of the climb are the true ones with the walk's
usual errors; the walk keeps the head's phone (its Wi-Fi is drawn anew, :mod:`rmbuild.synthetic.building`)
and gets a scan gap while it climbs.

The barometer gives a reading with every step: a walk's own pressure at the ground (the weather and the
phone's offset), a weather trend, the height of the step's floor (:data:`M_PER_HPA`) and white noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.config.simulate import BuildingConfig

#: m; a walk "passes" the stairs / lift when one of its steps comes this close
PASS_M = 2.0
#: candidate places of the stairs and the lift (a subsample of the ground floor's steps)
MAX_CANDIDATES = 1500
#: m; the lift stands at least this far from the stairs
LIFT_FROM_STAIRS_M = 10.0
#: steps per flight of stairs (a 3.5 m storey: 20 risers of 17.5 cm, one per step) and per landing
STAIR_STEPS, LANDING_STEPS = 10, 2
#: s per step on stairs (stair climbing cadence ~1.5-1.7 Hz)
STAIR_STEP_S = 0.62
#: m; a flight's run (10 treads of 28 cm) and the landing's width
FLIGHT_M, LANDING_M = 2.8, 1.2
#: s; waiting for the lift (uniform), doors and acceleration; m/s cruise speed (low-rise passenger lifts 1 m/s)
LIFT_WAIT_S, LIFT_DOORS_S, LIFT_SPEED_MPS = (5.0, 25.0), 6.0, 1.0
#: m per hPa of the simulated air (hypsometric slope at 1,000 hPa, 15 °C); the detector assumes 8.4
M_PER_HPA = 8.3
#: hPa; a walk's ground-floor pressure (weather and phone offsets), uniform
P0_HPA = (990.0, 1030.0)
#: relative 1-sigma of a climbing step's dead-reckoned length; rad of its heading change
CLIMB_LEN_SD, CLIMB_HEADING_SD = 0.03, 0.02


@dataclass
class Swap:
    """Walks ``a`` (floor ``k``, step ``i``) and ``b`` (floor ``k + 1``, step ``j``) pass ``kind`` ("stairs"
    / "lift") at ``xy``: they swap their parts after it."""

    a: str
    i: int
    b: str
    j: int
    k: int
    kind: str
    xy: np.ndarray


def transition_points(truth: list[pd.DataFrame], map_walks: list[set[str]]) -> dict[str, np.ndarray]:
    """{"stairs": xy, "lift": xy}: the points passed by the most map walks of the floor passed least."""
    from scipy.spatial import cKDTree

    cand = truth[0][["x_m", "y_m"]].to_numpy(float)
    cand = cand[::max(1, len(cand) // MAX_CANDIDATES)]
    score = np.full(len(cand), np.inf)
    for tp, walks in zip(truth, map_walks, strict=True):
        wid = tp["walk_id"].astype(str).to_numpy()
        near = cKDTree(tp[["x_m", "y_m"]].to_numpy(float)).query_ball_point(cand, PASS_M)
        n = np.array([len({w for w in wid[row] if w in walks}) for row in near])
        score = np.minimum(score, n)
    stairs = int(np.argmax(score))
    far = np.hypot(*(cand - cand[stairs]).T) >= LIFT_FROM_STAIRS_M
    lift = int(np.argmax(np.where(far, score, -1)))
    return {"stairs": cand[stairs], "lift": cand[lift]}


def choose_swaps(truth: list[pd.DataFrame], map_walks: list[set[str]], points: dict[str, np.ndarray],
                 per_pair: int, rng: np.random.Generator) -> list[Swap]:
    """Up to ``per_pair // 2`` swaps per pair of adjacent floors, stairs and lift in turn; a walk in one at
    most."""
    used: set[str] = set()
    out = []
    for k in range(len(truth) - 1):
        for s in range(per_pair // 2):
            kind = ("stairs", "lift")[s % 2]
            a = _passing(truth[k], map_walks[k] - used, points[kind], rng)
            b = _passing(truth[k + 1], map_walks[k + 1] - used, points[kind], rng)
            if a is None or b is None:
                continue
            used |= {a[0], b[0]}
            out.append(Swap(a[0], a[1], b[0], b[1], k, kind, points[kind]))
    return out


def _passing(tp: pd.DataFrame, walks: set[str], xy: np.ndarray, rng: np.random.Generator) -> tuple[str, int] | None:
    """A random walk of ``walks`` passing ``xy`` away from its ends, and its step closest to it."""
    found = []
    for w in sorted(walks):
        p = tp[tp["walk_id"] == w][["x_m", "y_m"]].to_numpy(float)
        d = np.hypot(*(p - xy).T)
        inner = np.arange(len(p))[10:-10]
        if len(inner) and d[inner].min() <= PASS_M:
            found.append((w, int(inner[np.argmin(d[inner])])))
    return found[int(rng.integers(len(found)))] if found else None


def climb(start: np.ndarray, end: np.ndarray, sw: Swap, up: bool, storey_m: float,
          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The true steps between a head's last step ``start`` and a tail's first ``end`` (x, y): (xy (n, 2),
    time after the head's last step (n,) s, height above the lower floor (n,) m, index of the first step on
    the new floor (n: the tail's first step))."""
    if sw.kind == "stairs":
        u, v = np.array([1.0, 0.0]), np.array([0.0, 1.0])
        knots = [start, sw.xy + FLIGHT_M * u, sw.xy + FLIGHT_M * u + LANDING_M * v, end]
        legs = [_leg(knots[0], knots[1], STAIR_STEPS), _leg(knots[1], knots[2], LANDING_STEPS),
                _leg(knots[2], knots[3], STAIR_STEPS)]
        xy = np.vstack(legs)
        rise = np.r_[np.arange(1, STAIR_STEPS + 1) / STAIR_STEPS * 0.5, np.full(LANDING_STEPS, 0.5),
                     0.5 + np.arange(1, STAIR_STEPS + 1) / STAIR_STEPS * 0.5]
        t = STAIR_STEP_S * np.arange(1, len(xy) + 1)
        first_new = STAIR_STEPS  # the first step at half the storey (the landing)
    else:
        xy = np.vstack([_leg(start, sw.xy, 2), _leg(sw.xy, end, 2)])
        ride = float(rng.uniform(*LIFT_WAIT_S)) + LIFT_DOORS_S + storey_m / LIFT_SPEED_MPS
        t = 0.6 * np.arange(1, 5) + np.r_[0.0, 0.0, ride, ride]
        rise = np.r_[0.0, 0.0, 1.0, 1.0]
        first_new = 2
    h = storey_m * (rise if up else 1.0 - rise)
    return xy, t, h, first_new


def _leg(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    return a + (b - a) * (np.arange(1, n + 1) / n)[:, None]


def increments(x: np.ndarray, y: np.ndarray, th: np.ndarray) -> np.ndarray:
    """(n - 1, 3) body-frame increments (forward, left, heading change) between consecutive poses."""
    dx, dy = np.diff(x), np.diff(y)
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, np.diff(th)])


def integrate(start: np.ndarray, inc: np.ndarray) -> np.ndarray:
    """(n, 3) poses after each body-frame increment from ``start`` (x, y, heading)."""
    out = np.zeros((len(inc), 3))
    x, y, th = (float(v) for v in start)
    for k, (f, lft, dth) in enumerate(inc):
        x += np.cos(th) * f - np.sin(th) * lft
        y += np.sin(th) * f + np.cos(th) * lft
        th += dth
        out[k] = (x, y, th)
    return out


def noisy(inc: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Dead-reckoning errors on climbing steps' true increments."""
    out = inc.copy()
    out[:, :2] *= 1.0 + rng.normal(0.0, CLIMB_LEN_SD, (len(inc), 1))
    out[:, 2] += rng.normal(0.0, CLIMB_HEADING_SD, len(inc))
    return out


def pressure(t_s: np.ndarray, h_m: np.ndarray, cfg: BuildingConfig, rng: np.random.Generator) -> np.ndarray:
    """One walk's barometer at its steps (hPa): ground pressure, weather trend, height, noise."""
    p0 = float(rng.uniform(*P0_HPA))
    trend = float(rng.normal(0.0, cfg.baro_drift_hpa_per_h)) / 3600.0
    t = np.asarray(t_s, float)
    return p0 + trend * (t - t[0]) - np.asarray(h_m, float) / M_PER_HPA + rng.normal(0.0, cfg.baro_noise_hpa, len(t))


def glue(head: dict[str, pd.DataFrame], i: int, tail: dict[str, pd.DataFrame], j: int, sw: Swap, up: bool,
         storey_m: float, rng: np.random.Generator) -> tuple[dict[str, pd.DataFrame], dict]:
    """``head``'s walk up to step ``i``, the climb, ``tail``'s walk from step ``j``: its tables ("poses",
    "truth" with floor index ``k`` and height ``h_m``, "fixes", "scans" (t_s)) under the head's id, and the
    truth of its floor change."""
    hp, ht, tp, tt = head["poses"], head["truth"], tail["poses"], tail["truth"]
    hxy, txy = ht[["x_m", "y_m"]].to_numpy(float), tt[["x_m", "y_m"]].to_numpy(float)
    xy, dt, h, first_new = climb(hxy[i], txy[j], sw, up, storey_m, rng)
    steps = np.diff(np.vstack([hxy[i], xy]), axis=0)
    th = np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))
    path = np.column_stack([xy, th])
    ends = np.vstack([ht[["x_m", "y_m", "heading_rad"]].to_numpy(float)[i], path,
                      tt[["x_m", "y_m", "heading_rad"]].to_numpy(float)[j]])
    inc = np.vstack([noisy(increments(*ends.T), rng),
                     increments(*tp[["x_m", "y_m", "heading_rad"]].to_numpy(float)[j:].T)])
    own0 = hp[["x_m", "y_m", "heading_rad"]].to_numpy(float)[i]
    own = np.vstack([hp[["x_m", "y_m", "heading_rad"]].to_numpy(float)[:i + 1], integrate(own0, inc)])
    t_i = float(hp["t_s"].iloc[i])
    shift = t_i + float(dt[-1]) + 0.6 - float(tp["t_s"].iloc[j])
    t_all = np.r_[hp["t_s"].to_numpy(float)[:i + 1], t_i + dt, tp["t_s"].to_numpy(float)[j:] + shift]
    t = np.asarray(np.round(t_all, 3), dtype=float)
    n_path, n_tail = len(xy), len(tp) - j
    mag = bool(np.isfinite(hp["yaw_abs_rad"].to_numpy(float)).any())

    def cat(col: str, mid: float) -> np.ndarray:
        tail_v = tp[col].to_numpy(float)[j:] if mag or not col.startswith("yaw") else np.full(n_tail, np.nan)
        return np.r_[hp[col].to_numpy(float)[:i + 1], np.full(n_path, mid), tail_v]

    wid = str(hp["walk_id"].iloc[0])
    poses = pd.DataFrame({"walk_id": wid, "t_s": t, "x_m": own[:, 0], "y_m": own[:, 1], "heading_rad": own[:, 2],
                          "yaw_abs_rad": cat("yaw_abs_rad", np.nan), "yaw_abs_sigma_rad": cat("yaw_abs_sigma_rad",
                                                                                              np.nan),
                          "step_freq_hz": cat("step_freq_hz", round(1.0 / STAIR_STEP_S, 4))})
    k_h, k_t = int(ht["k"].iloc[0]), int(tt["k"].iloc[0])
    k_path = np.where(np.arange(n_path) < first_new, k_h, k_t)
    truth = pd.DataFrame({"walk_id": wid, "t_s": t, "x_m": np.r_[hxy[:i + 1, 0], xy[:, 0], txy[j:, 0]],
                          "y_m": np.r_[hxy[:i + 1, 1], xy[:, 1], txy[j:, 1]],
                          "heading_rad": np.r_[ht["heading_rad"].to_numpy(float)[:i + 1], th,
                                               tt["heading_rad"].to_numpy(float)[j:]],
                          "k": np.r_[np.full(i + 1, k_h), k_path, np.full(n_tail, k_t)],
                          "h_m": np.r_[np.full(i + 1, k_h * storey_m), min(k_h, k_t) * storey_m + h,
                                       np.full(n_tail, k_t * storey_m)]})
    t_j = float(tp["t_s"].iloc[j])
    fixes = pd.concat([head["fixes"][head["fixes"]["t_s"] <= t_i],
                       tail["fixes"][tail["fixes"]["t_s"] >= t_j].assign(t_s=lambda d: np.round(d["t_s"] + shift, 3))],
                      ignore_index=True).assign(walk_id=wid)
    scans = np.r_[head["scans"][head["scans"] <= t_i], np.round(tail["scans"][tail["scans"] >= t_j] + shift, 3)]
    change = {"walk_id": wid, "kind": sw.kind, "from": k_h, "to": k_t, "step": i + 1 + first_new,
              "t_s": float(t[i + 1 + first_new])}
    return {"poses": poses, "truth": truth, "fixes": fixes, "scans": scans}, change
