"""Walkers: routes on the navigation graph, true step-by-step poses, foot-IMU dead reckoning in the walk's
own frame, and magnetometer heading observations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from rmbuild.config.simulate import ImuConfig, MagnetometerConfig, WalkersConfig
from rmbuild.geometry import wrap
from rmbuild.synthetic.venue import CORRIDOR, DOOR, HALL, JUNCTION, ROOM, Venue


@dataclass
class User:
    user_id: str
    alpha: float  # m/Hz, step model S = alpha f + beta
    beta: float  # m
    freq_hz: float  # mean step frequency


class Router:
    """Shortest paths on the venue's navigation graph, with per-walk perturbed edge weights."""

    def __init__(self, venue: Venue) -> None:
        self.venue = venue
        e = venue.nav_edges
        self.n = len(venue.nav_xy)
        self.length = np.hypot(*(venue.nav_xy[e[:, 0]] - venue.nav_xy[e[:, 1]]).T)
        kind = venue.nav_kind
        self.rooms = np.flatnonzero(kind == ROOM)
        self.open_places = np.flatnonzero(np.isin(kind, [CORRIDOR, JUNCTION, HALL]))

    def graph(self, rng: np.random.Generator) -> sp.csr_matrix:
        e = self.venue.nav_edges
        w = self.length * rng.uniform(1.0, 1.3, size=len(e)) + 1e-6
        g = sp.coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                          shape=(self.n, self.n))
        return g.tocsr()

    @staticmethod
    def path(g: sp.csr_matrix, a: int, b: int) -> list[int]:
        """Node sequence from a to b (both included); [a] when unreachable."""
        _, pred = dijkstra(g, directed=False, indices=a, return_predecessors=True)
        if pred[b] < 0 and a != b:
            return [a]
        out = [b]
        while out[-1] != a:
            out.append(int(pred[out[-1]]))
        return out[::-1]


