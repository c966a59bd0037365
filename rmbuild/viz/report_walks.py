"""The report's walk figure: the walks before and after optimize, each panel under the same kind of single
rigid fit that optimize's own figures use, so the picture and the numbers tell the same story.

Before: the raw dead reckoning, every walk from its own origin, moved by one SE(2) fitted on all walks
together (optimize's "raw" figures). After: the linked walks as optimize placed them, moved by one SE(2)
fitted on the linked walks (optimize's "optimised" figures), or as placed when the map is in the building's
frame (anchors, floor plan). A walk optimize could not link has no place in the map: it is drawn grey in
the before panel, left out of the after panel and named in the legend or caption as not linked.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from rmbuild.evaluate.trajectory import metric_alignment
from rmbuild.types import BUILDING_FRAME_GAUGES
from rmbuild.viz import figures
from rmbuild.viz.align import apply
from rmbuild.viz.colors import WALK_PALETTE, WALK_VALUE_CMAP

#: walks that name themselves in the legend; past this the per-walk table names them
LEGEND_WALKS = 12
#: unlinked walks named in the legend entry; past this it gives their number
NAMED_UNLINKED = 4


@dataclass
class WalkPanels:
    """The figure's panels (title, poses in the drawn frame), the fixes of each panel (or None), whether
    every panel is in the building frame, the optimiser-to-building transform (None when unknown or not
    needed) and the unlinked walks."""

    panels: list[tuple[str, pd.DataFrame]]
    fixes: list[pd.DataFrame | None]
    building: bool
    rt: Any
    unlinked: list[str]


def _fitted(poses: pd.DataFrame, ds: Any, fit_walks: list[str] | None) -> tuple[pd.DataFrame, Any]:
    """``poses`` moved by optimize's metric alignment (one SE(2) fitted on ``fit_walks``, all when None)."""
    r, t = metric_alignment(poses, ds, fit_walks)
    xy = apply((r, t), poses[["x_m", "y_m"]].to_numpy(dtype=float))
    out = poses.copy()
    out["x_m"], out["y_m"] = xy[:, 0], xy[:, 1]
    return out, (np.asarray(r), np.asarray(t))


def _reference(ds: Any, fixes: pd.DataFrame | None) -> str | None:
    """What the fits are fitted to: "the true paths", "the waypoints", or None (nothing to fit to)."""
    if ds.truth_poses is not None and len(ds.truth_poses) == len(ds.poses):
        return "the true paths"
    if fixes is not None and len(fixes) >= 2:
        return "the waypoints"
    return None


def walk_panels(ds: Any, opt: pd.DataFrame | None, walks: pd.DataFrame | None, gauge: str | None,
                fixes: pd.DataFrame | None) -> WalkPanels:
    """The before panel, and the after panel when optimize has run (``opt``: its poses; ``walks``: its
    per-walk table)."""
    ref = _reference(ds, fixes)
    unlinked = [] if walks is None else walks.loc[~walks["linked"].astype(bool), "walk_id"].astype(str).tolist()
    if ref is None:
        before = ("before: raw dead reckoning, every walk in its own frame from its own origin", ds.poses)
    else:
        before = (f"before: raw dead reckoning, every walk from its own origin; one rigid fit of all walks "
                  f"to {ref}", _fitted(ds.poses, ds, None)[0])
    out = WalkPanels([before], [fixes if ref else None], ref is not None, None, unlinked)
    if opt is None:
        return out
    linked = opt[~opt["walk_id"].astype(str).isin(unlinked)]
    if gauge in BUILDING_FRAME_GAUGES:
        by = "known anchor positions" if gauge == "anchors" else "the floor plan"
        after, building = (f"after: optimised, as placed in the building frame (fixed by {by})", linked), True
    elif ref is None:
        after, building = (f"after: optimised, in the frame of one walk (gauge {gauge})", linked), False
    else:
        fit_on = sorted(set(linked["walk_id"].astype(str))) or None
        moved, out.rt = _fitted(opt, ds, fit_on)
        after = (f"after: optimised; one rigid fit of the linked walks to {ref}",
                 moved[~moved["walk_id"].astype(str).isin(unlinked)])
        building = True
    out.panels.append(after)
    placed = None if fixes is None else fixes[~fixes["walk_id"].astype(str).isin(unlinked)]
    out.fixes.append(placed if building else None)
    out.building &= building
    return out


#: m; the predicted-error colour scale ends here (twice the 8 m a walk placed right lies within): past it a
#: walk is as doubtful as can be shown
ERROR_SCALE_TOP_M = 16.0


