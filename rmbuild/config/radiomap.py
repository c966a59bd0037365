"""Config of `rmbuild export-map` (docs/baselines.md for the histogram layer)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class FillConfig:
    """Optional fill of unvisited grid cells near visited ones (flagged ``interpolated`` in the map)."""

    # "none": only visited cells; "idw": inverse-distance weighting of nearby visited cells; "gp": Gaussian
    # process regression (RBF kernel) over all visited cells, with its predictive std as the uncertainty.
    method: Literal["none", "idw", "gp"] = "none"
    # m; only unvisited cells whose centre is within this distance of a visited cell's centre are filled.
    max_distance_m: float = bounded(3.0, 0.1, 50.0)
    # 1; IDW weight = 1 / distance**idw_power over the idw_neighbours nearest visited cells.
    idw_power: float = bounded(2.0, 0.1, 10.0)
    # 1; number of visited cells an IDW estimate uses.
    idw_neighbours: int = bounded(8, 1, 1000)
    # m; GP RBF kernel length scale ℓ.
    gp_length_scale_m: float = bounded(4.0, 0.1, 1000.0)
    # dB; GP prior (signal) std σ_f of a cell mean around the AP's mean.
    gp_signal_std_db: float = bounded(8.0, 0.1, 100.0)
    # dB; GP noise std σ_n of an observed cell mean.
    gp_noise_std_db: float = bounded(4.0, 0.1, 100.0)
    # 1; the GP solves one dense system over the visited cells; more cells than this is an input error
    # (10,000 cells: an 800 MB system).
    gp_max_cells: int = bounded(6000, 1, 10000)
    # 1; an AP is kept in a filled cell when its interpolated detection ratio is at least this.
    min_detect_ratio: float = bounded(0.5, 0.0, 1.0)

    def validate(self) -> None:
        check_ranges(self)


@dataclass(frozen=True)
class HistogramConfig:
    """Per-cell RSS histograms, kept apart by walking direction (the subway-station Wi-Fi + PDR paper)."""

    # dB; width of a histogram bin (paper: about 2 dB).
    bin_db: float = bounded(2.0, 0.5, 50.0)
    # 1; walking-direction sectors the histograms are kept apart by, centred on the map's +x axis and
    # every 360/n deg from it (0 = no direction). The paper keeps the two directions of each straight
    # sub-area apart; 4 sectors do that for corridors along either map axis.
    n_directions: int = bounded(4, 0, 36)

    def validate(self) -> None:
        check_ranges(self, "histogram.")


@dataclass(frozen=True)
class MapConfig:
    # m; grid cell edge (the subway-station paper: 1 m, SLAC's survey: 5 m).
    cell_size_m: float = bounded(2.0, 0.25, 100.0)
    # 1; minimum readings T of an AP in a cell for its statistics to be kept (T_min; fewer -> not detected).
    min_count: int = bounded(1, 1, 1_000_000)
    # 1; minimum scans in a cell for the cell to become a reference point (RP).
    min_scans: int = bounded(1, 1, 1_000_000)
    # name of the map's frame, written to the sidecar ("" = decided by the caller, e.g. "building" with
    # anchors or "walk:<id>" for the reference walk's frame).
    frame: str = ""
    # 1; number of strongest APs (by peak cell mean) that get a heat map.
    heatmap_top_n: int = bounded(6, 0, 24)
    # Walks that optimize could not link to the reference walk by Wi-Fi (and that no anchors placed) have an
    # unconstrained placement; false (default) leaves their nodes out of the built map, true keeps them
    # where optimize put them.
    include_unlinked_walks: bool = False
    fill: FillConfig = field(default_factory=FillConfig)
    histogram: HistogramConfig = field(default_factory=HistogramConfig)

    def validate(self) -> None:
        check_ranges(self)
        self.fill.validate()
        self.histogram.validate()
