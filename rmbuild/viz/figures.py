"""Every matplotlib figure rmbuild writes: the export-map pictures, evaluate's CDF and the report's figures.

One heat-map renderer (:func:`heatmaps_figure`, also behind :func:`coverage_figure`) and one CDF renderer
(:func:`cdf_figure`), so a picture of the same thing looks the same wherever it appears. Each function
builds a :class:`matplotlib.figure.Figure` directly (no pyplot state, no display needed) with constrained
layout (titles and colour bars are never cut off) and returns it; the caller saves it. Every axis carries
a label with its unit. Colour limits come from the data drawn (a -13 dBm peak shows as -13 dBm).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from rmbuild.viz.colors import LINE_COLORS, SEQUENTIAL_CMAP, walk_color

#: Line style of each map in a CDF (colour tells the localizer): built solid, surveyed dashed, raw dotted.
MAP_LINE_STYLES = {"built": "-", "surveyed": "--", "raw": ":"}
#: Error marks drawn on CDFs (m): the 5 m / 10 m thresholds the evaluate table reports (<5m, <10m).
CDF_MARKS_M = (5.0, 10.0)
#: Scans-per-cell colour bars switch to a log scale from this many scans (a few busy cells would flatten
#: a linear scale).
LOG_COUNT_FROM = 20
_XY_LABELS = ("x (m)", "y (m)")


def _wrapped(text: str, width_in: float) -> str:
    """``text`` broken into lines that fit an axes ``width_in`` inches wide at the titles' 10 pt (constrained
    layout makes room for the lines; it does not shorten a line wider than the figure)."""
    import textwrap

    return textwrap.fill(text, width=max(int(width_in * 13), 30))


def _frame_words(frame: str) -> str:
    return f"frame of walk {frame[5:]}" if frame.startswith("walk:") else f"{frame} frame"


def _figure(width_in: float, height_in: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def _cmap() -> Any:
    import matplotlib

    return matplotlib.colormaps[SEQUENTIAL_CMAP]


def _rgb(i: int) -> tuple[float, float, float]:
    r, g, b = walk_color(i)
    return r / 255, g / 255, b / 255


def walls_array(walls: Any) -> np.ndarray | None:
    """Wall segments as float (n, 4) x0, y0, x1, y1 (m) from an array-like or a venue dict with "walls";
    None when there are none."""
    if walls is None:
        return None
    if isinstance(walls, dict):
        walls = walls.get("walls")
        if walls is None:
            return None
    a = np.asarray(walls, dtype=float).reshape(-1, 4) if len(walls) else np.zeros((0, 4))
    return a if len(a) else None


def _walls(ax: Any, walls: np.ndarray | None, color: str = "0.25") -> None:
    if walls is None or len(walls) == 0:
        return
    from matplotlib.collections import LineCollection

    ax.add_collection(LineCollection(list(walls.reshape(-1, 2, 2)), colors=color, linewidths=0.9, zorder=2))


def _xy_axes(ax: Any, left: bool = True, bottom: bool = True) -> None:
    ax.set_aspect("equal")
    if bottom:
        ax.set_xlabel(_XY_LABELS[0])
    if left:
        ax.set_ylabel(_XY_LABELS[1])
    ax.tick_params(labelsize=7)


# ------------------------------------------------------------------ grids
def _cell_size(cells: pd.DataFrame) -> float:
    """The grid step (m) of a cell table with ix and x_m (1 m when it cannot be told)."""
    for i, c in (("ix", "x_m"), ("iy", "y_m")):
        d = cells.drop_duplicates(i)
        if len(d) > 1:
            di = np.diff(d.sort_values(i)[i].to_numpy(dtype=float))
            dx = np.diff(d.sort_values(i)[c].to_numpy(dtype=float))
            s = dx / di
            s = s[np.isfinite(s) & (s > 0)]
            if s.size:
                return float(np.median(s))
    return 1.0


class Grid:
    """The raster of a cell table (ix, iy, x_m, y_m: cell index and centre in the map frame, m)."""

    def __init__(self, cells: pd.DataFrame, cell_size_m: float | None = None):
        self.s = float(cell_size_m or _cell_size(cells))
        ix = cells["ix"].to_numpy(dtype=np.int64)
        iy = cells["iy"].to_numpy(dtype=np.int64)
        self.ix0, self.iy0 = int(ix.min()), int(iy.min())
        self.shape = (int(iy.max()) - self.iy0 + 1, int(ix.max()) - self.ix0 + 1)
        # cell centre = origin + (i + 0.5) * s: the origin from any row
        ox = float(np.median(cells["x_m"].to_numpy(dtype=float) - (ix + 0.5) * self.s))
        oy = float(np.median(cells["y_m"].to_numpy(dtype=float) - (iy + 0.5) * self.s))
        self.extent = (ox + self.ix0 * self.s, ox + (self.ix0 + self.shape[1]) * self.s,
                       oy + self.iy0 * self.s, oy + (self.iy0 + self.shape[0]) * self.s)

    def image(self, cells: pd.DataFrame, values: np.ndarray) -> np.ndarray:
        """float (rows, cols) image: ``values`` at the cells' (iy, ix), NaN elsewhere."""
        img = np.full(self.shape, np.nan)
        img[cells["iy"].to_numpy(dtype=np.int64) - self.iy0, cells["ix"].to_numpy(dtype=np.int64) - self.ix0] = values
        return img


