"""Colours shared by the rerun bridge and the report figures (numpy only, no rerun, no matplotlib)."""

from __future__ import annotations

import numpy as np

#: Qualitative palette (RGB 0-255), one colour per walk in walk order, cycled (Tableau 20 order).
WALK_PALETTE = np.array([
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
    (174, 199, 232), (255, 187, 120), (152, 223, 138), (255, 152, 150), (197, 176, 213),
    (196, 156, 148), (247, 182, 210), (199, 199, 199), (219, 219, 141), (158, 218, 229),
], dtype=np.uint8)

#: Viridis sampled at 9 points (RGB 0-255); :func:`colormap` interpolates between them.
_VIRIDIS = np.array([
    (68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141),
    (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37),
], dtype=np.float64)

#: Green -> yellow -> red, for errors (low is good).
_TRAFFIC = np.array([(26, 152, 80), (145, 207, 96), (254, 224, 139), (252, 141, 89), (215, 48, 39)],
                    dtype=np.float64)


def walk_color(i: int) -> tuple[int, int, int]:
    """RGB of the i-th walk (walk order of the workspace)."""
    c = WALK_PALETTE[i % len(WALK_PALETTE)]
    return int(c[0]), int(c[1]), int(c[2])


def _ramp(table: np.ndarray, t: np.ndarray) -> np.ndarray:
    t = np.clip(np.nan_to_num(np.asarray(t, dtype=np.float64), nan=0.0), 0.0, 1.0)
    pos = t * (len(table) - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, len(table) - 1)
    f = (pos - lo)[..., None]
    return (table[lo] * (1 - f) + table[hi] * f).round().astype(np.uint8)


def colormap(values: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """RGBA uint8 (..., 4) of ``values`` on viridis over [vmin, vmax]; NaN -> fully transparent."""
    v = np.asarray(values, dtype=np.float64)
    span = vmax - vmin if vmax > vmin else 1.0
    rgb = _ramp(_VIRIDIS, (v - vmin) / span)
    alpha = np.where(np.isfinite(v), 255, 0).astype(np.uint8)
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def error_colors(err: np.ndarray, scale: float) -> np.ndarray:
    """RGB uint8 (n, 3): green (0) -> red (>= ``scale``); NaN counts as the worst."""
    e = np.asarray(err, dtype=np.float64)
    e = np.where(np.isfinite(e), e, scale)
    return _ramp(_TRAFFIC, e / (scale if scale > 0 else 1.0))