def _cut_corners(pts: np.ndarray, radius: float, iterations: int = 2) -> np.ndarray:
    """Round a polyline's corners by replacing each interior vertex with two points on its segments."""
    for _ in range(iterations):
        if len(pts) < 3:
            return pts
        seg = np.diff(pts, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        out = [pts[0]]
        for i in range(1, len(pts) - 1):
            la, lb = seg_len[i - 1], seg_len[i]
            if la < 1e-9 or lb < 1e-9:
                out.append(pts[i])
                continue
            ra, rb = min(radius, la / 3), min(radius, lb / 3)
            out.append(pts[i] - seg[i - 1] / la * ra)
            out.append(pts[i] + seg[i] / lb * rb)
        out.append(pts[-1])
        pts = np.array(out)
    return pts


def _jitter_node(venue: Venue, node: int, cfg: WalkersConfig, rng: np.random.Generator) -> np.ndarray:
    xy = venue.nav_xy[node].copy()
    kind = venue.nav_kind[node]
    j = cfg.waypoint_jitter_m
    if kind == DOOR:
        return xy
    if kind == ROOM:
        room = next(r for r in venue.rooms if r.get("node") == node)
        x0, y0, x1, y1 = room["rect"]
        return np.array([rng.uniform(x0 + 1.5, max(x0 + 1.5, x1 - 1.5)),
                         rng.uniform(y0 + 1.5, max(y0 + 1.5, y1 - 1.5))])
    if kind == HALL:
        j = 1.5
    return xy + rng.uniform(-j, j, size=2)


def plan_route(
    venue: Venue, router: Router, cfg: WalkersConfig, kind: str, length_m: float, rng: np.random.Generator
) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """A walkable polyline (k, 2) of at least ``length_m`` (when the graph allows) and the pauses
    (arc length m, duration s) along it. ``kind``: "long", "short" or "end_to_end"."""
    g = router.graph(rng)
    if kind == "end_to_end":
        along_x = [c for c in venue.corridors if c[2] - c[0] > c[3] - c[1]]
        longest = max(along_x, key=lambda c: c[2] - c[0])
        yc = 0.5 * (longest[1] + longest[3])
        on_line = np.flatnonzero(np.abs(venue.nav_xy[:, 1] - yc) < 1e-6)
        x_line = venue.nav_xy[on_line, 0]
        ends = [int(on_line[np.argmin(x_line)]), int(on_line[np.argmax(x_line)])]
        if rng.random() < 0.5:
            ends = ends[::-1]
        nodes = router.path(g, ends[0], ends[1])
        pts = np.array([_jitter_node(venue, n, cfg, rng) for n in nodes])
        return _cut_corners(pts, 1.0), []
    places = router.open_places
    cur = int(places[rng.integers(len(places))])
    seq = [cur]
    pauses_at: list[tuple[int, float]] = []  # (index in seq, duration)
    total = 0.0
    failures = 0
    while total < length_m and failures < 1000:  # the guard only matters for a disconnected graph
        if kind == "long" and len(router.rooms) and rng.random() < cfg.room_visit_prob:
            dest = int(router.rooms[rng.integers(len(router.rooms))])
        else:
            dest = int(places[rng.integers(len(places))])
        p = router.path(g, cur, dest) if dest != cur else [cur]
        if len(p) < 2:
            failures += 1
            continue
        seg = venue.nav_xy[p]
        total += float(np.hypot(*np.diff(seg, axis=0).T).sum())
        seq.extend(p[1:])
        cur = dest
        if kind == "long" and rng.random() < cfg.pause_prob:
            pauses_at.append((len(seq) - 1, float(rng.uniform(*cfg.pause_s))))
    pts = np.array([_jitter_node(venue, n, cfg, rng) for n in seq])
    # arc length of each pause vertex (before corner cutting: close enough)
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    pauses = [(float(arc[i]), d) for i, d in pauses_at]
    return _cut_corners(pts, 1.0), pauses


def walk_route(
    route: np.ndarray,
    pauses: list[tuple[float, float]],
    n_steps: int,
    user: User,
    wcfg: WalkersConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """True per-step motion along ``route``: times (n+1,), positions (n+1, 2), headings (n+1,), step
    frequencies (n+1,), and interpolation knots (times, positions) that hold the position during pauses.
    The walk is cut short if the route ends first."""
    f_walk = user.freq_hz + rng.normal(0.0, wcfg.step_freq_walk_sd_hz)
    e = np.empty(n_steps)
    prev = 0.0
    innov = rng.normal(0.0, wcfg.step_freq_step_sd_hz * np.sqrt(1 - 0.95**2), size=n_steps)
    for k in range(n_steps):
        prev = 0.95 * prev + innov[k]
        e[k] = prev
    f = np.clip(f_walk + e, 1.0, 3.0)
    step_len = np.maximum(user.alpha * f + user.beta, 0.2)
    seg = np.diff(route, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    keep = seg_len > 1e-9
    route = np.vstack([route[:1], route[1:][keep]])
    seg, seg_len = seg[keep], seg_len[keep]
    arc = np.r_[0.0, np.cumsum(seg_len)]
    s = np.r_[0.0, np.cumsum(step_len)]
    n = int(np.searchsorted(s, arc[-1], side="right"))  # poses that fit on the route
    s, f = s[:n], np.r_[f[0], f][:n]
    x = np.interp(s, arc, route[:, 0])
    y = np.interp(s, arc, route[:, 1])
    si = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(seg) - 1)
    tan = seg[si] / seg_len[si, None]
    # lateral offset: per-walk constant + smooth AR(1) wiggle, clipped to stay inside door openings
    rho = 0.9
    w = rng.normal(0.0, wcfg.wiggle_sd_m * np.sqrt(1 - rho**2), size=n)
    wig = np.empty(n)
    prev = rng.normal(0.0, wcfg.wiggle_sd_m)
    for k in range(n):
        prev = rho * prev + w[k]
        wig[k] = prev
    off = np.clip(rng.uniform(-wcfg.lateral_offset_m, wcfg.lateral_offset_m) + wig, -0.5, 0.5)
    xy = np.c_[x - off * tan[:, 1], y + off * tan[:, 0]]
    d = np.diff(xy, axis=0)
    heading = np.r_[0.0, np.arctan2(d[:, 1], d[:, 0])]
    heading[0] = heading[1] if n > 1 else 0.0
    if wcfg.start_facing == "random":
        heading[0] = rng.uniform(-np.pi, np.pi)
    dt = np.r_[0.0, 1.0 / f[1:]]
    pause = np.zeros(n)
    for arc_p, dur in pauses:
        k = int(np.searchsorted(s, arc_p, side="left"))
        if 1 <= k < n:
            pause[k] += dur
    t = np.cumsum(dt + pause)
    moving = pause > 0
    knot_t = np.r_[t, (t - dt)[moving]]
    knot_xy = np.r_[xy, np.roll(xy, 1, axis=0)[moving]]
    order = np.argsort(knot_t, kind="stable")
    return t, xy, heading, f, knot_t[order], knot_xy[order]


def dead_reckon(
    t: np.ndarray, xy: np.ndarray, heading: np.ndarray, icfg: ImuConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Foot-IMU dead reckoning in the walk's own frame: (n, 2) positions from (0, 0) and headings from 0.

    Errors: a per-walk step-length scale, per-step length noise, and a heading error that integrates a
    random-walk gyro bias (over time, pauses included) plus per-step increment noise."""
    n = len(t)
    d = np.diff(xy, axis=0)
    true_len = np.hypot(d[:, 0], d[:, 1])
    scale = 1.0 + rng.normal(0.0, icfg.step_scale_sd)
    meas_len = np.maximum(true_len * scale + rng.normal(0.0, icfg.step_noise_m, size=n - 1), 0.0)
    dt = np.diff(t)
    bias0 = np.deg2rad(rng.normal(0.0, icfg.heading_bias_sd_dps))
    bias_rw = np.deg2rad(icfg.heading_bias_rw_dps) * np.sqrt(dt) * rng.standard_normal(n - 1)
    bias = bias0 + np.cumsum(bias_rw)
    step_noise = np.deg2rad(icfg.heading_step_noise_deg) * rng.standard_normal(n - 1)
    eps = np.r_[0.0, np.cumsum(bias * dt + step_noise)]
    own_heading = wrap(heading - heading[0] + eps)
    own_heading[0] = 0.0
    steps = meas_len[:, None] * np.c_[np.cos(own_heading[1:]), np.sin(own_heading[1:])]
    own_xy = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return own_xy, own_heading


class MagneticField:
    """Spatially smooth indoor disturbance of the magnetometer heading (rad), with amplified hot spots."""

    def __init__(self, cfg: MagnetometerConfig, venue: Venue, rng: np.random.Generator, n_features: int = 64):
        self.cfg = cfg
        self.omega = rng.normal(0.0, 1.0 / cfg.disturbance_corr_m, size=(n_features, 2))
        self.phase = rng.uniform(0.0, 2 * np.pi, size=n_features)
        self.weight = rng.standard_normal(n_features)
        self.hot_xy = np.c_[rng.uniform(0, venue.width_m, cfg.n_hotspots),
                            rng.uniform(0, venue.height_m, cfg.n_hotspots)]

    def disturbance_rad(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        base = np.cos(xy @ self.omega.T + self.phase) @ self.weight * np.sqrt(2.0 / len(self.weight))
        gain = np.ones(len(xy))
        for hx, hy in self.hot_xy:
            r2 = (xy[:, 0] - hx) ** 2 + (xy[:, 1] - hy) ** 2
            gain += self.cfg.hotspot_gain * np.exp(-0.5 * r2 / self.cfg.hotspot_radius_m**2)
        return np.deg2rad(self.cfg.disturbance_sd_deg) * base * gain

    def observe(self, xy: np.ndarray, heading: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured absolute heading (rad, wrapped) along one walk."""
        c = self.cfg
        offset = np.deg2rad(c.north_offset_deg + rng.normal(0.0, c.walk_offset_sd_deg))
        noise = np.deg2rad(c.noise_sd_deg) * rng.standard_normal(len(heading))
        return wrap(heading + offset + self.disturbance_rad(xy) + noise)