def _plan_image(ax: Any, image: tuple[np.ndarray, Sequence[float]] | None, alpha: float = 0.45) -> None:
    """The plan's raster (pixels, extent x0, y0, x1, y1 m; row 0 the top) faded under everything else."""
    if image is None:
        return
    x0, y0, x1, y1 = image[1]
    ax.imshow(image[0], extent=(x0, x1, y0, y1), origin="upper", alpha=alpha, zorder=-1, interpolation="bilinear")


def _draw_grid(ax: Any, grid: Grid, img: np.ndarray, norm: Any, walls: np.ndarray | None,
               fixes_xy: np.ndarray | None = None, image: tuple[np.ndarray, Sequence[float]] | None = None) -> Any:
    _plan_image(ax, image)
    im = ax.imshow(img, origin="lower", extent=grid.extent, cmap=_cmap(), norm=norm, interpolation="nearest",
                   zorder=0)
    _walls(ax, walls)
    if fixes_xy is not None and len(fixes_xy):
        ax.scatter(fixes_xy[:, 0], fixes_xy[:, 1], s=3, marker="o", color="0.55", lw=0, zorder=1)
    ax.set_xlim(grid.extent[0], grid.extent[1])
    ax.set_ylim(grid.extent[2], grid.extent[3])
    return im


def _data_norm(values: np.ndarray) -> Any:
    """A linear colour scale over the finite values' full range (no clipping)."""
    from matplotlib.colors import Normalize

    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return Normalize(-100.0, -30.0)
    lo, hi = float(v.min()), float(v.max())
    return Normalize(lo, hi if hi > lo else lo + 1.0)


def radio_keys(bssid: str) -> tuple[str, ...]:
    """Keys shared by the virtual BSSIDs of one radio: an access point announces several networks from one
    radio with MACs that differ in the first octet (the locally administered variants) or in the last hex
    digit. A BSSID that is not a MAC address is a radio of its own."""
    octets = bssid.lower().replace("-", ":").split(":")
    if len(octets) != 6 or not all(len(o) == 2 for o in octets):
        return (bssid,)
    return (":".join(octets[1:]), ":".join(octets[:5]) + ":" + octets[5][0])


def strongest_aps(cells: pd.DataFrame, top_n: int) -> pd.Series:
    """The ``top_n`` APs with the highest peak cell mean (dBm), strongest first (ties: first seen), one per
    radio (:func:`radio_keys`: its other virtual BSSIDs map the same signal)."""
    peak = cells.groupby("bssid", sort=False)["rssi_mean_dbm"].max().dropna()
    peak = peak.sort_values(ascending=False, kind="stable")
    seen: set[str] = set()
    keep: list[bool] = []
    for ap in peak.index:
        keys = radio_keys(str(ap))
        keep.append(not seen.intersection(keys))
        seen.update(keys)
    return peak[np.array(keep, dtype=bool)].iloc[:top_n]


