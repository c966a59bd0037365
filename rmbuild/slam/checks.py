"""Checks of a solution against the dead reckoning it was solved from.

A cost that only pulls similar-looking scans together can fold the map (walks crumpled onto each other):
the cost goes down while the map gets worse. Two checks catch it: the RMS of the odometry residuals (in
sigmas), and each walk's extent (RMS distance from its centroid) relative to its dead-reckoned extent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rmbuild import geometry
from rmbuild.config.optimize import OptimizeConfig
from rmbuild.slam.problem import WalkSet


@dataclass
class CheckResult:
    odometry_rms_sigma: float
    extent_ratio: np.ndarray  # (n_walks,) solved / dead-reckoned extent, NaN for walks that take no part
    rejected: bool
    warnings: list[str] = field(default_factory=list)


def check_solution(walks: WalkSet, poses: np.ndarray, raw_scaled: np.ndarray, cfg: OptimizeConfig) -> CheckResult:
    """Odometry residual RMS (sigmas) and per-walk extent ratios; ``rejected`` when the RMS exceeds
    ``solve.max_odometry_rms_sigma`` or the median walk shrank below ``solve.min_extent_ratio``."""
    o = cfg.odometry
    sig = np.array([o.sigma_x_m, o.sigma_y_m, 1 / np.sqrt(o.mu)])
    res = []
    extent = np.full(walks.n_walks, np.nan)
    for w in np.flatnonzero(walks.keep):
        s, e = walks.starts[w], walks.ends[w]
        du = geometry.increments(poses[s:e]) - geometry.increments(raw_scaled[s:e])
        du[:, 2] = geometry.wrap(du[:, 2])
        res.append(du / sig)
        er = geometry.extent_m(raw_scaled[s:e, :2])
        extent[w] = geometry.extent_m(poses[s:e, :2]) / er if er > 0 else 1.0
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2))) if res else 0.0
    out = CheckResult(rms, extent, False)
    scfg = cfg.solve
    if rms > scfg.max_odometry_rms_sigma:
        out.warnings.append(f"solution rejected: odometry residual RMS {rms:.1f} sigma > "
                            f"{scfg.max_odometry_rms_sigma}; initial poses returned")
        out.rejected = True
    for w in np.flatnonzero(extent < scfg.min_extent_ratio):
        out.warnings.append(f"walk {walks.walk_ids[w]} shrank to {extent[w]:.2f} of its raw PDR extent (folded?)")
    if np.nanmedian(extent) < scfg.min_extent_ratio and not out.rejected:
        out.warnings.append("solution rejected: the map shrank (median walk extent ratio "
                            f"{np.nanmedian(extent):.2f}); initial poses returned")
        out.rejected = True
    return out
