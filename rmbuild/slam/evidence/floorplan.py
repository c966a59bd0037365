"""Floor-plan evidence: people walk in walkable space, not through walls or shops.

- Frame: with a plan the map is built in the plan's frame. The compass gives each component's rotation in
  the plan's frame (the compass world and the plan are both north-up); what is left is a translation,
  found by correlating the component's poses with the walkable space (:func:`best_translation`: an FFT
  cross-correlation of the rasterised poses with the walkable mask, for the compass rotation and small
  turns about it, PLAN_TURNS_DEG). The reference component is always moved onto the plan; another
  component only when its best fit is distinct — it keeps PLAN_MIN_INSIDE of its poses inside and leads the
  best fit elsewhere (more than PLAN_DISTINCT_M away) by PLAN_MARGIN of the poses — and it is then
  reported as placed by the plan.
- Frame check: the plan is not used (the map stays in the reference walk's frame, with a warning) when
  under PLAN_FRAME_MIN_INSIDE of the reference component's poses fit it, when they fit it almost as well
  (within PLAN_FRAME_MARGIN of the poses) somewhere more than PLAN_DISTINCT_M away, or when they fit it clearly better
  (PLAN_TURN_GAIN of the poses) turned more than PLAN_TURN_MIN_DEG from the compass's north, searched over
  the full circle: the plan is then rotated (or mirrored) against north. A shifted plan, or another floor's
  with similar corridors, cannot be told apart here (the fit follows the plan): the data's fixes can
  (:func:`rmbuild.io.floorplan.check_plan_frame`).
- Solve: after each solve every keyframe pose outside walkable space (by more than PLAN_TOLERANCE_M) gets a
  robust (Huber) position prior towards the nearest walkable point, sigma PLAN_SIGMA_M; the associations
  are renewed after each solve.
"""

from __future__ import annotations

import gtsam
import numpy as np

from rmbuild import geometry
from rmbuild.floorplan import FloorPlan, correlate_points
from rmbuild.slam.evidence.base import EvidenceSource, RotationPriors, SolveState, Update
from rmbuild.slam.factors import X
from rmbuild.slam.held import Holding
from rmbuild.slam.problem import WalkSet

# m; raster cell of the translation search, and how softly a pose outside walkable space still counts
PLAN_CELL_M = 1.0
PLAN_SOFT_M = 1.5
# deg; turns about the compass rotation tried by the translation search (the compass's common offset)
PLAN_TURNS_DEG = (-6.0, -3.0, 0.0, 3.0, 6.0)
# a further component is placed by the plan when at least this share of its poses falls inside, leading the
# best fit more than PLAN_DISTINCT_M away by this share of its poses
PLAN_MIN_INSIDE = 0.8
PLAN_MARGIN = 0.15
PLAN_DISTINCT_M = 10.0
# the frame check (module docstring). Measured on the five MS ILC 2.0 floors (reference component, plan
# right -> turned 20/90/180 deg, mirrored, another floor's): the right plans keep 78-94 % of the poses
# inside and gain at most 0.058 turned elsewhere (site2/B1, -55 deg); turned plans gain up to 0.22
PLAN_FRAME_MIN_INSIDE = 0.5
# ... and when the reference component's best fit leads the best fit more than PLAN_DISTINCT_M away by less
# than this share of its poses: its place on the plan is a guess. Measured on the same floors: the fits
# that put the map within 9 m of the truth led by 0.13 / 0.15 (site1/F1, F2), the ones 82 and 47 m off by
# 0.02 / 0.04 (site2/F4, F6); site2/B1 0.05 (15 m off, as far as its radio places the walks anyway)
PLAN_FRAME_MARGIN = 0.08
PLAN_TURN_GAIN = 0.09
PLAN_TURN_MIN_DEG = 15.0
# deg; the turns of the frame check's full-circle search
PLAN_CHECK_TURNS_DEG = tuple(float(a) for a in range(0, 360, 5))
# m; poses outside walkable space by more than this get a wall prior; its sigma and Huber width (sigmas)
PLAN_TOLERANCE_M = 0.5
PLAN_SIGMA_M = 1.0
PLAN_HUBER_K = 1.0


