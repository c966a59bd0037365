"""The solve schedule: how many times the pose graph is solved, and when a step-length scale round runs.

Pure bookkeeping (no gtsam), so it can be tested on its own. The joint solve is repeated because what the
graph contains depends on the solution:

- the sources re-select their evidence from the solved poses (Wi-Fi: the pairs within d_max) and say
  whether anything changed (:class:`rmbuild.slam.evidence.base.Update`);
- with ``estimate_scale`` each of the first SCALE_ROUNDS_MIN solves but the last is followed by a round
  that re-estimates each walk's step-length scale; further rounds (one more solve each, up to
  SCALE_ROUNDS_MAX rounds) follow while the last round still moved some scale by more than
  SCALE_EXTEND_MOVE (an uncalibrated phone step length is far from converged after two).

The budget is ``outer_iterations`` solves plus SCALE_ROUNDS_MIN with scale estimation. After a solve the
schedule stops when it was the last of the budget, or when nothing changed (no source's evidence, no scale
moved by more than SCALE_TOL). Two things add a solve beyond the budget: an extended scale round that moved
a scale, and a source's ``first_switch`` after the last solve (e.g. anisotropic pairs switched on).
"""

from __future__ import annotations

from dataclasses import dataclass

# scale rounds always run (when the budget allows) and the tolerances of the scale rounds
SCALE_ROUNDS_MIN = 2
SCALE_ROUNDS_MAX = 8  # at most (`default --raw-imu` seed 7: 2 rounds 2.30 m, 4 1.61 m, 8 1.37 m)
SCALE_TOL = 0.005  # a round that moved no scale by more than this changed nothing
SCALE_EXTEND_MOVE = 0.03  # rounds continue while the last one moved some scale by more than this


@dataclass
class SolveSchedule:
    """State of the schedule across solves (module docstring). Use: after each solve call
    :meth:`scale_round_due`; if True run a round and report its largest move with :meth:`scale_done`;
    then :meth:`next_solve` with whether the sources changed and whether one of them asks for a first
    switch; it says whether to solve again."""

    outer_iterations: int
    estimate_scale: bool
    scale_rounds_max: int = SCALE_ROUNDS_MAX
    solves: int = 0  # solves done
    rounds: int = 0  # scale rounds done
    last_move: float = 0.0  # largest scale change of the last round
    budget: int = 0

    def __post_init__(self) -> None:
        self.budget = self.outer_iterations + (SCALE_ROUNDS_MIN if self.estimate_scale else 0)
        self._moved = False

    def solved(self) -> None:
        """Record a solve."""
        self.solves += 1
        self._moved = False

    @property
    def is_last(self) -> bool:
        return self.solves >= self.budget

    def _extending(self) -> bool:
        return (self.estimate_scale and SCALE_ROUNDS_MIN <= self.rounds < self.scale_rounds_max
                and self.last_move > SCALE_EXTEND_MOVE)

    def scale_round_due(self) -> bool:
        """Whether a scale round follows this solve."""
        return self.estimate_scale and ((not self.is_last and self.rounds < SCALE_ROUNDS_MIN) or self._extending())

    def scale_done(self, max_move: float) -> bool:
        """Record a scale round whose largest scale change was ``max_move``; returns whether it moved."""
        extending = self._extending()
        self.rounds += 1
        self.last_move = max_move
        self._moved = max_move > SCALE_TOL
        if extending and self._moved:
            self.budget += 1  # the rescaled graph is solved once more
        return self._moved

    def settling(self) -> bool:
        """Whether scale rounds are still to come (walks whose scale moves keep isotropic pairs meanwhile)."""
        return self.estimate_scale and (self.rounds < SCALE_ROUNDS_MIN or (
            self.rounds < self.scale_rounds_max and self.last_move > SCALE_EXTEND_MOVE))

    def next_solve(self, sources_changed: bool, first_switch: bool) -> bool:
        """After a solve (and its scale round, if any): solve again?"""
        if first_switch and self.is_last:
            self.budget += 1
        if self.is_last:
            return False
        return sources_changed or self._moved
