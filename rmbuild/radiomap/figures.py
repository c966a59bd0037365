"""Matplotlib figures of a radio map (returned as Figure objects; the caller saves them).

Figures are built with :class:`matplotlib.figure.Figure` directly (no pyplot state, no backend needed).
``walls``: optional venue walls overlay, an array-like (n, 4) of segments (x0, y0, x1, y1) in the map
frame, or a venue dict with a ``"walls"`` entry of that shape.
"""

from __future__ import annotations

import numpy as np


def _walls_array(walls) -> np.ndarray | None:
    if walls is None:
        return None
    if isinstance(walls, dict):
        walls = walls.get("walls")
        if walls is None:
            return None
    a = np.asarray(walls, dtype=float)
    if a.ndim != 2 or a.shape[1] != 4:
        raise ValueError("walls must be (n, 4) segments x0, y0, x1, y1")
    return a


def _draw_walls(ax, walls) -> None:
    a = _walls_array(walls)
    if a is None or len(a) == 0:
        return
    from matplotlib.collections import LineCollection

    ax.add_collection(LineCollection(list(a.reshape(-1, 2, 2)), colors="0.2", linewidths=0.8, zorder=3))


def _raster(rm, values: np.ndarray) -> tuple[np.ndarray, list[float]]:
    ix = rm.cells["ix"].to_numpy()
    iy = rm.cells["iy"].to_numpy()
    x0, y0 = ix.min(), iy.min()
    img = np.full((iy.max() - y0 + 1, ix.max() - x0 + 1), np.nan)
    img[iy - y0, ix - x0] = values
    s = rm.cell_size_m
    ext = [rm.origin_xy[0] + x0 * s, rm.origin_xy[0] + (ix.max() + 1) * s,
           rm.origin_xy[1] + y0 * s, rm.origin_xy[1] + (iy.max() + 1) * s]
    return img, ext


def coverage_figure(rm, walls=None):
    from matplotlib.colors import LogNorm, Normalize
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 6), layout="constrained")
    ax = fig.subplots()
    n = rm.cells["n_scans"].to_numpy(dtype=float)
    interp = rm.cells["interpolated"].to_numpy(dtype=bool)
    img, ext = _raster(rm, np.where(interp, np.nan, n))
    vmax = max(float(np.nanmax(img)) if np.isfinite(img).any() else 1.0, 1.0)
    norm = LogNorm(vmin=1, vmax=vmax) if vmax >= 20 else Normalize(vmin=0, vmax=vmax)
    im = ax.imshow(img, origin="lower", extent=ext, cmap="viridis", norm=norm, interpolation="nearest")
    if interp.any():
        fimg, _ = _raster(rm, np.where(interp, 1.0, np.nan))
        ax.imshow(fimg, origin="lower", extent=ext, cmap="Greys", vmin=0, vmax=4, alpha=0.6,
                  interpolation="nearest")
    fig.colorbar(im, ax=ax, label="scans per cell")
    _draw_walls(ax, walls)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"coverage: {int((~interp).sum())} visited cells"
                 + (f" + {int(interp.sum())} filled (grey)" if interp.any() else "")
                 + f", {rm.cell_size_m:g} m grid" + (f", frame {rm.frame}" if rm.frame else ""))
    return fig


def heatmaps_figure(rm, top_n: int, walls=None):
    from matplotlib.figure import Figure

    aps = rm.strongest_aps(top_n)
    n = max(len(aps), 1)
    ncol = min(3, n)
    nrow = int(np.ceil(n / ncol))
    fig = Figure(figsize=(4.2 * ncol, 3.6 * nrow), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    finite = rm.mean_dbm[:, aps][np.isfinite(rm.mean_dbm[:, aps])] if aps else np.array([])
    vmin = float(np.percentile(finite, 2)) if finite.size else -100.0
    vmax = float(finite.max()) if finite.size else -30.0
    im = None
    for ax, j in zip(axes, aps, strict=False):
        img, ext = _raster(rm, rm.mean_dbm[:, j])
        im = ax.imshow(img, origin="lower", extent=ext, cmap="inferno", vmin=vmin, vmax=vmax,
                       interpolation="nearest")
        _draw_walls(ax, walls)
        ax.set_aspect("equal")
        ax.set_title(str(rm.bssids[j]), fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes[len(aps):]:
        ax.set_axis_off()
    if im is not None:
        fig.colorbar(im, ax=list(axes[:len(aps)]), label="mean RSSI [dBm]", shrink=0.8)
    fig.suptitle(f"strongest {len(aps)} APs, mean RSSI per {rm.cell_size_m:g} m cell")
    return fig