class FloorPlanSource(EvidenceSource):
    """The walkable space of one floor (module docstring)."""

    name = "floorplan"

    def __init__(self, walks: WalkSet, plan: FloorPlan, rot: RotationPriors, holding: Holding | None = None):
        """``holding``: a held map (:mod:`rmbuild.slam.held`) already in the plan's frame: nothing is moved
        into it; the walkable space only holds the other walks."""
        self.holding = holding
        self.warnings: list[str] = []
        self.plan = plan
        self.walks = walks
        self.rot = rot
        self.mask, self.origin = _walkable_mask(plan)
        self.nodes = np.zeros(0, np.int64)
        self.targets = np.zeros((0, 2))
        self.fit: dict = {}
        self.used = True  # False when the frame check refused the plan: no frame, no wall priors

    def place(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        """Move the components into the plan's frame (module docstring)."""
        if self.holding is not None:
            self.used = self.holding.state.frame == "floorplan"
            return
        ref = placement.reference
        if not self.rot.known[ref]:
            self.warnings.append("floor plan: the reference walk has no compass heading; the map is not put "
                                 "into the plan's frame")
            self.used = False
            return
        T = placement.world_T_walk
        walk_frame = T.copy()
        T[:] = geometry.compose(np.array([0.0, 0.0, self.rot.theta[ref]]), T)  # into the compass world
        comp = placement.component
        problem = self._frame_check(walks.apply_frames(T)[(comp == 0)[walks.walk_of], :2])
        if problem:
            T[:] = walk_frame
            self.used = False
            label = f"floor plan {self.plan.name}" if self.plan.name else "floor plan"
            self.warnings.append(f"{label}: {problem}; not used (the map stays in the reference walk's frame)")
            return
        fits = {}
        for c in np.unique(comp):
            members = comp == c
            xy = walks.apply_frames(T)[members[walks.walk_of], :2]
            fit = best_translation(self.mask, self.origin, xy)
            if c == 0 or _distinct(fit):
                fit = refine_fit(self.plan, xy, fit)
            fits[int(c)] = fit
            if c != 0 and not _distinct(fit):
                continue
            turn = np.array([0.0, 0.0, np.radians(fit["turn_deg"])])
            pivot = xy.mean(axis=0)
            shift = np.r_[fit["t"], 0.0]
            moved = geometry.compose(turn, T[members] - np.r_[pivot, 0.0]) + np.r_[pivot, 0.0] + shift
            T[members] = moved
            if c != 0:
                placement.component[members] = 0
                placement.method[members] = "floorplan"
        _, placement.component = np.unique(placement.component, return_inverse=True)  # no id left empty
        self.fit = {**self.fit, "inside": round(fits[0]["inside"], 3), "turn_deg": fits[0]["turn_deg"],
                    "placed_components": int(sum(1 for c, f in fits.items() if c != 0 and _distinct(f)))}
        placement.frame = "floorplan"
        placement.frame_rotation = float(self.rot.theta[ref] + np.radians(fits[0]["turn_deg"]))

    def _frame_check(self, xy: np.ndarray) -> str | None:
        """What looks wrong with the plan's frame for the reference component's poses ``xy`` (compass
        world), or None (module docstring); the figures go to the report."""
        compass = best_translation(self.mask, self.origin, xy)
        full = best_translation(self.mask, self.origin, xy, PLAN_CHECK_TURNS_DEG)
        turn = float((full["turn_deg"] + 180.0) % 360.0 - 180.0)  # from the compass's north
        gain = full["inside"] - compass["inside"]
        self.fit = {"frame_check": {"compass_inside": round(compass["inside"], 3),
                                    "compass_second": round(compass["second"], 3),
                                    "best_turn_deg": turn, "best_turn_inside": round(full["inside"], 3)}}
        if compass["inside"] < PLAN_FRAME_MIN_INSIDE:
            return f"only {compass['inside']:.0%} of the map's poses fit its walkable space"
        if compass["inside"] - compass["second"] < PLAN_FRAME_MARGIN:
            return (f"the map fits it almost as well ({compass['second']:.0%} of the poses inside against "
                    f"{compass['inside']:.0%}) more than {PLAN_DISTINCT_M:g} m from its best place: where it "
                    "lies on the plan is ambiguous")
        if gain >= PLAN_TURN_GAIN and abs(turn) >= PLAN_TURN_MIN_DEG:
            return (f"the map fits it better turned {turn:+.0f} deg from the compass's north ({full['inside']:.0%} "
                    f"of the poses inside, {compass['inside']:.0%} unturned): it looks rotated or mirrored")
        return None

    def prepare(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        if not self.used:
            return
        nodes = np.flatnonzero(placement.linked[walks.walk_of])
        self._associate(init_xyt, nodes)

    def factors(self, state: SolveState) -> list:
        if not self.used:
            return []
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(PLAN_HUBER_K),
                                               gtsam.noiseModel.Isotropic.Sigma(2, PLAN_SIGMA_M))
        keep = np.isin(self.nodes, state.keyframes) if state.keyframes is not None else np.ones(len(self.nodes), bool)
        return [gtsam.PoseTranslationPrior2D(X(int(i)), gtsam.Pose2(float(x), float(y), 0.0), noise)
                for i, (x, y) in zip(self.nodes[keep].tolist(), self.targets[keep].tolist())]

    def update(self, state: SolveState) -> Update:
        """Re-associate the keyframe poses outside walkable space with their nearest walkable points."""
        if not self.used:
            return Update()
        kf = state.keyframes if state.keyframes is not None else np.arange(len(state.poses))
        before = self.nodes
        self._associate(state.poses, kf[state.placement.linked[self.walks.walk_of[kf]]])
        return Update(changed=not np.array_equal(before, self.nodes))

    def _associate(self, poses: np.ndarray, nodes: np.ndarray) -> None:
        d = self.plan.distance(poses[nodes, :2])
        self.nodes = nodes[d > PLAN_TOLERANCE_M]
        self.targets = nearest_walkable(self.plan, poses[self.nodes, :2])

    def report(self) -> dict:
        return {**self.fit, "used": self.used, "wall_priors": int(len(self.nodes)),
                "walkable_m2": round(self.plan.area_m2, 1)}


def _distinct(fit: dict) -> bool:
    return bool(fit["inside"] >= PLAN_MIN_INSIDE and fit["inside"] - fit["second"] >= PLAN_MARGIN)


def _walkable_mask(plan: FloorPlan) -> tuple[np.ndarray, np.ndarray]:
    """(score (rows, cols) at PLAN_CELL_M: 1 inside walkable space, falling off outside as a Gaussian of
    the distance (sigma PLAN_SOFT_M), origin (x, y) of cell (0, 0))."""
    grid, (ox, oy), res = plan.distance_field()
    step = max(1, int(round(PLAN_CELL_M / res)))
    d = np.maximum(grid[::step, ::step], 0.0)
    return np.exp(-0.5 * (d / PLAN_SOFT_M) ** 2), np.array([ox, oy])


def best_translation(mask: np.ndarray, origin: np.ndarray, xy: np.ndarray,
                     turns: tuple[float, ...] = PLAN_TURNS_DEG) -> dict:
    """The translation (and turn about the points' centroid, one of ``turns``) that puts the most points
    ``xy`` (n, 2) inside ``mask``: {"t" (2,), "turn_deg", "inside" (share), "second" (share of the best fit
    more than PLAN_DISTINCT_M from it)}."""
    best: dict = {"inside": -1.0}
    cen = xy.mean(axis=0)
    for turn in turns:
        p = (xy - cen) @ geometry.rot(np.radians(turn)).T
        score, t = correlate_points(mask, origin, PLAN_CELL_M, p)
        if score.max() > best["inside"] * len(xy) - 1e-9:
            i = np.unravel_index(int(np.argmax(score)), score.shape)
            far = _far_from(score.shape, i, PLAN_DISTINCT_M / PLAN_CELL_M)
            best = {"t": t(i) - cen, "turn_deg": turn, "inside": float(score[i]) / len(xy),
                    "second": float(score[far].max()) / len(xy) if far.any() else 0.0}
    return best


def refine_fit(plan: FloorPlan, xy: np.ndarray, fit: dict) -> dict:
    """``fit`` refined continuously (translation and turn about the points' centroid) to maximise the soft
    in-walkable score of the points (Nelder-Mead on the distance field, within a cell and PLAN_TURNS_DEG's
    step of the search's answer)."""
    from scipy.optimize import minimize

    cen = xy.mean(axis=0)

    def cost(v: np.ndarray) -> float:
        p = (xy - cen) @ geometry.rot(np.radians(v[2])).T + cen + v[:2]
        d = np.maximum(plan.distance(p), 0.0)
        return -float(np.mean(np.exp(-0.5 * (d / PLAN_SOFT_M) ** 2)))

    res = minimize(cost, np.r_[fit["t"], fit["turn_deg"]], method="Nelder-Mead",
                   options={"xatol": 0.05, "fatol": 1e-5, "maxiter": 400})
    v = res.x
    if np.hypot(*(v[:2] - fit["t"])) > 2 * PLAN_CELL_M or abs(v[2] - fit["turn_deg"]) > 3.0:
        return fit
    return {**fit, "t": v[:2], "turn_deg": float(v[2]), "inside": -float(res.fun)}


def _far_from(shape, i, radius_cells: float) -> np.ndarray:
    r, c = np.ogrid[:shape[0], :shape[1]]
    return (r - i[0]) ** 2 + (c - i[1]) ** 2 > radius_cells**2


def nearest_walkable(plan: FloorPlan, xy: np.ndarray) -> np.ndarray:
    """(n, 2) the nearest walkable point of each point (n, 2) (via the distance field's feature transform)."""
    if not len(xy):
        return np.zeros((0, 2))
    grid, (ox, oy), res = plan.distance_field()
    from scipy import ndimage

    _, (ri, ci) = ndimage.distance_transform_edt(grid > 0, return_indices=True)
    r = np.clip(np.rint((xy[:, 1] - oy) / res).astype(int), 0, grid.shape[0] - 1)
    c = np.clip(np.rint((xy[:, 0] - ox) / res).astype(int), 0, grid.shape[1] - 1)
    return np.c_[ox + res * ci[r, c], oy + res * ri[r, c]]
