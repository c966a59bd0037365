"""A floor plan: where people can walk, in the floor's own metric frame (no I/O; shapely for geometry).

A plan is the walkable space of one floor as polygons in local metres (x east, y north, the frame the map
is built in when a plan is given), optionally with the lon/lat of that frame (:class:`Georef`). It comes from
GeoJSON: either walkable units, or a floor outline whose other features (shops, rooms, obstacles) are cut
out of it. For fast look-ups it is rasterised into a signed distance field (metres to the walkable
boundary, negative inside).

GeoJSON in WGS84 is projected to local metres; the MS ILC 2.0 floors give their waypoints in metres over the
plan's bounding box instead (``floor_info.json``: width, height), so :func:`from_ilc` projects with Web
Mercator (EPSG:3857) and scales the outline's bounding box onto width × height.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from rmbuild import geometry
from rmbuild.limits import MAX_COORD_M, MAX_PLAN_SIZE_M, MAX_PLAN_VERTICES

# m; cell of the distance field
FIELD_RESOLUTION_M = 0.5
# cells; the distance field's resolution coarsens for a plan larger than this at FIELD_RESOLUTION_M (2 km at
# ~1 m: bounded memory for the largest plan accepted, MAX_PLAN_SIZE_M)
FIELD_MAX_CELLS = 4_000_000
# m; the field extends this far beyond the plan
FIELD_MARGIN_M = 20.0
# deg; a lon/lat plan spanning more than this (about 5 km) is no building: its coordinates must be metres
MAX_PLAN_SPAN_DEG = 0.05


@dataclass(frozen=True)
class Georef:
    """How the plan's metric frame maps to WGS84: ``kind`` "enu" (east/north metres about lon0, lat0) or
    "ilc" (Web Mercator over the lon/lat bounding box ``bbox`` = (lon_min, lat_min, lon_max, lat_max) scaled
    onto ``size_m`` = (width, height))."""

    kind: str
    lon0: float = 0.0
    lat0: float = 0.0
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    size_m: tuple[float, float] = (0.0, 0.0)

    def to_lonlat(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) lon/lat (deg) of local points (n, 2) [m]."""
        from pyproj import Transformer

        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.kind == "ilc":
            mx, my = self.to_web_mercator(xy).T
            lon, lat = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True).transform(mx, my)
            return np.c_[lon, lat]
        t = Transformer.from_pipeline(_enu_pipeline(self.lon0, self.lat0))
        lon, lat, _ = t.transform(xy[:, 0], xy[:, 1], np.zeros(len(xy)), direction="INVERSE")
        return np.c_[lon, lat]

    def to_web_mercator(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) Web Mercator (EPSG:3857) x, y [m] of local points (n, 2) [m]: the projected metres
        UJIIndoorLoc gives as LONGITUDE, LATITUDE."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.kind == "ilc":
            x0, y0, x1, y1 = _mercator_bbox(self.bbox)
            return np.c_[x0 + xy[:, 0] / self.size_m[0] * (x1 - x0), y0 + xy[:, 1] / self.size_m[1] * (y1 - y0)]
        from pyproj import Transformer

        lonlat = self.to_lonlat(xy)
        mx, my = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
        return np.c_[mx, my]


@dataclass
class FloorPlan:
    """Walkable space (shapely geometry, local metres), the floor outline, the obstacles cut out of it,
    the georeference (None for a plan given in local metres) and a name."""

    walkable: shapely.Geometry
    outline: shapely.Geometry
    obstacles: list = field(default_factory=list)
    georef: Georef | None = None
    name: str = ""
    _field: tuple | None = field(default=None, repr=False)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return tuple(self.outline.bounds)  # type: ignore[return-value]

    @property
    def area_m2(self) -> float:
        return float(self.walkable.area)

    def inside(self, xy: np.ndarray, tolerance_m: float = 0.0) -> np.ndarray:
        """bool (n,): points (n, 2) in walkable space (within ``tolerance_m`` of it)."""
        return self.distance(xy) <= tolerance_m

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """(n,) signed distance (m) of points (n, 2) to the walkable boundary, negative inside; bilinear in
        the distance field, clamped to the field's edge outside it."""
        grid, (ox, oy), res = self.distance_field()
        xy = np.asarray(xy, float).reshape(-1, 2)
        c = (xy[:, 0] - ox) / res
        r = (xy[:, 1] - oy) / res
        from scipy import ndimage  # imported here: ~0.4 s at import, and most runs use no plan

        return ndimage.map_coordinates(grid, [r, c], order=1, mode="nearest")

    def distance_field(self) -> tuple[np.ndarray, tuple[float, float], float]:
        """(grid (rows, cols) signed distance [m], origin (x, y) of cell (0, 0), resolution [m])."""
        if self._field is None:
            x0, y0, x1, y1 = self.bounds
            cells = (x1 - x0 + 2 * FIELD_MARGIN_M) * (y1 - y0 + 2 * FIELD_MARGIN_M) / FIELD_RESOLUTION_M**2
            res = FIELD_RESOLUTION_M * max(1.0, float(np.sqrt(cells / FIELD_MAX_CELLS)))
            self._field = _signed_distance(self.walkable, self.bounds, res, FIELD_MARGIN_M)
        return self._field