def heatmaps_figure(cells: pd.DataFrame, top_n: int = 6, walls: Any = None, cell_size_m: float | None = None,
                    fixes_xy: np.ndarray | None = None, image: tuple[np.ndarray, Sequence[float]] | None = None) -> Any:
    """Mean RSSI per cell of the ``top_n`` APs with the highest peak cell mean, one panel each, one colour
    scale over the full range of what is drawn.

    ``cells``: the radio map's long table (ix, iy, x_m, y_m, bssid, rssi_mean_dbm, ...; x_m, y_m cell
    centres in the map frame); ``walls`` (n, 4) m, ``fixes_xy`` (n, 2) m and the plan's ``image`` (pixels,
    extent m) in that frame. None without data.
    """
    need = {"ix", "iy", "bssid", "rssi_mean_dbm", "x_m", "y_m"}
    if cells is None or len(cells) == 0 or not need <= set(cells.columns):
        return None
    peak = strongest_aps(cells, top_n)
    if peak.empty:
        return None
    grid = Grid(cells, cell_size_m)
    shown = cells[cells["bssid"].isin(peak.index)]
    norm = _data_norm(shown["rssi_mean_dbm"].to_numpy(dtype=float))
    ncol = min(3, len(peak))
    nrow = int(np.ceil(len(peak) / ncol))
    aspect = (grid.extent[3] - grid.extent[2]) / max(grid.extent[1] - grid.extent[0], 1e-9)
    fig = _figure(3.9 * ncol + 0.9, (3.9 * min(max(aspect, 0.4), 1.6)) * nrow + 0.6)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    im = None
    for k, (ax, (ap, pk)) in enumerate(zip(axes.flat, peak.items())):
        g = shown[shown["bssid"] == ap]
        im = _draw_grid(ax, grid, grid.image(g, g["rssi_mean_dbm"].to_numpy(dtype=float)), norm,
                        walls_array(walls), fixes_xy, image)
        ax.set_title(f"{ap} (peak {pk:.0f} dBm)", fontsize=9)
        _xy_axes(ax, left=k % ncol == 0, bottom=k // ncol == nrow - 1 or k + ncol >= len(peak))
    for ax in list(axes.flat)[len(peak):]:
        ax.set_axis_off()
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.85, label="mean RSSI (dBm)")
    fig.suptitle(f"the {len(peak)} strongest radios: mean RSSI per {grid.s:g} m cell", fontsize=11)
    return fig


def _bounds(grid: Grid, walls: np.ndarray | None, image: tuple[np.ndarray, Sequence[float]] | None
            ) -> tuple[float, float, float, float]:
    """x0, x1, y0, y1 (m) holding the grid, the walls and the plan's image: the whole plan, not only the
    part the map covers."""
    xs, ys = [grid.extent[0], grid.extent[1]], [grid.extent[2], grid.extent[3]]
    if walls is not None and len(walls):
        xs += [float(walls[:, [0, 2]].min()), float(walls[:, [0, 2]].max())]
        ys += [float(walls[:, [1, 3]].min()), float(walls[:, [1, 3]].max())]
    if image is not None:
        x0, y0, x1, y1 = image[1]
        xs += [x0, x1]
        ys += [y0, y1]
    return min(xs), max(xs), min(ys), max(ys)


def coverage_figure(cells: pd.DataFrame, cell_size_m: float | None = None, walls: Any = None,
                    frame: str | None = None, image: tuple[np.ndarray, Sequence[float]] | None = None) -> Any:
    """Scans per visited cell (same colour map as the heat maps; log scale from :data:`LOG_COUNT_FROM`
    scans), cells filled by interpolation in grey, over the plan's ``image`` (pixels, extent m) when given;
    the axes span the whole plan (walls and image), so what the map does not cover shows.
    ``cells``: ix, iy, x_m, y_m, n_scans, interpolated."""
    from matplotlib.colors import LogNorm, Normalize

    grid = Grid(cells, cell_size_m)
    walls = walls_array(walls)
    x0, x1, y0, y1 = _bounds(grid, walls, image)
    n = cells["n_scans"].to_numpy(dtype=float)
    interp = cells["interpolated"].to_numpy(dtype=bool) if "interpolated" in cells else np.zeros(len(cells), bool)
    img = grid.image(cells, np.where(interp, np.nan, n))
    vmax = max(float(np.nanmax(img)) if np.isfinite(img).any() else 1.0, 1.0)
    norm = LogNorm(1, vmax) if vmax >= LOG_COUNT_FROM else Normalize(0, vmax)
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig = _figure(7.5, 1.2 + 6.0 * min(max(aspect, 0.4), 1.6))
    ax = fig.subplots()
    if interp.any():
        ax.imshow(grid.image(cells, np.where(interp, 1.0, np.nan)), origin="lower", extent=grid.extent,
                  cmap="Greys", vmin=0, vmax=4, interpolation="nearest", zorder=0)
    im = _draw_grid(ax, grid, img, norm, walls, image=image)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    fig.colorbar(im, ax=ax, label="scans per cell", shrink=0.85)
    _xy_axes(ax)
    ax.set_title(_wrapped(f"coverage: {int((~interp).sum())} visited cells"
                          + (f" + {int(interp.sum())} filled (grey)" if interp.any() else "")
                          + f", {grid.s:g} m grid" + (f", {_frame_words(frame)}" if frame else ""), 6.0),
                 fontsize=10)
    return fig


