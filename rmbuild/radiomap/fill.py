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


def _candidates(cells: pd.DataFrame, max_d: float, s: float) -> np.ndarray:
    from scipy.spatial import cKDTree

    vis = cells[["ix", "iy"]].to_numpy(dtype=np.int64)
    r = int(np.ceil(max_d / s))
    lo, hi = vis.min(axis=0) - r, vis.max(axis=0) + r
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    allc = np.stack([gx.ravel(), gy.ravel()], axis=1)
    visited = set(map(tuple, vis.tolist()))
    allc = allc[[tuple(c) not in visited for c in allc.tolist()]]
    if len(allc) == 0:
        return allc
    d, _ = cKDTree(vis.astype(float)).query(allc.astype(float), k=1)
    return allc[d * s <= max_d + 1e-9]


def fill_cells(cells, cnt, mean, std, ratio, nw, origin, s, cfg: FillConfig):
    """Append filled cells to the visited-cell arrays; returns the same tuple, extended."""
    from scipy.spatial import cKDTree

    cand = _candidates(cells, cfg.max_distance_m, s)
    if len(cand) == 0:
        return cells, cnt, mean, std, ratio, nw
    vis_xy = cells[["x_m", "y_m"]].to_numpy(dtype=np.float64)
    cand_xy = origin + (cand + 0.5) * s
    k = min(cfg.idw_neighbours, len(vis_xy))
    d, nb = cKDTree(vis_xy).query(cand_xy, k=k)
    d, nb = d.reshape(len(cand), k), nb.reshape(len(cand), k)
    w = 1.0 / np.maximum(d, 1e-9) ** cfg.idw_power  # (nc, k)
    p = (w[:, :, None] * ratio[nb]).sum(axis=1) / w.sum(axis=1)[:, None]  # (nc, m)
    keep = p >= cfg.min_detect_ratio
    det = ~np.isnan(mean)
    if cfg.method == "idw":
        wd = w[:, :, None] * det[nb]
        sw = wd.sum(axis=1)
        mu_n = np.nan_to_num(mean[nb])
        with np.errstate(invalid="ignore", divide="ignore"):
            f_mean = (wd * mu_n).sum(axis=1) / sw
            var_between = (wd * (mu_n - f_mean[:, None, :]) ** 2).sum(axis=1) / sw
            var_within = (wd * np.nan_to_num(std[nb]) ** 2).sum(axis=1) / sw
        f_std = np.sqrt(var_between + var_within)
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
        kxx = sf2 * np.exp(-((x[:, None, :] - x[None, :, :]) ** 2).sum(-1) / l2) + sn2 * np.eye(len(tr))
        ks = sf2 * np.exp(-((cand_xy[rows][:, None, :] - x[None, :, :]) ** 2).sum(-1) / l2)
        c = cho_factor(kxx, lower=True)
        f_mean[rows, j] = mu + ks @ cho_solve(c, y - mu)
        v = np.einsum("ij,ji->i", ks, cho_solve(c, ks.T))
        f_std[rows, j] = np.sqrt(np.maximum(sf2 - v, 0.0) + sn2)
    return f_mean, f_std