def from_features(features: list[dict], to_local, name: str = "") -> FloorPlan:
    """A plan from GeoJSON features (properties decide each polygon's role):

    - ``"walkable": true`` polygons, when there are any, make the walkable space, and every other polygon
      except the floor outline is an obstacle cut out of it;
    - otherwise the floor outline (the polygon with ``"type": "floor"``, else the first one) is walkable
      and every other polygon (shops, rooms, obstacles) is cut out of it.

    ``to_local``: maps an (n, 2) array of the GeoJSON's coordinates to local metres. ValueError for a vertex
    that is not finite or beyond :data:`MAX_COORD_M` in local metres, a plan wider than
    :data:`MAX_PLAN_SIZE_M`, or no walkable area.
    """
    polys = [(f.get("properties") or {}, _polygon(f["geometry"], to_local)) for f in features if f.get("geometry")
             and f["geometry"]["type"] in ("Polygon", "MultiPolygon")]
    if not polys:
        raise ValueError("no Polygon or MultiPolygon features")
    floor_i = next((i for i, (p, _) in enumerate(polys) if p.get("type") == "floor"), None)
    walkable = [g for p, g in polys if p.get("walkable") is True]
    if walkable:
        obstacles = [g for i, (p, g) in enumerate(polys) if p.get("walkable") is not True and i != floor_i]
        area = shapely.union_all(walkable)
        outline = shapely.union_all([area] + ([polys[floor_i][1]] if floor_i is not None else []))
    else:
        floor_i = floor_i if floor_i is not None else 0
        obstacles = [g for i, (_, g) in enumerate(polys) if i != floor_i]
        area = outline = polys[floor_i][1]
    w = shapely.difference(area, shapely.union_all(obstacles)) if obstacles else area
    x0, y0, x1, y1 = outline.bounds
    if max(x1 - x0, y1 - y0) > MAX_PLAN_SIZE_M:
        raise ValueError(f"the plan spans {x1 - x0:.6g} x {y1 - y0:.6g} m: at most {MAX_PLAN_SIZE_M:g} m on a side "
                         "(coordinates in metres?)")
    w = shapely.make_valid(w)
    if not w.area > 0:
        raise ValueError("the plan has no walkable area (its polygons are empty or degenerate)")
    return FloorPlan(w, outline, obstacles, None, name)


def check_vertex_count(features: list) -> None:
    """ValueError when the Polygon and MultiPolygon geometries of a user's GeoJSON ``features`` have more
    than :data:`MAX_PLAN_VERTICES` positions (counted before any polygon is built; other geometries are
    ignored, as :func:`from_features` ignores them)."""
    n = 0
    for f in features:
        g = f.get("geometry") if isinstance(f, dict) else None
        if not isinstance(g, dict) or g.get("type") not in ("Polygon", "MultiPolygon"):
            continue
        polys = g.get("coordinates") if g["type"] == "MultiPolygon" else [g.get("coordinates")]
        for poly in polys if isinstance(polys, list) else []:
            for ring in poly if isinstance(poly, list) else []:
                n += len(ring) if isinstance(ring, list) else 0
    if n > MAX_PLAN_VERTICES:
        raise ValueError(f"{n:,} vertices: at most {MAX_PLAN_VERTICES:,} in a floor plan")