def walk_style(walk_order: list[str], walks: pd.DataFrame | None) -> figures.WalkStyle:
    """Colours that stay distinct: one palette colour per walk up to the palette's size (20); past it,
    optimize's predicted placement error on a colour-blind-safe scale (without optimize: the walk order).
    Walks optimize could not link are grey (not coloured) and one legend entry names them."""
    unlinked = [] if walks is None else walks.loc[~walks["linked"].astype(bool), "walk_id"].astype(str).tolist()
    placed = [w for w in walk_order if w not in set(unlinked)]
    if len(walk_order) <= len(WALK_PALETTE):
        base = figures.walk_style(walk_order)
        rgb = {w: base.rgb[w] for w in placed}
        legend: list[tuple[str, Any]] = [(w, rgb[w]) for w in placed] if len(walk_order) <= LEGEND_WALKS else []
        colorbar = None
    else:
        rgb, colorbar = _by_value(placed, walks)
        legend = []
    if unlinked:
        names = ", ".join(unlinked) if len(unlinked) <= NAMED_UNLINKED else f"{len(unlinked)} walks"
        legend.append((f"grey: not linked, not in the map ({names})", figures.UNPLACED_GREY))
    return figures.WalkStyle(rgb, legend, colorbar)


def _by_value(placed: list[str], walks: pd.DataFrame | None
              ) -> tuple[dict[str, tuple[float, float, float]], tuple[str, float, float, str]]:
    """Colours by optimize's predicted error (m) of each placed walk, or by walk order without it."""
    import matplotlib
    from matplotlib.colors import Normalize

    by_error = walks is not None and "predicted_error_m" in walks
    if walks is not None and by_error:
        pred = walks.set_index(walks["walk_id"].astype(str))["predicted_error_m"].astype(float)
        values = np.array([pred.get(w, np.nan) for w in placed], dtype=float)
        label = "optimize's predicted placement error (m)"
    else:
        values = np.arange(len(placed), dtype=float)
        label = "walk (input order)"
    finite = values[np.isfinite(values)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if by_error and hi > ERROR_SCALE_TOP_M:  # a few walks hundreds of metres off would
        hi = ERROR_SCALE_TOP_M                                    # leave every other walk one colour
        lo = min(lo, hi / 2)
        label = f"optimize's predicted placement error (m; top colour: {ERROR_SCALE_TOP_M:.0f} m or more)"
    cmap, norm = matplotlib.colormaps[WALK_VALUE_CMAP], Normalize(lo, hi if hi > lo else lo + 1.0, clip=True)
    rgb = {w: tuple(float(c) for c in cmap(norm(v))[:3]) if np.isfinite(v) else (0.45, 0.45, 0.45)
           for w, v in zip(placed, values)}
    return rgb, (WALK_VALUE_CMAP, lo, hi, label)  # type: ignore[return-value]


def walk_caption(wp: WalkPanels, style: figures.WalkStyle, opt_report: dict | None, truth: bool,
                 plan: bool, image: bool) -> str:
    """What the walk figure shows (only what is drawn), with optimize's own before / after figures it
    agrees with."""
    parts = ["Both panels: the same kind of single rigid fit optimize's figures use (no walk is fitted on "
             "its own)" if wp.building and len(wp.panels) > 1 else ""]
    parts.append("colour: optimize's predicted placement error of each walk (colour bar)" if style.colorbar
                 else "colour: one per walk")
    parts.append("dashed grey: ground truth" if truth else "no true paths to draw")
    n_fix = max((len(f) for f in wp.fixes if f is not None), default=0)
    if n_fix:
        parts.append(f"crosses: waypoints / position fixes ({n_fix}), in their walk's colour")
    if plan:
        parts.append("dark lines: floor plan" + ("; underneath: the plan's image" if image else ""))
    if wp.unlinked:
        shown = ", ".join(wp.unlinked[:8]) + (", ..." if len(wp.unlinked) > 8 else "")
        parts.append(f"light grey, before only: the {len(wp.unlinked)} walk(s) optimize could not link "
                     f"({shown}): their place is unknown, so they are not drawn after (the per-walk table lists "
                     "them)")
    text = "; ".join(p for p in parts if p) + "."
    figures_text = _error_text(opt_report)
    return text + (" " + figures_text if figures_text else "")


def _error_text(rep: dict | None) -> str:
    """optimize's landmark error / ATE before and after, as its report gives them."""
    if not rep:
        return ""
    raw, opt = rep.get("raw") or {}, rep.get("optimized") or {}
    lm_raw = (raw.get("landmark_error_m") or {}).get("mean")
    lm_opt = (opt.get("landmark_error_fitted_walks_m") or opt.get("landmark_error_m") or {}).get("mean")
    ate_raw = (raw.get("ate_m") or {}).get("rmse")
    ate_opt = (opt.get("ate_m") or {}).get("rmse")
    out = []
    if lm_raw is not None and lm_opt is not None:
        out.append(f"Landmark error (mean distance to the waypoints): {lm_raw:.1f} m before (all walks), "
                   f"{lm_opt:.1f} m after (linked walks)")
    if ate_raw is not None and ate_opt is not None:
        out.append(f"ATE (rmse against the true paths): {ate_raw:.2f} m before, {ate_opt:.2f} m after")
    return ("; ".join(out) + " (optimize/report.json).") if out else ""
