"""The evidence-source interface of the back end.

An evidence source is one kind of information about where the walks lie — Wi-Fi similarity between
scans, the phone's compass, known positions — in one module. The optimizer asks every source the same
questions, in this order, and never looks inside one:

1. **Placement** (before any solve; :mod:`rmbuild.slam.placement`):
   - :meth:`links` — cross-walk node correspondences ("node k of one walk is near node q of another")
     the placement loop fits walks to the placed map with;
   - :meth:`scan_locator` — an object that localises a walk's scans on the map placed so far (kNN
     growth), or None;
   - :meth:`rotation_priors` — per walk, the rotation of its own frame in a common world (compass);
   - :meth:`ties` — position ties between walks (one walk's end and the next one's start), which join
     components of walks placed apart;
   - :meth:`place` — move the placed components afterwards (anchors put them into the building frame).
2. **Solve set-up** (:mod:`rmbuild.slam.solve`), after placement: :meth:`prepare` with the initial
   poses, then :meth:`required_nodes` (the nodes its factors touch: the keyframes of the chain reduction)
   and :meth:`static_factors` (factors that stay the same in every solve).
3. **Each solve**: :meth:`factors` (the factors for this solve at the current poses), then, after it,
   :meth:`update` (re-select / re-estimate from the solved poses; says whether what it contributes changed).
4. :meth:`pairs_near` — the node pairs it ties together that lie within its range at given poses (the
   step-length scale rounds fit walks to them), and :meth:`report` — what it did, JSON-able.

Every method has a do-nothing default, so a source implements only what it contributes. To add a source:
subclass :class:`EvidenceSource` in a new module of :mod:`rmbuild.slam.evidence`, give it a config table
in ``rmbuild/config/optimize.py`` and add it to :func:`rmbuild.slam.evidence.default_sources`.
"""

from __future__ import annotations

from abc import ABC
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmbuild.slam.problem import WalkSet


@dataclass
class Links:
    """Cross-walk node correspondences for placement: ``node_k`` / ``node_q`` (m,) node ids of different
    walks."""

    node_k: np.ndarray
    node_q: np.ndarray

    def __len__(self) -> int:
        return len(self.node_k)


@dataclass
class Ties:
    """Position ties between nodes of different walks: ``node_a`` / ``node_b`` (m,) lie within about
    ``sigma_m`` (m,) of each other (e.g. one walk's end and the next walk's start)."""

    node_a: np.ndarray
    node_b: np.ndarray
    sigma_m: np.ndarray

    def __len__(self) -> int:
        return len(self.node_a)


@dataclass
class RotationPriors:
    """Per walk (n_walks,): the rotation (rad) of its own frame in a common world, whether it is known,
    and its 1-sigma (rad)."""

    theta: np.ndarray
    known: np.ndarray
    sigma: np.ndarray


@dataclass
class SolveState:
    """What a source sees at a solve: the current poses (n, 3) in the common frame, the walks whose
    step-length scale is still settling (n_walks,) bool, the placement (walk frames, components) and the
    nodes the solve keeps (its keyframes; factors may only touch those or the source's required nodes)."""

    poses: np.ndarray
    settling: np.ndarray
    placement: Any
    keyframes: np.ndarray | None = None


@dataclass
class Update:
    """A source's answer after a solve: ``changed`` — it will contribute something different next time
    (another solve is worth it); ``first_switch`` — a change that deserves one more solve even after the
    last one of the schedule (a model switched on for the first time)."""

    changed: bool = False
    first_switch: bool = False


@dataclass
class StaticFactors:
    """Factors that stay the same in every solve, and counts per kind for the report."""

    factors: list = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)


class EvidenceSource(ABC):  # noqa: B024 - every method has a default: a source implements what it gives
    """One kind of evidence (see the module docstring for the protocol). ``warnings``: one line each,
    for the run's report."""

    name: str = "evidence"
    warnings: list[str]

    def links(self) -> Links | None:
        return None

    def scan_locator(self):
        return None

    def rotation_priors(self) -> RotationPriors | None:
        return None

    def ties(self) -> Ties | None:
        return None

    def place(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        return None

    def fixes_rotation(self, placement) -> bool:
        """Whether its factors fix the map's rotation (the gauge then leaves the rotation free)."""
        return False

    def prepare(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> None:
        return None

    def required_nodes(self) -> np.ndarray:
        return np.zeros(0, np.int64)

    def static_factors(self, walks: WalkSet, placement, init_xyt: np.ndarray) -> StaticFactors:
        return StaticFactors()

    def factors(self, state: SolveState) -> list:
        return []

    def update(self, state: SolveState) -> Update:
        return Update()

    def pairs_near(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)

    def final_factors(self, state: SolveState) -> list:
        """The last solve's factors rebuilt at the final poses (the report's final cost)."""
        return self.factors(state)

    def report(self) -> dict[str, Any]:
        return {}