def from_ilc(geojson: dict, width_m: float, height_m: float, name: str = "") -> FloorPlan:
    """An MS ILC 2.0 floor: lon/lat in Web Mercator, the outline's bounding box scaled onto width × height."""
    feats = geojson["features"]
    check_vertex_count(feats)
    outline = _polygon(feats[0]["geometry"], lambda a: a)
    b = [float(v) for v in outline.bounds]
    bbox = (b[0], b[1], b[2], b[3])
    ref = Georef("ilc", bbox=bbox, size_m=(float(width_m), float(height_m)))
    x0, y0, x1, y1 = _mercator_bbox(bbox)

    def to_local(lonlat: np.ndarray) -> np.ndarray:
        from pyproj import Transformer

        mx, my = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
        return np.c_[(np.asarray(mx) - x0) / (x1 - x0) * width_m, (np.asarray(my) - y0) / (y1 - y0) * height_m]

    plan = from_features([{**feats[0], "properties": {**(feats[0].get("properties") or {}), "type": "floor"}},
                          *feats[1:]], to_local, name)
    return FloorPlan(plan.walkable, plan.outline, plan.obstacles, ref, name)


def covered_share(plan: FloorPlan, centres: np.ndarray, cell_m: float) -> dict:
    """How much of the plan's walkable space square cells of ``cell_m`` at ``centres`` (n, 2) m cover:
    {"walkable_m2", "covered_m2" (the cells' union within walkable space), "share"}."""
    c = np.asarray(centres, float).reshape(-1, 2)
    h = cell_m / 2.0
    cells = shapely.union_all(shapely.box(c[:, 0] - h, c[:, 1] - h, c[:, 0] + h, c[:, 1] + h)) if len(c) else None
    walkable = float(plan.walkable.area)
    covered = 0.0 if cells is None else float(shapely.intersection(cells, plan.walkable).area)
    return {"walkable_m2": round(walkable, 1), "covered_m2": round(covered, 1),
            "share": round(covered / walkable, 4) if walkable > 0 else None}


def lonlat_to_enu(lon0: float, lat0: float):
    """A function (n, 2) lon/lat -> (n, 2) east/north metres about (lon0, lat0) on the WGS84 ellipsoid."""
    from pyproj import Transformer

    t = Transformer.from_pipeline(_enu_pipeline(lon0, lat0))

    def f(lonlat: np.ndarray) -> np.ndarray:
        e, n, _ = t.transform(lonlat[:, 0], lonlat[:, 1], np.zeros(len(lonlat)))
        return np.c_[e, n]

    return f


def image_extent_m(plan: FloorPlan, extent: tuple[float, float, float, float] | None = None) -> list[float]:
    """Where a raster image of the plan lies in its local metres, [x0, y0, x1, y1] (left, bottom, right,
    top): ``extent`` in the plan's own coordinates as the user gave the plan (west, south, east, north in
    degrees for a plan in WGS84 lon/lat, metres otherwise), or the plan's bounding box when None."""
    if extent is None:
        return [float(v) for v in plan.bounds]
    g = plan.georef
    if g is None or g.kind != "enu":
        return [float(v) for v in extent]
    (x0, y0), (x1, y1) = lonlat_to_enu(g.lon0, g.lat0)(np.array([extent[:2], extent[2:]], float))
    return [float(x0), float(y0), float(x1), float(y1)]


def _enu_pipeline(lon0: float, lat0: float) -> str:
    return (f"+proj=pipeline +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lon_0={lon0} +lat_0={lat0} +h_0=0")


