"""Optional fill of unvisited cells near visited ones (inverse-distance weighting or a Gaussian process).

Candidates: every grid cell that no scan visited whose centre lies within ``max_distance_m`` of a visited
cell's centre. For each candidate and AP:

* detection ratio p = IDW average (over the ``idw_neighbours`` nearest visited cells, weight 1/d^power) of
  the visited cells' detection ratios; the AP is kept in the filled cell when p >= ``min_detect_ratio``;
* ``idw``: mean = IDW average of the means of the neighbours that detected the AP; uncertainty
  σ = sqrt(weighted variance of those means + weighted mean of their σ², σ = 0 where T < 2);
* ``gp``: mean and σ from a Gaussian process per AP over the visited cells that detected it (RBF kernel,
  length ℓ, signal σ_f, noise σ_n, prior mean = the AP's average cell mean); σ is the predictive std of a
  cell mean, sqrt(σ_f² (1 − k*ᵀ (K + σ_n² I)⁻¹ k* / σ_f²) + σ_n²).

Filled cells get count 0, n_walks 0, n_scans 0 and ``interpolated = True``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rmbuild.config.radiomap import FillConfig
from rmbuild.errors import InputError
from rmbuild.limits import MAX_MAP_CELLS

#: (visited cell, offset) pairs the candidate search looks at in one block, and elements of the fill's
#: (candidates, neighbours, APs) products computed at once: bounded memory on any map
_PAIR_BLOCK = 1 << 22
_BLOCK_ELEMS = 1 << 22


def _candidates(cells: pd.DataFrame, max_d: float, s: float) -> np.ndarray:
    """(n, 2) int64 grid indices of the unvisited cells whose centre lies within ``max_d`` of a visited
    cell's centre: the visited cells' neighbourhoods (offsets within the distance), not their bounding box,
    so that a map spread over kilometres costs what its cells do. InputError when there would be more than
    the map's tables can hold (:data:`MAX_MAP_CELLS` over the map's APs)."""
    vis = cells[["ix", "iy"]].to_numpy(dtype=np.int64)
    r = int(np.ceil(max_d / s))
    ox, oy = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
    near = np.hypot(ox, oy) * s <= max_d + 1e-9
    off = np.stack([ox[near], oy[near]], axis=1)
    span = int(np.ptp(vis[:, 1])) + 2 * r + 1 if len(vis) else 1
    base = vis[:, 1].min() - r if len(vis) else 0

    def key(ij: np.ndarray) -> np.ndarray:  # one integer per cell (row-major over the padded y range)
        return ij[:, 0] * span + (ij[:, 1] - base)

    visited = np.unique(key(vis))
    found: list[np.ndarray] = []
    n_found = 0
    per = max(1, _PAIR_BLOCK // max(len(off), 1))
    for b in range(0, len(vis), per):
        k = np.unique(key((vis[b:b + per, None, :] + off[None, :, :]).reshape(-1, 2)))
        k = k[~np.isin(k, visited, assume_unique=True)]
        found.append(k)
        n_found += len(k)
        if n_found > MAX_MAP_CELLS:
            break
    keys = np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
    return np.stack([keys // span, keys % span + base], axis=1)


def fill_cells(cells, cnt, mean, std, ratio, nw, origin, s, cfg: FillConfig):
    """Append filled cells to the visited-cell arrays; returns the same tuple, extended."""
    from scipy.spatial import cKDTree

    cand = _candidates(cells, cfg.max_distance_m, s)
    if len(cand) == 0:
        return cells, cnt, mean, std, ratio, nw
    m = mean.shape[1]
    if (len(cells) + len(cand)) * m > MAX_MAP_CELLS:
        raise InputError(f"fill: {len(cand):,} unvisited cells within fill.max_distance_m = {cfg.max_distance_m:g} m "
                         f"of the {len(cells):,} visited ones, x {m:,} APs: more than the {MAX_MAP_CELLS:,} entries a "
                         "map's tables hold; lower fill.max_distance_m or give a larger cell size")
    vis_xy = cells[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    cand_xy = origin + (cand + 0.5) * s
    k = min(cfg.idw_neighbours, len(vis_xy))
    d, nb = cKDTree(vis_xy).query(cand_xy, k=k)
    d, nb = d.reshape(len(cand), k), nb.reshape(len(cand), k)
    w = 1.0 / np.maximum(d, 1e-9) ** cfg.idw_power  # (nc, k)
    det = ~np.isnan(mean)
    p = np.empty((len(cand), m))
    f_mean, f_std, sw = np.empty((len(cand), m)), np.empty((len(cand), m)), np.empty((len(cand), m))
    step = max(1, _BLOCK_ELEMS // (k * m))  # the (candidates, k, APs) products a block of candidates at a time
    for b in range(0, len(cand), step):
        wb, nbb = w[b:b + step], nb[b:b + step]
        p[b:b + step] = (wb[:, :, None] * ratio[nbb]).sum(axis=1) / wb.sum(axis=1)[:, None]  # (nc, m)
        if cfg.method == "idw":
            wd = wb[:, :, None] * det[nbb]
            sw[b:b + step] = wd.sum(axis=1)
            mu_n = np.nan_to_num(mean[nbb])
            with np.errstate(invalid="ignore", divide="ignore"):
                fm = (wd * mu_n).sum(axis=1) / sw[b:b + step]
                var_between = (wd * (mu_n - fm[:, None, :]) ** 2).sum(axis=1) / sw[b:b + step]
                var_within = (wd * np.nan_to_num(std[nbb]) ** 2).sum(axis=1) / sw[b:b + step]
            f_mean[b:b + step] = fm
            f_std[b:b + step] = np.sqrt(var_between + var_within)
    keep = p >= cfg.min_detect_ratio
    if cfg.method == "idw":
        keep &= sw > 0
    else:
        f_mean, f_std = _gp(vis_xy, cand_xy, mean, keep, cfg)
    f_mean = np.where(keep, f_mean, np.nan)
    f_std = np.where(keep, f_std, np.nan)
    f_ratio = np.where(keep, p, 0.0)
    n = len(cand)
    new = pd.DataFrame({
        "ix": cand[:, 0], "iy": cand[:, 1], "x_m": cand_xy[:, 0], "y_m": cand_xy[:, 1],
        "n_scans": np.zeros(n, np.int64), "n_nodes": np.zeros(n, np.int64), "n_walks": np.zeros(n, np.int64),
        "interpolated": True,
    })
    any_ap = keep.any(axis=1)
    new = new[any_ap]
    m = mean.shape[1]
    out = (
        pd.concat([cells, new], ignore_index=True),
        np.vstack([cnt, np.zeros((any_ap.sum(), m), cnt.dtype)]),
        np.vstack([mean, f_mean[any_ap]]),
        np.vstack([std, f_std[any_ap]]),
        np.vstack([ratio, f_ratio[any_ap]]),
        np.vstack([nw, np.zeros((any_ap.sum(), m), nw.dtype)]),
    )
    return out


def _gp(vis_xy, cand_xy, mean, keep, cfg: FillConfig):
    from scipy.linalg import cho_factor, cho_solve

    nc, m = len(cand_xy), mean.shape[1]
    f_mean = np.full((nc, m), np.nan)
    f_std = np.full((nc, m), np.nan)
    l2 = 2.0 * cfg.gp_length_scale_m ** 2
    sf2, sn2 = cfg.gp_signal_std_db ** 2, cfg.gp_noise_std_db ** 2
    for j in range(m):
        rows = np.flatnonzero(keep[:, j])
        if len(rows) == 0:
            continue
        tr = np.flatnonzero(~np.isnan(mean[:, j]))
        if len(tr) == 0:
            continue
        if len(tr) > cfg.gp_max_cells:
            raise InputError(f"GP fill: AP column {j} has {len(tr)} cells > fill.gp_max_cells; use IDW")
        x = vis_xy[tr]
        y = mean[tr, j].astype(np.float64)
        mu = y.mean()
        kxx = sf2 * np.exp(-_sq_dist(x, x) / l2) + sn2 * np.eye(len(tr))
        c = cho_factor(kxx, lower=True)
        alpha = cho_solve(c, y - mu)
        for b in range(0, len(rows), max(1, _BLOCK_ELEMS // len(tr))):  # (rows, cells) kernels a block at a time
            rb = rows[b:b + max(1, _BLOCK_ELEMS // len(tr))]
            ks = sf2 * np.exp(-_sq_dist(cand_xy[rb], x) / l2)
            f_mean[rb, j] = mu + ks @ alpha
            v = np.einsum("ij,ji->i", ks, cho_solve(c, ks.T))
            f_std[rb, j] = np.sqrt(np.maximum(sf2 - v, 0.0) + sn2)
    return f_mean, f_std


def _sq_dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) squared distances of points (n, 2), without an (n, m, 2) temporary."""
    return (a[:, None, 0] - b[None, :, 0]) ** 2 + (a[:, None, 1] - b[None, :, 1]) ** 2
