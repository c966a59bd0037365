"""The synthetic floor plan: corridors, rooms with doors, an open hall with kiosks, walls with attenuation,
and the navigation graph walkers route on."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rmbuild.config.simulate import VenueConfig
from rmbuild.synthetic.geometry import segments_cross

# navigation node kinds
CORRIDOR, JUNCTION, DOOR, ROOM, HALL = "corridor", "junction", "door", "room", "hall"


@dataclass
class Venue:
    """A floor plan in the building frame (m, x east, y north, origin at the south-west corner).

    ``walls``: (m, 4) segments x0, y0, x1, y1; ``wall_atten_db``: (m,) loss of one crossing (2.4 GHz);
    ``wall_kind``: (m,) "corridor" / "partition" / "kiosk" / "outer". ``nav_xy``: (N, 2) navigation nodes,
    ``nav_kind``: (N,) their kinds, ``nav_edges``: (E, 2) undirected edges that cross no wall.
    """

    width_m: float
    height_m: float
    walls: np.ndarray
    wall_atten_db: np.ndarray
    wall_kind: np.ndarray
    rooms: list[dict]
    corridors: list[list[float]]
    hall: list[float] | None
    kiosks: list[list[float]]
    nav_xy: np.ndarray
    nav_kind: np.ndarray
    nav_edges: np.ndarray
    landmark_xy: np.ndarray
    landmark_labels: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-able description for plots: bounds, walls with attenuation, rooms, hall, corridors."""
        r6 = lambda v: round(float(v), 6)  # noqa: E731
        return {
            "bounds": [0.0, 0.0, r6(self.width_m), r6(self.height_m)],
            "walls": [[r6(v) for v in w] for w in self.walls],
            "wall_atten_db": [r6(a) for a in self.wall_atten_db],
            "wall_kind": [str(k) for k in self.wall_kind],
            "rooms": [
                {"rect": [r6(v) for v in r["rect"]], "door": [r6(v) for v in r["door"]]} for r in self.rooms
            ],
            "hall": None if self.hall is None else [r6(v) for v in self.hall],
            "kiosks": [[r6(v) for v in k] for k in self.kiosks],
            "corridors": [[r6(v) for v in c] for c in self.corridors],
            "landmarks": [
                {"label": lab, "x_m": r6(x), "y_m": r6(y)}
                for lab, (x, y) in zip(self.landmark_labels, self.landmark_xy)
            ],
        }


def _wall_with_gaps(a: float, b: float, c: float, gaps: list[tuple[float, float]], horizontal: bool):
    """Pieces of the wall from a to b (along x if horizontal, at y = c; else along y at x = c) minus gaps."""
    pieces = []
    cur = a
    for g0, g1 in sorted(gaps):
        if g0 > cur + 1e-9:
            pieces.append((cur, g0))
        cur = max(cur, g1)
    if b > cur + 1e-9:
        pieces.append((cur, b))
    if horizontal:
        return [(p0, c, p1, c) for p0, p1 in pieces]
    return [(c, p0, c, p1) for p0, p1 in pieces]


class _Nodes:
    def __init__(self) -> None:
        self.xy: list[tuple[float, float]] = []
        self.kind: list[str] = []
        self._index: dict[tuple[float, float], int] = {}
        self.edges: list[tuple[int, int]] = []

    def add(self, x: float, y: float, kind: str) -> int:
        key = (round(x, 3), round(y, 3))
        i = self._index.get(key)
        if i is None:
            i = len(self.xy)
            self._index[key] = i
            self.xy.append((float(x), float(y)))
            self.kind.append(kind)
        elif kind == JUNCTION:
            self.kind[i] = JUNCTION
        return i

    def link(self, i: int, j: int) -> None:
        if i != j:
            self.edges.append((min(i, j), max(i, j)))


class _Walls:
    """Wall segments collected while the floor plan is drawn, with their attenuation and kind."""

    def __init__(self) -> None:
        self.segs: list[tuple[float, float, float, float]] = []
        self.atten: list[float] = []
        self.kind: list[str] = []

    def add(self, segs, a: float, k: str) -> None:
        for s in segs:
            x0, y0, x1, y1 = (float(v) for v in s)
            self.segs.append((x0, y0, x1, y1))
            self.atten.append(a)
            self.kind.append(k)