def _mercator_bbox(bbox: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    from pyproj import Transformer

    t = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    x0, y0 = t.transform(bbox[0], bbox[1])
    x1, y1 = t.transform(bbox[2], bbox[3])
    return float(x0), float(y0), float(x1), float(y1)


def _polygon(geom: dict, to_local) -> shapely.Geometry:
    """A shapely (Multi)Polygon in local metres from a GeoJSON geometry dict."""
    rings = geom["coordinates"] if geom["type"] == "MultiPolygon" else [geom["coordinates"]]
    polys = []
    for poly in rings:
        shell, *holes = [_local_ring(np.asarray(r, float)[:, :2], to_local) for r in poly]
        polys.append(shapely.Polygon(shell, holes))
    return shapely.make_valid(shapely.MultiPolygon(polys) if len(polys) > 1 else polys[0])


def _local_ring(ring: np.ndarray, to_local) -> np.ndarray:
    """A ring's positions in local metres; ValueError unless every one is finite and within MAX_COORD_M."""
    if not np.isfinite(ring).all():
        raise ValueError("a vertex is NaN or infinite")
    xy = np.asarray(to_local(ring), float)
    bad = ~(np.abs(xy) <= MAX_COORD_M).all(axis=1)
    if bad.any():
        v = ring[int(np.argmax(bad))]
        raise ValueError(f"vertex ({v[0]:.6g}, {v[1]:.6g}) lies more than {MAX_COORD_M:g} m from the plan's origin")
    return xy


def _signed_distance(walkable, bounds, res: float, margin: float):
    """Signed distance field of ``walkable`` over ``bounds`` + margin (negative inside), via the Euclidean
    distance transform of its rasterised mask."""
    x0, y0, x1, y1 = bounds
    ox, oy = x0 - margin, y0 - margin
    nc, nr = int(np.ceil((x1 - x0 + 2 * margin) / res)) + 1, int(np.ceil((y1 - y0 + 2 * margin) / res)) + 1
    xs, ys = ox + res * np.arange(nc), oy + res * np.arange(nr)
    gx, gy = np.meshgrid(xs, ys)
    mask = shapely.contains_xy(walkable, gx.ravel(), gy.ravel()).reshape(nr, nc)
    from scipy import ndimage

    outside = ndimage.distance_transform_edt(~mask) * res
    inside = ndimage.distance_transform_edt(mask) * res
    return np.where(mask, -inside, outside), (ox, oy), res


def to_geojson(plan: FloorPlan) -> dict:
    """The plan in local metres as GeoJSON (the workspace's ``data/floorplan.local.json``: GeoJSON-shaped, but
    in metres, so not RFC 7946 GeoJSON): the outline
    (``"type": "floor"``), the walkable space (``"walkable": true``) and the georeference, which
    :func:`from_local_geojson` reads back."""

    def feature(geom, **props) -> dict:
        return {"type": "Feature", "properties": props, "geometry": shapely.geometry.mapping(geom)}

    g = plan.georef
    return {"type": "FeatureCollection", "name": plan.name, "frame": "local_m",
            "georef": None if g is None else {"kind": g.kind, "lon0": g.lon0, "lat0": g.lat0, "bbox": list(g.bbox),
                                               "size_m": list(g.size_m)},
            "features": [feature(plan.outline, type="floor"), feature(plan.walkable, walkable=True)]}


def from_local_geojson(doc: dict) -> FloorPlan:
    """A plan written by :func:`to_geojson` (coordinates in local metres)."""
    plan = from_features(doc["features"], lambda a: a, str(doc.get("name", "")))
    g = doc.get("georef")
    if g:
        plan.georef = Georef(g["kind"], float(g["lon0"]), float(g["lat0"]), tuple(g["bbox"]),  # type: ignore[arg-type]
                             tuple(g["size_m"]))  # type: ignore[arg-type]
    return plan


def from_user_geojson(doc: dict, name: str = "") -> FloorPlan:
    """A user's plan: a GeoJSON FeatureCollection (the roles of its polygons: :func:`from_features`) in
    WGS84 lon/lat (RFC 7946), projected to east/north metres about the outline's south-west corner, or in
    local metres when the collection says ``"frame": "local_m"``. ValueError for anything else."""
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        raise ValueError("not a GeoJSON FeatureCollection")
    check_vertex_count(doc["features"])
    if doc.get("frame") == "local_m":
        return from_local_geojson(doc) if doc.get("georef") else from_features(doc["features"], lambda a: a, name)
    coords = np.array([c for f in doc["features"] if f.get("geometry")
                       for c in _all_coords(f["geometry"].get("coordinates", []))], float).reshape(-1, 2)
    if not len(coords) or not np.isfinite(coords).all() or np.abs(coords[:, 0]).max() > 180 \
            or np.abs(coords[:, 1]).max() > 90 or np.ptp(coords, axis=0).max() > MAX_PLAN_SPAN_DEG:
        raise ValueError("coordinates are not one building in WGS84 lon/lat (give \"frame\": \"local_m\" for "
                         "metres)")
    lon0, lat0 = float(coords[:, 0].min()), float(coords[:, 1].min())
    plan = from_features(doc["features"], lonlat_to_enu(lon0, lat0), name)
    plan.georef = Georef("enu", lon0, lat0)
    return plan


def _all_coords(c) -> list:
    """The [x, y] positions of a nested GeoJSON coordinates array."""
    if isinstance(c, (list, tuple)) and len(c) >= 2 and all(isinstance(v, (int, float)) for v in c[:2]):
        return [list(c[:2])]
    return [p for sub in (c or []) for p in _all_coords(sub)]


# m; raster cell of the frame check's search, and how near walkable space a fix counts as in it
FRAME_CELL_M = 1.0
FRAME_TOLERANCE_M = 1.0
# deg; step of the frame check's turns over the full circle
FRAME_TURN_STEP_DEG = 5.0
# cells; the frame check's raster of the points (cells of FRAME_CELL_M) at most: points spread wider than
# ~1 km are not searched (no floor's fixes do; the FFT's memory grows with the raster)
FRAME_MAX_POINT_CELLS = 1_000_000


def frame_correction(plan: FloorPlan, xy: np.ndarray) -> dict:
    """How well points ``xy`` (n, 2; the data's fixes) fit the plan as it is, and the SE(2) correction that
    fits them best: a turn about their centroid (every FRAME_TURN_STEP_DEG over the full circle), then the
    translation that puts most of them within FRAME_TOLERANCE_M of walkable space (FFT cross-correlation of
    their raster with the walkable mask, any overlap; each turn's best re-measured exactly). {"inside": share
    as given, "best_inside": share after the correction, "turn_deg", "shift_m" [dx, dy] (applied after the
    turn about their centroid), "moved_m": how far the correction moves the points, on average; no
    correction (0) unless it fits more points than the plan as given; "searched": false when the points
    spread too wide for the search's raster (FRAME_MAX_POINT_CELLS), which then finds no correction}."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    inside = float(plan.inside(xy, FRAME_TOLERANCE_M).mean())
    out: dict = {"inside": inside, "best_inside": inside, "turn_deg": 0.0, "shift_m": [0.0, 0.0], "moved_m": 0.0,
                 "searched": True}
    grid, origin, res = plan.distance_field()
    step = max(1, int(round(FRAME_CELL_M / res)))
    reach = 2.0 * float(np.linalg.norm(xy - xy.mean(axis=0), axis=1).max(initial=0.0)) / (step * res) + 2.0
    if reach**2 > FRAME_MAX_POINT_CELLS:  # the points' raster under any turn would be larger
        out["searched"] = False
        return out
    mask = (grid[::step, ::step] <= FRAME_TOLERANCE_M).astype(float)
    cen = xy.mean(axis=0)
    for turn in np.arange(0.0, 360.0, FRAME_TURN_STEP_DEG):
        p = (xy - cen) @ geometry.rot(np.radians(turn)).T + cen
        score, t = correlate_points(mask, np.asarray(origin), step * res, p, full=True)
        shift = t(np.unravel_index(int(np.argmax(score)), score.shape))
        share = float(plan.inside(p + shift, FRAME_TOLERANCE_M).mean())
        if share * len(xy) > out["best_inside"] * len(xy) + 0.5:
            out.update(best_inside=share, turn_deg=float((turn + 180.0) % 360.0 - 180.0),
                       shift_m=[float(shift[0]), float(shift[1])],
                       moved_m=float(np.linalg.norm(p + shift - xy, axis=1).mean()))
    return out


def correlate_points(mask: np.ndarray, origin: np.ndarray, cell: float, p: np.ndarray, full: bool = False):
    """How many points ``p`` (n, 2) land on ``mask`` (rows y, columns x, cells of ``cell`` m, cell (0, 0) at
    ``origin``) for every translation: an FFT cross-correlation of the points' raster (cells of ``cell`` from
    their minimum) with the mask. ``full``: every translation that overlaps them at all; else those that keep
    the points' raster within the mask (padded when the points spread wider than it). Returns (score, the
    translation of a score cell (row, col))."""
    from scipy import signal  # imported here: scipy.signal costs ~1 s at import, and most runs use no plan

    lo = p.min(axis=0)
    ij = np.floor((p - lo) / cell).astype(int)
    occ = np.zeros((ij[:, 1].max() + 1, ij[:, 0].max() + 1))
    np.add.at(occ, (ij[:, 1], ij[:, 0]), 1.0)
    mask = mask.astype(float)
    if full:
        off = np.array(occ.shape) - 1
        score = signal.fftconvolve(mask, occ[::-1, ::-1], mode="full")
    else:
        off = np.zeros(2, int)
        grow = np.maximum(np.array(occ.shape) - np.array(mask.shape), 0)
        mask = np.pad(mask, ((0, grow[0]), (0, grow[1])))
        score = signal.fftconvolve(mask, occ[::-1, ::-1], mode="valid")

    def shift(cell_rc) -> np.ndarray:  # the points' raster cell (0, 0) (its centre) on mask sample cell_rc - off
        return origin + cell * np.array([cell_rc[1] - off[1], cell_rc[0] - off[0]]) - lo - cell / 2

    return score, shift
