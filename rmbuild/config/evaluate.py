"""Config of `rmbuild evaluate` and of kNN (docs/localizers.md); the paper baselines' settings are
:mod:`rmbuild.baselines.config` (docs/baselines.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from rmbuild.baselines.config import BaselinesConfig
from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class KnnConfig:
    """FL / kNN and distance-weighted kNN (He et al. 2015 baseline, Chen et al. 2018 eq. 3-4)."""

    # 1; K nearest reference points (He et al. 2015's comparison: 15).
    k: int = bounded(15, 1, 1000)
    # "fill": a missing reading counts as fill_dbm (Gu et al. 2017); "exclude": distances use only the APs
    # detected in both the query and the reference point.
    missing: Literal["fill", "exclude"] = "fill"
    # dBm; value of a missing reading under missing = "fill" (Gu et al. 2017: -110).
    fill_dbm: float = bounded(-110.0, -200.0, 0.0)
    # "euclidean": sqrt(Σ_j (a_j − b_j)²) (plain; scikit-learn's metric on filled vectors);
    # "rms": sqrt(Σ_j (a_j − b_j)² / M), M = |union| of detected APs under "fill" (Gu et al. 2017 eq. 9) or
    # |shared| under "exclude" (also the normalisation used by "exclude" with either choice).
    metric: Literal["euclidean", "rms"] = "euclidean"
    # 1; under missing = "exclude", a reference point sharing fewer APs with the query is never a neighbour.
    min_shared_aps: int = bounded(1, 1, 1000)
    # "cells": the grid cells of the radio map are the RPs; "nodes": every map node's own fingerprint is.
    reference: Literal["cells", "nodes"] = "cells"
    # dB; distance-weighted kNN weight = 1 / max(d, weight_eps_db) (sklearn semantics when 0: exact matches win).
    weight_eps_db: float = bounded(0.0, 0.0, 100.0)

    def validate(self) -> None:
        check_ranges(self, "knn.")


@dataclass(frozen=True)
class EvaluateConfig:
    # localizer registry names run side by side (rmbuild.localize.registry; `rmbuild evaluate --help`).
    localizers: tuple[str, ...] = ("knn", "wknn")
    # 1; default split when no walk has role "test": walk i (in walks order) is a test walk when
    # i % split_every == split_offset. Never splits a walk.
    split_every: int = bounded(5, 2, 1000)
    # 1; see split_every (0 <= split_offset < split_every).
    split_offset: int = bounded(2, 0, 999)
    # "scan": every Wi-Fi scan (readings sharing walk and time) is one query; "node": every node's mean
    # fingerprint is one query.
    query: Literal["scan", "node"] = "scan"
    # m; a building's combined error adds this per floor the floor classification is off by (the IPIN
    # competition's and the Kaggle Indoor Location & Navigation metric's 15 m).
    floor_penalty_m: float = bounded(15.0, 0.0, 1000.0)
    knn: KnnConfig = field(default_factory=KnnConfig)
    # the paper baselines' settings (rmbuild.baselines; docs/baselines.md)
    baselines: BaselinesConfig = field(default_factory=BaselinesConfig)

    def validate(self) -> None:
        if not self.localizers:
            raise ValueError("localizers must name at least one localizer")
        check_ranges(self)
        if not 0 <= self.split_offset < self.split_every:
            raise ValueError("split_offset must be in [0, split_every)")
        self.knn.validate()
        self.baselines.validate()
