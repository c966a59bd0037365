"""The solve schedule (rmbuild/slam/schedule.py) on its own: no gtsam, no data."""

from __future__ import annotations

import pytest

from rmbuild.slam import schedule
from rmbuild.slam.schedule import SolveSchedule


def _run(s: SolveSchedule, changed: list[bool], moves: list[float], first_switch_at: int | None = None) -> list:
    """Drive the schedule: after solve i the sources report changed[i] and a due scale round moves[0..]."""
    trace, moves = [], list(moves)
    while True:
        s.solved()
        i = s.solves - 1
        did = s.scale_round_due()
        if did:
            s.scale_done(moves.pop(0) if moves else 0.0)
        trace.append(("scale" if did else "solve", s.settling()))
        if not s.next_solve(changed[min(i, len(changed) - 1)], first_switch_at == i):
            return trace


def test_without_scale_stops_when_nothing_changes_or_at_the_budget():
    s = SolveSchedule(outer_iterations=3, estimate_scale=False, scale_rounds_max=8)
    assert len(_run(s, [True, False], [])) == 2
    s = SolveSchedule(outer_iterations=3, estimate_scale=False, scale_rounds_max=8)
    assert len(_run(s, [True], [])) == 3  # the budget
    s = SolveSchedule(outer_iterations=1, estimate_scale=False, scale_rounds_max=8)
    assert len(_run(s, [True], [])) == 1  # the paper: one solve


def test_two_scale_rounds_then_extension_while_a_scale_moves():
    s = SolveSchedule(outer_iterations=3, estimate_scale=True, scale_rounds_max=8)
    # budget 5: rounds after solves 1 and 2; moves 0.10 and 0.05 keep extending past the budget
    trace = _run(s, [False], [0.10, 0.05, 0.04, 0.01])
    assert s.rounds == 4 and [t[0] for t in trace].count("scale") == 4
    assert trace[-1] == ("solve", False)  # the last solve has settled scales: anisotropy for every walk
    # a round that moved nothing (<= SCALE_TOL) and unchanged sources stop the solves
    s = SolveSchedule(outer_iterations=3, estimate_scale=True, scale_rounds_max=8)
    trace = _run(s, [False], [schedule.SCALE_TOL / 2])
    assert s.solves == 1 and s.rounds == 1


def test_extension_is_bounded_by_scale_rounds_max():
    s = SolveSchedule(outer_iterations=3, estimate_scale=True, scale_rounds_max=4)
    _run(s, [False], [0.2] * 10)
    assert s.rounds == 4


def test_first_switch_after_the_last_solve_adds_one():
    s = SolveSchedule(outer_iterations=2, estimate_scale=False, scale_rounds_max=8)
    assert len(_run(s, [True], [], first_switch_at=1)) == 3
    s = SolveSchedule(outer_iterations=2, estimate_scale=False, scale_rounds_max=8)
    assert len(_run(s, [True], [], first_switch_at=0)) == 2  # within the budget: nothing added


@pytest.mark.parametrize("rounds_max", [2, 8])
def test_settling_ends_with_the_rounds(rounds_max):
    s = SolveSchedule(outer_iterations=3, estimate_scale=True, scale_rounds_max=rounds_max)
    assert s.settling()
    _run(s, [False], [0.2] * 10)
    assert not s.settling()
