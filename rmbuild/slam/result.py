"""What :func:`rmbuild.slam.optimize` returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from rmbuild.types import OptimizeState


@dataclass
class OptimizeResult:
    """What :func:`rmbuild.slam.optimize` returns (a full or an incremental run).

    ``poses`` / ``initial_poses``: walk_id, step, t_s, x_m, y_m, heading_rad in the common frame (the
    reference walk's own frame, or the building frame with anchors), and ``linked`` (the walk is placed in
    that frame, by evidence or by anchors; an unlinked walk's poses are in a frame of their own), rows as
    ``dataset.poses``.
    ``pairs``: the vicinity factors of the final solve: node_k, node_q, walk_k, walk_q, kind, rss_dist,
    common, init_dist_m, final_dist_m, final_error (eq. 10 e), in_range (d < d_max at the end), injected,
    anisotropic (an along/across factor).
    ``candidates``: every pair the search produced (before verification), with ``used`` and ``injected``.
    ``walks``: per walk (:func:`rmbuild.slam.report.walk_table`).
    ``placement_log``: one row per walk-to-map fit the placement tried (phase, round, walk, accepted, ...).
    ``solve_starts``: index into ``cost_history`` of each solve's first entry.
    ``state``: what later stages need (:class:`rmbuild.types.OptimizeState`, written as optimize/state.json).
    ``stats``: factor counts, costs, iterations, time_s per phase, cost_history, warnings, ... (JSON-able).
    """

    poses: pd.DataFrame
    initial_poses: pd.DataFrame
    pairs: pd.DataFrame
    candidates: pd.DataFrame
    walks: pd.DataFrame
    stats: dict
    state: OptimizeState
    cost_history: list[float] = field(default_factory=list)
    placement_log: pd.DataFrame = field(default_factory=pd.DataFrame)
    solve_starts: list[int] = field(default_factory=list)