def build_venue(cfg: VenueConfig, rng: np.random.Generator) -> Venue:
    """Generate the floor plan of ``cfg`` (deterministic given ``rng``'s state)."""
    W, H, cw = cfg.width_m, cfg.height_m, cfg.corridor_width_m
    Wo = W - cfg.hall_width_m  # east edge of the office part
    walls = _Walls()
    ys, xs = _corridor_lines(cfg, Wo, rng)
    corridors = [[0.0, y - cw / 2, Wo, y + cw / 2] for y in ys]
    corridors += [[x - cw / 2, 0.0, x + cw / 2, H] for x in xs]
    rooms = _office_rooms(cfg, Wo, ys, xs, walls, rng)
    # x corridors meeting the west outer wall are dead ends; at the east they open into the hall (or end)
    hall = [Wo, 0.0, W, H] if cfg.hall_width_m > 0 else None
    kiosks = _hall_kiosks(cfg, Wo, rng) if hall is not None else []
    for x0, y0, x1, y1 in kiosks:
        walls.add([(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)],
                  cfg.kiosk_atten_db, "kiosk")
    walls.add([(0, 0, W, 0), (W, 0, W, H), (W, H, 0, H), (0, H, 0, 0)], cfg.outer_wall_atten_db, "outer")
    walls_arr = np.array(walls.segs, dtype=np.float64).reshape(-1, 4)

    nodes = _Nodes()
    _corridor_chains(nodes, cfg, Wo, ys, xs, hall is not None)
    _door_nodes(nodes, ys, rooms)
    if hall is not None:
        _hall_grid(nodes, cfg, Wo, ys, kiosks)
    nav_xy = np.array(nodes.xy, dtype=np.float64)
    edges = np.array(sorted(set(nodes.edges)), dtype=np.int64).reshape(-1, 2)
    if len(edges):
        blocked = segments_cross(nav_xy[edges[:, 0]], nav_xy[edges[:, 1]], walls_arr).any(axis=1)
        edges = edges[~blocked]
    nav_kind = np.array(nodes.kind, dtype=object)
    lm = _landmark_nodes(cfg, nav_xy, nav_kind, rng)

    return Venue(
        width_m=W, height_m=H, walls=walls_arr, wall_atten_db=np.array(walls.atten, dtype=np.float64),
        wall_kind=np.array(walls.kind, dtype=object), rooms=rooms, corridors=corridors, hall=hall, kiosks=kiosks,
        nav_xy=nav_xy, nav_kind=nav_kind, nav_edges=edges, landmark_xy=nav_xy[lm].reshape(-1, 2),
        landmark_labels=[f"L{i + 1:02d}" for i in range(len(lm))],
    )