# ------------------------------------------------------------------ CDFs
def cdf_figure(errors: Mapping[str, np.ndarray], title: str = "localization error CDF") -> Any:
    """Empirical CDFs (``Axes.ecdf``) of per-scan position errors (m), one curve per label.

    A label "map / localizer" gets the localizer's colour and the map's line style
    (:data:`MAP_LINE_STYLES`), so the same localizer on two maps is one colour; other labels one colour each.
    """
    fig = _figure(7.8, 4.8)
    ax = fig.subplots()
    colours: dict[str, str] = {}
    for label, e in errors.items():
        e = np.asarray(e, dtype=float)
        e = e[np.isfinite(e)]
        if e.size == 0:
            continue
        map_name, _, loc = label.rpartition(" / ")
        c = colours.setdefault(loc, LINE_COLORS[len(colours) % len(LINE_COLORS)])
        ax.ecdf(e, color=c, ls=MAP_LINE_STYLES.get(map_name, "-"), lw=1.4,
                label=f"{label}: median {np.median(e):.1f} m, n = {e.size}")
    for x in CDF_MARKS_M:
        ax.axvline(x, color="0.8", lw=0.8, zorder=0)
    ax.set_xlabel("position error (m)")
    ax.set_ylabel("fraction of test scans")
    ax.set_ylim(0, 1.01)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.set_title(_wrapped(title, 7.0), fontsize=10)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7.5, loc="lower right")
    return fig


# ------------------------------------------------------------------ walks and the optimiser
@dataclass(frozen=True)
class WalkStyle:
    """How the walks are coloured: ``rgb`` walk_id -> colour (0-1) of each walk drawn in colour (a walk
    without one is drawn thin and light grey: not placed); ``legend`` (label, colour) entries; ``colorbar``
    (colour map name, vmin, vmax, label) when the colours stand for a value rather than a walk."""

    rgb: Mapping[str, tuple[float, float, float]]
    legend: Sequence[tuple[str, Any]] = ()
    colorbar: tuple[str, float, float, str] | None = None


#: the light grey of walks not placed in the map
UNPLACED_GREY = "0.72"


def walk_style(walk_order: Sequence[str]) -> WalkStyle:
    """One palette colour per walk (:data:`rmbuild.viz.colors.WALK_PALETTE`, cycled), named in the legend
    when there are at most 12."""
    rgb = {str(w): _rgb(i) for i, w in enumerate(walk_order)}
    legend = [(w, c) for w, c in rgb.items()] if len(rgb) <= 12 else []
    return WalkStyle(rgb, legend)


def walks_figure(panels: Sequence[tuple[str, pd.DataFrame]], style: WalkStyle | Sequence[str],
                 truth: pd.DataFrame | None = None, walls: np.ndarray | None = None,
                 fixes: Sequence[pd.DataFrame | None] | None = None,
                 image: tuple[np.ndarray, Sequence[float]] | None = None) -> Any:
    """One panel per (title, poses) — poses with walk_id, x_m, y_m — over the floor plan (walls (n, 4) m;
    ``image``: its raster (pixels, extent x0, y0, x1, y1 m), faded) and the true paths (thin dashed grey)
    when known, coloured by ``style`` (a :class:`WalkStyle`, or the walk order: one colour per walk).
    ``fixes``: per panel, the waypoints / position fixes (walk_id, x_m, y_m) in that panel's frame, or None
    when they cannot be placed there; drawn as crosses in their walk's colour."""
    style = style if isinstance(style, WalkStyle) else walk_style(style)
    fig = _figure(6.2 * len(panels), 5.6 + (0.5 if style.legend else 0))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    any_fix = False
    for k, (ax, (title, poses)) in enumerate(zip(axes, panels)):
        _plan_image(ax, image)
        _walls(ax, walls, color="0.45")
        if truth is not None:
            for _, g in truth.groupby("walk_id", sort=False):
                ax.plot(g["x_m"], g["y_m"], color="0.6", lw=0.7, ls="--", zorder=2)
        for wid, g in poses.groupby("walk_id", sort=False):
            c = style.rgb.get(str(wid))
            ax.plot(g["x_m"], g["y_m"], color=UNPLACED_GREY if c is None else c, lw=0.7 if c is None else 1.1,
                    zorder=2.5 if c is None else 3)
        fx = fixes[k] if fixes is not None and k < len(fixes) else None
        if fx is not None and len(fx):
            any_fix = True
            cols = [style.rgb.get(str(w), UNPLACED_GREY) for w in fx["walk_id"]]
            ax.scatter(fx["x_m"], fx["y_m"], s=22, marker="x", c=cols, lw=1.0, zorder=4)
        ax.set_title(_wrapped(title, 5.4), fontsize=10)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(_XY_LABELS[0])
        ax.set_ylabel(_XY_LABELS[1])
        ax.grid(alpha=0.2)
    _walks_legend(fig, axes, style, truth is not None, any_fix)
    return fig


