"""matplotlib figures of the report (Agg backend; each function returns a Figure, the caller saves it)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from rmbuild.viz.colors import walk_color


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _rgb(i: int) -> tuple[float, float, float]:
    r, g, b = walk_color(i)
    return r / 255, g / 255, b / 255


def _walls(ax, walls: np.ndarray | None) -> None:
    if walls is None or len(walls) == 0:
        return
    from matplotlib.collections import LineCollection

    ax.add_collection(LineCollection(list(walls.reshape(-1, 2, 2)), colors="0.35", linewidths=1.2, zorder=1))


def _paths(ax, poses: pd.DataFrame, order: dict[str, int], **kw) -> None:
    for wid, g in poses.groupby("walk_id", sort=False):
        ax.plot(g["x_m"], g["y_m"], color=_rgb(order.get(str(wid), 0)), lw=1.1, zorder=3, **kw)


def walks_figure(panels: Sequence[tuple[str, pd.DataFrame]], walk_order: Sequence[str],
                 truth: pd.DataFrame | None = None, walls: np.ndarray | None = None):
    """One panel per (title, poses) — poses with walk_id, x_m, y_m in the frame of ``walls``/``truth`` —
    over the floor plan (walls (n, 4) m) and the true paths (thin grey) when known; one colour per walk."""
    plt = _plt()
    order = {str(w): i for i, w in enumerate(walk_order)}
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 5.2), squeeze=False)
    for ax, (title, poses) in zip(axes[0], panels):
        _walls(ax, walls)
        if truth is not None:
            for _, g in truth.groupby("walk_id", sort=False):
                ax.plot(g["x_m"], g["y_m"], color="0.6", lw=0.7, ls="--", zorder=2)
        _paths(ax, poses, order)
        ax.set_title(title, fontsize=10)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(alpha=0.2)
    if len(walk_order) <= 12:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color=_rgb(i), label=str(w)) for i, w in enumerate(walk_order)]
        if truth is not None:
            handles.append(Line2D([], [], color="0.6", ls="--", label="truth"))
        fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 7), fontsize=8, frameon=False)
        fig.subplots_adjust(bottom=0.2)
    fig.tight_layout(rect=(0, 0.08 if len(walk_order) <= 12 else 0, 1, 1))
    return fig


def heatmaps_figure(cells: pd.DataFrame, top_n: int = 6, walls_map_frame: np.ndarray | None = None,
                    cell_size_m: float | None = None):
    """Mean RSSI per cell of the ``top_n`` APs with the highest peak cell mean, one panel each.

    ``cells``: the radio map's long table (ix, iy, x_m, y_m, bssid, rssi_mean_dbm, ...); x_m, y_m are cell
    centres in the map frame; ``walls_map_frame`` (n, 4) m in that frame. Returns None without data.
    """
    if cells is None or len(cells) == 0 or not {"bssid", "rssi_mean_dbm", "x_m", "y_m"} <= set(cells.columns):
        return None
    plt = _plt()
    peak = cells.groupby("bssid")["rssi_mean_dbm"].max().sort_values(ascending=False, kind="stable")
    aps = list(peak.index[:top_n])
    if not aps:
        return None
    s = cell_size_m or _cell_size(cells)
    x_all, y_all = cells["x_m"].to_numpy(dtype=float), cells["y_m"].to_numpy(dtype=float)
    x0, y0 = np.nanmin(x_all) - s / 2, np.nanmin(y_all) - s / 2
    nx = int(round((np.nanmax(x_all) + s / 2 - x0) / s))
    ny = int(round((np.nanmax(y_all) + s / 2 - y0) / s))
    ncol = min(3, len(aps))
    nrow = int(np.ceil(len(aps) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.9 * nrow), squeeze=False)
    im = None
    for ax, ap in zip(axes.flat, aps):
        g = cells[cells["bssid"] == ap]
        img = np.full((ny, nx), np.nan)
        c = np.clip(((g["x_m"].to_numpy(dtype=float) - x0) / s).astype(int), 0, nx - 1)
        r = np.clip(((g["y_m"].to_numpy(dtype=float) - y0) / s).astype(int), 0, ny - 1)
        img[r, c] = g["rssi_mean_dbm"].to_numpy(dtype=float)
        im = ax.imshow(img, origin="lower", extent=(x0, x0 + nx * s, y0, y0 + ny * s), cmap="viridis",
                       vmin=-100, vmax=-30, interpolation="nearest", zorder=0)
        _walls(ax, walls_map_frame)
        ax.set_title(f"{ap}  (peak {peak[ap]:.0f} dBm)", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(x0, x0 + nx * s)
        ax.set_ylim(y0, y0 + ny * s)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(aps):]:
        ax.axis("off")
    fig.tight_layout()
    if im is not None:
        fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="mean RSSI (dBm)")
    return fig


def _cell_size(cells: pd.DataFrame) -> float:
    if "ix" in cells and cells["ix"].nunique() > 1:
        d = cells.drop_duplicates("ix").sort_values("ix")
        dx = np.diff(d["x_m"].to_numpy(dtype=float)) / np.diff(d["ix"].to_numpy(dtype=float))
        dx = dx[np.isfinite(dx) & (dx > 0)]
        if dx.size:
            return float(np.median(dx))
    return 1.0


def cdf_figure(errors: dict[str, np.ndarray], title: str = "localization error"):
    """Empirical CDFs of position errors (m), one curve per label ("map / localizer")."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    styles = {"built": "-", "surveyed": "--", "raw": ":"}
    for i, (label, e) in enumerate(errors.items()):
        e = np.sort(np.asarray(e, dtype=float)[np.isfinite(e)])
        if e.size == 0:
            continue
        ls = styles.get(label.split(" / ")[0], "-")
        ax.step(e, np.arange(1, e.size + 1) / e.size, where="post", ls=ls, color=f"C{i % 10}",
                label=f"{label} (median {np.median(e):.1f} m, n={e.size})")
    ax.set_xlabel("error (m)")
    ax.set_ylabel("fraction of scans")
    ax.set_ylim(0, 1.01)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def cost_figure(cost: np.ndarray, solve: np.ndarray | None = None):
    """The optimiser's cost per iteration (log scale when positive); with ``solve`` (the solve of each
    iteration) each solve is its own line and a dotted line marks where the next one starts."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 3.2))
    c = np.asarray(cost, dtype=float)
    sv = np.zeros(c.size, dtype=np.int64) if solve is None else np.asarray(solve, dtype=np.int64)
    for k in np.unique(sv):
        idx = np.flatnonzero(sv == k)
        ax.plot(idx, c[idx], marker="o", ms=3, color="C0")
        if k > sv.min():
            ax.axvline(idx[0] - 0.5, color="0.5", ls=":", lw=1)
    if sv.size and sv.max() > sv.min():
        ax.text(0.99, 0.97, f"{sv.max() - sv.min() + 1} solves (dotted: a new solve, new factors)",
                transform=ax.transAxes, ha="right", va="top", fontsize=8, color="0.3")
    if c.size and np.all(c[np.isfinite(c)] > 0):
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost")
    ax.grid(alpha=0.3)
    ax.set_title("optimiser cost per iteration", fontsize=10)
    fig.tight_layout()
    return fig