def _corridor_lines(cfg: VenueConfig, Wo: float, rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """Centre lines of the x corridors (their y) and the y corridors (their x), slightly jittered off the
    regular grid."""
    cw = cfg.corridor_width_m
    band = cfg.height_m / cfg.n_x_corridors
    ys = [band * (i + 0.5) for i in range(cfg.n_x_corridors)]
    if cfg.n_x_corridors > 1:
        slack = max(0.0, min(2.0, (band - cw - 2 * cfg.min_room_depth_m) / 2))
        ys = [y + rng.uniform(-slack, slack) for y in ys]
    xs: list[float] = []
    if cfg.n_y_corridors > 0:
        step = Wo / (cfg.n_y_corridors + 1)
        slack = max(0.0, min(3.0, (step - cw - 2.0) / 2))
        xs = [step * (j + 1) + rng.uniform(-slack, slack) for j in range(cfg.n_y_corridors)]
    return ys, xs


def _office_rooms(cfg: VenueConfig, Wo: float, ys: list[float], xs: list[float], walls: _Walls,
                  rng: np.random.Generator) -> list[dict]:
    """The office cells between corridors, filled with rows of rooms (their walls go to ``walls``)."""
    cw = cfg.corridor_width_m
    x_edges = [0.0] + [v for x in xs for v in (x - cw / 2, x + cw / 2)] + [Wo]
    y_edges = [0.0] + [v for y in ys for v in (y - cw / 2, y + cw / 2)] + [cfg.height_m]
    rooms: list[dict] = []
    for ci in range(0, len(x_edges), 2):
        for cj in range(0, len(y_edges), 2):
            rooms += _office_cell(cfg, (x_edges[ci], y_edges[cj], x_edges[ci + 1], y_edges[cj + 1]), walls, rng)
    return rooms


def _office_cell(cfg: VenueConfig, cell: tuple[float, float, float, float], walls: _Walls,
                 rng: np.random.Generator) -> list[dict]:
    """One office cell: its corridor walls (with a door per room), and one or two rows of rooms."""
    xa, ya, xb, yb = cell
    bottom_corr, top_corr = ya > 0.0, yb < cfg.height_m
    if xa > 0.0:
        walls.add([(xa, ya, xa, yb)], cfg.corridor_wall_atten_db, "corridor")
    if xb < cfg.width_m:  # a y corridor or the hall on the east side
        walls.add([(xb, ya, xb, yb)], cfg.corridor_wall_atten_db, "corridor")
    if bottom_corr and top_corr and yb - ya >= 2 * cfg.min_room_depth_m:
        ym = 0.5 * (ya + yb)
        rows = [(ya, ym, -1), (ym, yb, +1)]
        walls.add([(xa, ym, xb, ym)], cfg.partition_atten_db, "partition")
    elif bottom_corr:
        rows = [(ya, yb, -1)]
    else:
        rows = [(ya, yb, +1)]
    gaps: dict[int, list[tuple[float, float]]] = {-1: [], +1: []}
    rooms: list[dict] = []
    for r0, r1, facing in rows:
        n = max(1, int(round((xb - xa) / cfg.room_width_m)))
        edges = np.linspace(xa, xb, n + 1)
        for k in range(n):
            x0, x1 = float(edges[k]), float(edges[k + 1])
            if k > 0:
                walls.add([(x0, r0, x0, r1)], cfg.partition_atten_db, "partition")
            dw = cfg.door_width_m
            lo, hi = x0 + 0.4 + dw / 2, x1 - 0.4 - dw / 2
            xd = float(rng.uniform(lo, hi)) if hi > lo else 0.5 * (x0 + x1)
            yd = r0 if facing < 0 else r1
            gaps[facing].append((xd - dw / 2, xd + dw / 2))
            rooms.append({"rect": [x0, r0, x1, r1], "door": [xd, yd], "facing": facing})
    if bottom_corr:
        walls.add(_wall_with_gaps(xa, xb, ya, gaps[-1], True), cfg.corridor_wall_atten_db, "corridor")
    if top_corr:
        walls.add(_wall_with_gaps(xa, xb, yb, gaps[+1], True), cfg.corridor_wall_atten_db, "corridor")
    return rooms


def _hall_kiosks(cfg: VenueConfig, Wo: float, rng: np.random.Generator) -> list[list[float]]:
    """Kiosks (x0, y0, x1, y1) placed at random in the hall, at least 4 m from each other and the walls."""
    W, H = cfg.width_m, cfg.height_m
    kiosks: list[list[float]] = []
    for _ in range(cfg.n_hall_kiosks):
        for _try in range(200):
            sx, sy = rng.uniform(3.0, 5.0, size=2)
            kx = rng.uniform(Wo + 4.0, W - 4.0 - sx)
            ky = rng.uniform(4.0, H - 4.0 - sy)
            ok = all(
                kx > k[2] + 4.0 or kx + sx < k[0] - 4.0 or ky > k[3] + 4.0 or ky + sy < k[1] - 4.0
                for k in kiosks
            )
            if ok:
                kiosks.append([float(kx), float(ky), float(kx + sx), float(ky + sy)])
                break
    return kiosks


def _corridor_chains(nodes: _Nodes, cfg: VenueConfig, Wo: float, ys: list[float], xs: list[float],
                     has_hall: bool) -> None:
    """Navigation nodes along every corridor's centre line (ends and junctions), linked in order."""
    half = cfg.corridor_width_m / 2
    x_end = Wo if has_hall else cfg.width_m - half
    for y in ys:
        stops = {round(half, 6): CORRIDOR, round(x_end, 6): CORRIDOR}
        for x in xs:
            stops[round(x, 6)] = JUNCTION
        ids = [nodes.add(x, y, k) for x, k in sorted(stops.items())]
        for a, b in zip(ids[:-1], ids[1:]):
            nodes.link(a, b)
    for x in xs:
        stops = {round(half, 6): CORRIDOR, round(cfg.height_m - half, 6): CORRIDOR}
        for y in ys:
            stops[round(y, 6)] = JUNCTION
        ids = [nodes.add(x, y, k) for y, k in sorted(stops.items())]
        for a, b in zip(ids[:-1], ids[1:]):
            nodes.link(a, b)


def _door_nodes(nodes: _Nodes, ys: list[float], rooms: list[dict]) -> None:
    """A corridor node opposite each door (split into its x corridor's chain), the door and the room
    centre, linked; each room gets its node id under ``"node"``."""
    split: dict[float, list[float]] = {y: [] for y in ys}
    for room in rooms:
        xd, yd = room["door"]
        yc = min(ys, key=lambda y: abs(y - yd))
        split[yc].append(xd)
    for y in ys:
        line = [i for i, (nx, ny) in enumerate(nodes.xy) if abs(ny - y) < 1e-6]
        xs_line = sorted({round(nodes.xy[i][0], 6) for i in line} | {round(x, 6) for x in split[y]})
        ids = [nodes.add(x, y, CORRIDOR) for x in xs_line]
        nodes.edges = [
            e for e in nodes.edges
            if not (abs(nodes.xy[e[0]][1] - y) < 1e-6 and abs(nodes.xy[e[1]][1] - y) < 1e-6)
        ]
        for a, b in zip(ids[:-1], ids[1:]):
            nodes.link(a, b)
    for room in rooms:
        xd, yd = room["door"]
        yc = min(ys, key=lambda y: abs(y - yd))
        c = nodes.add(xd, yc, CORRIDOR)
        d = nodes.add(xd, yd, DOOR)
        x0, y0, x1, y1 = room["rect"]
        r = nodes.add(0.5 * (x0 + x1), 0.5 * (y0 + y1), ROOM)
        room["node"] = r
        nodes.link(c, d)
        nodes.link(d, r)


def _hall_grid(nodes: _Nodes, cfg: VenueConfig, Wo: float, ys: list[float], kiosks: list[list[float]]) -> None:
    """A walkable grid over the hall (diagonals included, kiosks left out), each x corridor's east end
    linked to its three nearest grid nodes."""
    g = cfg.hall_grid_m
    gx = np.arange(Wo + g / 2, cfg.width_m - 1.0, g)
    gy = np.arange(g / 2, cfg.height_m - 1.0, g)
    grid: dict[tuple[int, int], int] = {}
    for i, x in enumerate(gx):
        for j, y in enumerate(gy):
            if any(k[0] - 1.0 < x < k[2] + 1.0 and k[1] - 1.0 < y < k[3] + 1.0 for k in kiosks):
                continue
            grid[(i, j)] = nodes.add(float(x), float(y), HALL)
    for (i, j), a in sorted(grid.items()):
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
            b = grid.get((i + di, j + dj))
            if b is not None:
                nodes.link(a, b)
    hall_ids = sorted(grid.values())
    hall_xy = np.array([nodes.xy[i] for i in hall_ids]).reshape(-1, 2)
    for y in ys:
        m = nodes.add(Wo, y, CORRIDOR)
        dist = np.hypot(hall_xy[:, 0] - Wo, hall_xy[:, 1] - y)
        for k in np.argsort(dist, kind="stable")[:3]:
            nodes.link(m, hall_ids[int(k)])


def _landmark_nodes(cfg: VenueConfig, nav_xy: np.ndarray, nav_kind: np.ndarray,
                    rng: np.random.Generator) -> list[int]:
    """Landmarks spread over junctions and hall nodes (corridor nodes too when those are too few) by
    farthest-point sampling from a random first one: their navigation node ids."""
    cand = np.flatnonzero(np.isin(nav_kind, [JUNCTION, HALL]))
    if len(cand) < cfg.n_landmarks:
        cand = np.flatnonzero(np.isin(nav_kind, [JUNCTION, HALL, CORRIDOR]))
    lm: list[int] = []
    if cfg.n_landmarks > 0 and len(cand):
        lm.append(int(cand[rng.integers(len(cand))]))
        dmin = np.hypot(*(nav_xy[cand] - nav_xy[lm[0]]).T)
        while len(lm) < min(cfg.n_landmarks, len(cand)):
            k = int(cand[int(np.argmax(dmin))])
            lm.append(k)
            dmin = np.minimum(dmin, np.hypot(*(nav_xy[cand] - nav_xy[k]).T))
    return lm


def plan_geojson(venue: dict) -> dict:
    """The floor plan of a venue (:meth:`Venue.to_dict`) as a GeoJSON FeatureCollection in local metres, as
    a venue operator would draw it: the bounds as the floor outline, the corridors and the hall as
    ``"walkable": true`` polygons, the rooms (offices, shops: walked into now and then) and the kiosks as
    units cut out of the walkable space."""

    def rect(r, **props) -> dict:
        x0, y0, x1, y1 = (round(float(v), 6) for v in r)
        ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
        return {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}}

    feats = [rect(venue["bounds"], type="floor")]
    feats += [rect(c, walkable=True, kind="corridor") for c in venue["corridors"]]
    if venue.get("hall") is not None:
        feats.append(rect(venue["hall"], walkable=True, kind="hall"))
    feats += [rect(r["rect"], kind="room") for r in venue["rooms"]]
    feats += [rect(k, kind="kiosk") for k in venue.get("kiosks", [])]
    return {"type": "FeatureCollection", "features": feats}
