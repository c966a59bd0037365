"""Colours shared by the rerun bridge and the report figures (no rerun here).

Colour maps come from :data:`matplotlib.colormaps`, so the viewer and the PNGs use the same ones.
"""

from __future__ import annotations

import numpy as np

#: The one sequential colour map of every scalar picture (RSSI, scans per cell), in the PNGs and the
#: viewer: perceptually uniform and readable in grey and by colour-blind readers.
SEQUENTIAL_CMAP = "viridis"
#: Errors (low is good): blue -> yellow -> red; no red-green contrast, so colour-blind readers see it too.
ERROR_CMAP = "RdYlBu_r"
#: Per-walk quantities in the report (optimize's predicted error, m): perceptually uniform, colour-blind safe.
WALK_VALUE_CMAP = "plasma"

#: Qualitative palette (RGB 0-255), one colour per walk in walk order, cycled: the colour-blind-safe
#: Okabe-Ito colours first (a venue of up to 8 walks is told apart by every reader), then distinct others.
#: Grey is left out: it marks what is not placed.
WALK_PALETTE = np.array([
    (230, 159, 0), (86, 180, 233), (0, 158, 115), (0, 114, 178), (213, 94, 0), (204, 121, 167), (0, 0, 0),
    (190, 170, 0), (140, 86, 75), (148, 103, 189), (23, 190, 207), (188, 189, 34),
    (255, 187, 120), (174, 199, 232), (152, 223, 138), (197, 176, 213), (196, 156, 148), (247, 182, 210),
    (219, 219, 141), (158, 218, 229),
], dtype=np.uint8)
#: Lines told apart by colour in one plot (localizers in a CDF, near / far in the RF model): Okabe-Ito.
LINE_COLORS = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#000000", "#BEAA00")


def walk_color(i: int) -> tuple[int, int, int]:
    """RGB of the i-th walk (walk order of the workspace)."""
    c = WALK_PALETTE[i % len(WALK_PALETTE)]
    return int(c[0]), int(c[1]), int(c[2])


def _rgba(name: str, t: np.ndarray) -> np.ndarray:
    import matplotlib

    return np.asarray(matplotlib.colormaps[name](np.clip(t, 0.0, 1.0), bytes=True), dtype=np.uint8)


def colormap(values: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """RGBA uint8 (..., 4) of ``values`` on :data:`SEQUENTIAL_CMAP` over [vmin, vmax]; NaN -> transparent."""
    v = np.asarray(values, dtype=np.float64)
    span = vmax - vmin if vmax > vmin else 1.0
    out = _rgba(SEQUENTIAL_CMAP, np.nan_to_num((v - vmin) / span, nan=0.0))
    out[..., 3] = np.where(np.isfinite(v), 255, 0)
    return out


def error_colors(err: np.ndarray, scale: float) -> np.ndarray:
    """RGB uint8 (n, 3) on :data:`ERROR_CMAP`: blue (0) -> red (>= ``scale``); NaN counts as the worst."""
    e = np.asarray(err, dtype=np.float64)
    e = np.where(np.isfinite(e), e, scale)
    return _rgba(ERROR_CMAP, e / (scale if scale > 0 else 1.0))[..., :3]
