"""Evidence sources of the back end, one module each, behind one interface (:mod:`.base`). The floor plan's
source (:mod:`.floorplan`, shapely) is imported only when a plan is given."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pandas as pd

from rmbuild.config.optimize import OptimizeConfig
from rmbuild.slam.evidence.anchors import AnchorSource
from rmbuild.slam.evidence.base import EvidenceSource
from rmbuild.slam.evidence.compass import CompassSource
from rmbuild.slam.evidence.continuity import ContinuitySource
from rmbuild.slam.evidence.wifi import CandidatesHook, WifiSource
from rmbuild.slam.held import Holding
from rmbuild.slam.problem import WalkSet

if TYPE_CHECKING:
    from rmbuild.floorplan import FloorPlan

__all__ = ["AnchorSource", "CompassSource", "ContinuitySource", "EvidenceSource", "WifiSource", "default_sources"]


def default_sources(walks: WalkSet, cfg: OptimizeConfig, anchors: pd.DataFrame | None = None, progress=None,
                    candidates_hook: CandidatesHook | None = None, floorplan: FloorPlan | None = None,
                    holding: Holding | None = None) -> list[EvidenceSource]:
    """The sources of a run, in the order their links and static factors are gathered (a floor plan only
    when one is given). ``holding``: the held map of an incremental run (:mod:`rmbuild.slam.held`), which
    each source restricts itself by (the solve drops any factor that touches held nodes only)."""
    wifi = WifiSource(walks, cfg.wifi, progress, candidates_hook, holding)
    compass = CompassSource(walks, cfg.compass, holding)
    plan = []
    if floorplan is not None:
        from rmbuild.slam.evidence.floorplan import FloorPlanSource

        plan = [FloorPlanSource(walks, floorplan, compass.rotation_priors(), holding)]
    return [
        wifi,
        ContinuitySource(walks, cfg.continuity, wifi.rf, wifi.rss, walks.fingerprints.node),
        *plan,
        AnchorSource(walks, anchors, cfg.anchors),
        compass,
    ]