def _walks_legend(fig: Any, axes: Any, style: WalkStyle, truth: bool, fixes: bool) -> None:
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=c, label=label) for label, c in style.legend]
    if truth:
        handles.append(Line2D([], [], color="0.6", ls="--", label="truth"))
    if fixes:
        handles.append(Line2D([], [], color="0.2", marker="x", ls="", label="waypoints / fixes"))
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 6), fontsize=8,
                   frameon=False)
    if style.colorbar is not None:
        import matplotlib
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        name, lo, hi, label = style.colorbar
        sm = ScalarMappable(Normalize(lo, hi if hi > lo else lo + 1.0), matplotlib.colormaps[name])
        fig.colorbar(sm, ax=list(axes), shrink=0.8, label=label)


def cost_figure(cost: np.ndarray, solve: np.ndarray | None = None) -> Any:
    """The optimiser's cost per iteration (log scale when positive); with ``solve`` (the solve of each
    iteration) each solve is its own line and a dotted line marks where the next one starts."""
    fig = _figure(6.4, 3.4)
    ax = fig.subplots()
    c = np.asarray(cost, dtype=float)
    sv = np.zeros(c.size, dtype=np.int64) if solve is None else np.asarray(solve, dtype=np.int64)
    for k in np.unique(sv):
        idx = np.flatnonzero(sv == k)
        ax.plot(idx, c[idx], marker="o", ms=3, color=LINE_COLORS[0])
        if k > sv.min():
            ax.axvline(idx[0] - 0.5, color="0.5", ls=":", lw=1)
    n_solves = int(sv.max() - sv.min() + 1) if sv.size else 1
    if c.size and np.all(c[np.isfinite(c)] > 0):
        ax.set_yscale("log")
    ax.set_xlabel("iteration, all solves in order" + ("; dotted: a new solve with new factors" if n_solves > 1
                                                       else ""))
    ax.set_ylabel("cost (factor-graph error)")
    ax.grid(alpha=0.3)
    ax.set_title("optimiser cost per Levenberg-Marquardt iteration"
                 + (f", {n_solves} solves" if n_solves > 1 else ""), fontsize=10)
    return fig


def rf_model_figure(model: Mapping[str, float], exponent_auc: Mapping[str, float] | None = None,
                    exponent: float | None = None) -> Any:
    """The data set's RF model (``optimize.json`` vicinity.rf_model): the cross-walk RSS distance of near and
    of far scan pairs as two Gaussians and the distance where they are equally likely; with
    ``exponent_auc`` a second panel: each powed exponent's within-walk near/far AUC, the one used marked."""
    fig = _figure(9.6 if exponent_auc else 6.4, 3.4)
    axes = fig.subplots(1, 2 if exponent_auc else 1, squeeze=False)[0]
    ax = axes[0]
    mu = (float(model["near_mu"]), float(model["far_mu"]))
    sd = (float(model["near_sigma"]), float(model["far_sigma"]))
    r = np.linspace(max(0.0, mu[0] - 4 * sd[0]), mu[1] + 4 * sd[1], 300)
    for (m, s), label, color in zip(zip(mu, sd), ("near (< 5 m)", "far (15-30 m)"), LINE_COLORS[:2]):
        ax.plot(r, np.exp(-0.5 * ((r - m) / s) ** 2) / (s * np.sqrt(2 * np.pi)), color=color, label=label)
    if "threshold_db" in model:
        ax.axvline(float(model["threshold_db"]), color="0.3", ls="--", lw=1, label="equally likely")
    ax.set_xlabel("RSS distance between two walks' scans (dB)")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(f"RF model (calibrated on {int(model.get('n_near', 0))} / {int(model.get('n_far', 0))} "
                 "same-walk pairs)", fontsize=10)
    if exponent_auc:
        ax2 = axes[1]
        betas = [float(b) for b in exponent_auc]
        ax2.plot(betas, list(exponent_auc.values()), marker="o", color=LINE_COLORS[0])
        if exponent is not None:
            ax2.axvline(float(exponent), color="0.3", ls="--", lw=1, label=f"used: β = {exponent:g}")
            ax2.legend(fontsize=8)
        ax2.set_xlabel("powed exponent β")
        ax2.set_ylabel("near / far AUC, same-walk pairs")
        ax2.grid(alpha=0.3)
        ax2.set_title("how well each β tells near from far", fontsize=10)
    return fig
