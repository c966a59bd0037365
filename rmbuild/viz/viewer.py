"""The viewer contract: what a stage may log while it runs, and a viewer that logs nothing.

:class:`Viewer` lists every method explicitly; :class:`rmbuild.viz.rerun_bridge.RerunViewer` implements it
with rerun, :class:`NullViewer` with no-ops (a test checks that the three method sets agree, so a misspelt
call fails whether viewing is on or off). Stages call their viewer unconditionally; code that would read
data only to log it asks ``viewer.enabled`` first. Nothing here imports rerun.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import pandas as pd

#: default caps of the logging methods (keep recordings small and quick to log)
MAX_VICINITY_LINES = 3000
MAX_TENSOR_APS = 256
STRONGEST_APS = 6
#: the building-frame transform applies to these entity groups (see RerunViewer.log_alignment)
ALIGNED_PARTS = ("optimized", "initial", "vicinity", "map")


@dataclass(frozen=True)
class ViewTarget:
    """Where a recording goes: ``mode`` "save" (``path`` is the .rrd), "spawn" (native viewer on rerun's
    default port) or "serve" (web viewer on localhost: ``port`` for the web page, gRPC on ``port`` + 1)."""

    mode: str
    path: Path | None = None
    port: int = 9090

    def __post_init__(self) -> None:
        if self.mode not in ("save", "spawn", "serve"):
            raise ValueError(f"unknown view mode {self.mode!r}")
        if self.mode == "save" and self.path is None:
            raise ValueError("save needs a path")


@runtime_checkable
class Viewer(Protocol):
    """What stages and ``rmbuild view`` log. ``enabled``: False for the do-nothing viewer."""

    @property
    def enabled(self) -> bool: ...

    @property
    def target(self) -> ViewTarget | None: ...

    @property
    def counts(self) -> dict[str, int]: ...

    def __enter__(self) -> Viewer: ...

    def __exit__(self, exc_type: object, *exc: object) -> None: ...

    def flush(self) -> None: ...

    def close(self, keep: bool = True) -> Path | None: ...

    def set_walks(self, walk_ids: Sequence[str]) -> None: ...

    def log_raw_walks(self, poses: pd.DataFrame) -> None: ...

    def log_truth(self, truth_poses: pd.DataFrame) -> None: ...

    def log_optimized(self, poses: pd.DataFrame, kind: str = "optimized") -> None: ...

    def log_venue(self, venue: dict | None) -> None: ...

    def log_plan_image(self, pixels: np.ndarray, extent_m: Sequence[float]) -> None: ...

    def log_fixes(self, fixes: pd.DataFrame) -> None: ...

    def log_alignment(self, theta_rad: float, translation_xy: Sequence[float] | np.ndarray,
                      parts: Sequence[str] = ALIGNED_PARTS) -> None: ...

    def log_vicinity(self, pairs: pd.DataFrame, node_xy: np.ndarray, max_lines: int = MAX_VICINITY_LINES,
                     error_scale: float | None = None, seed: int = 0) -> int: ...

    def log_cost_history(self, cost: Sequence[float] | np.ndarray, iteration: np.ndarray | None = None) -> None: ...

    def log_cost(self, iteration: int, cost: float) -> None: ...

    def log_residuals(self, raw: pd.DataFrame, optimized: pd.DataFrame, pairs: pd.DataFrame | None) -> None: ...

    def log_radiomap(self, cells: pd.DataFrame, cell_size_m: float | None = None,
                     origin_xy_m: Sequence[float] | None = None, strongest: int = STRONGEST_APS,
                     max_aps: int = MAX_TENSOR_APS) -> None: ...

    def log_tracks(self, tracks: pd.DataFrame) -> int: ...

    def log_particles(self, localizer: str, scan: int, xy: np.ndarray, weights: np.ndarray | None = None,
                      xi: float | None = None) -> None: ...


class NullViewer:
    """Stands in when viewing is off: every method of :class:`Viewer`, doing nothing."""

    enabled = False
    target: ViewTarget | None = None

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def __enter__(self) -> NullViewer:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close()

    def flush(self) -> None:
        pass

    def close(self, keep: bool = True) -> Path | None:
        return None

    def set_walks(self, walk_ids: Sequence[str]) -> None:
        pass

    def log_raw_walks(self, poses: pd.DataFrame) -> None:
        pass

    def log_truth(self, truth_poses: pd.DataFrame) -> None:
        pass

    def log_optimized(self, poses: pd.DataFrame, kind: str = "optimized") -> None:
        pass

    def log_venue(self, venue: dict | None) -> None:
        pass

    def log_plan_image(self, pixels: np.ndarray, extent_m: Sequence[float]) -> None:
        pass

    def log_fixes(self, fixes: pd.DataFrame) -> None:
        pass

    def log_alignment(self, theta_rad: float, translation_xy: Sequence[float] | np.ndarray,
                      parts: Sequence[str] = ALIGNED_PARTS) -> None:
        pass

    def log_vicinity(self, pairs: pd.DataFrame, node_xy: np.ndarray, max_lines: int = MAX_VICINITY_LINES,
                     error_scale: float | None = None, seed: int = 0) -> int:
        return 0

    def log_cost_history(self, cost: Sequence[float] | np.ndarray, iteration: np.ndarray | None = None) -> None:
        pass

    def log_cost(self, iteration: int, cost: float) -> None:
        pass

    def log_residuals(self, raw: pd.DataFrame, optimized: pd.DataFrame, pairs: pd.DataFrame | None) -> None:
        pass

    def log_radiomap(self, cells: pd.DataFrame, cell_size_m: float | None = None,
                     origin_xy_m: Sequence[float] | None = None, strongest: int = STRONGEST_APS,
                     max_aps: int = MAX_TENSOR_APS) -> None:
        pass

    def log_tracks(self, tracks: pd.DataFrame) -> int:
        return 0

    def log_particles(self, localizer: str, scan: int, xy: np.ndarray, weights: np.ndarray | None = None,
                      xi: float | None = None) -> None:
        pass


def ensure_viewer(viewer: Viewer | None) -> Viewer:
    """``viewer`` itself, or a :class:`NullViewer` when None."""
    return NullViewer() if viewer is None else viewer
