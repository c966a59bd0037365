"""Localizing scans against a finished radio map: positions, a per-scan uncertainty, and a tidy table.

The uncertainty is localizer-agnostic: for each scan, the K reference points nearest in signal space
(kNN's neighbours, K = ``knn.k``, the same reference view and distance as the ``knn`` localizer) are
taken as the places the scan could have come from, and ``uncertainty_m`` is the root-mean-square
distance of their positions from the estimate: the spread of the signal-space neighbourhood around
the answer. It is a figure of the map's ambiguity at that scan, not a calibrated standard deviation; docs/api.md reports
how it ranks the errors on the test walks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rmbuild.config.evaluate import EvaluateConfig
from rmbuild.localize.base import Query, make_localizer
from rmbuild.localize.knn import KnnLocalizer
from rmbuild.radiomap.build import RadioMap
from rmbuild.radiomap.reference import ReferenceSet

#: Columns of :func:`positions_table` (then x_true_m, y_true_m, error_m when a reference is given).
POSITION_COLUMNS = ("walk_id", "t_s", "x_m", "y_m", "uncertainty_m", "n_aps")


@dataclass
class Localized:
    """What :func:`localize_query` returns. ``xy`` float64 (n, 2) metres in the map's frame (NaN = no
    estimate); ``uncertainty_m`` float64 (n,); ``n_aps`` int (n,) APs of the map heard in each scan;
    ``summary``: the localizer's own figures (e.g. SLAC's calibrated parameters)."""

    localizer: str
    xy: np.ndarray
    uncertainty_m: np.ndarray
    n_aps: np.ndarray
    summary: dict = field(default_factory=dict)


def neighbourhood_spread(ref: RadioMap | ReferenceSet, query: Query, xy: np.ndarray,
                         cfg: EvaluateConfig | None = None) -> np.ndarray:
    """float64 (n,) RMS distance (m) of each scan's K signal-space nearest RPs from ``xy`` (NaN when the
    scan has no admissible neighbour or no estimate)."""
    knn = KnnLocalizer((cfg or EvaluateConfig()).knn).fit(ref)
    assert knn.ref is not None
    dist, idx = knn.kneighbors(query.aligned(knn.ref.bssids).rss_dbm)
    ok = np.isfinite(dist) & (idx >= 0)
    pos = knn.ref.xy[np.maximum(idx, 0)]  # (n, k, 2)
    d2 = ((pos - np.asarray(xy, dtype=float)[:, None, :]) ** 2).sum(axis=2)
    n = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(np.where(ok, d2, 0.0).sum(axis=1) / n)
    out[n == 0] = np.nan
    return out


def localize_query(rm: RadioMap, query: Query, name: str, cfg: EvaluateConfig | None = None) -> Localized:
    """Fit the registered localizer ``name`` (configured by ``cfg``, an EvaluateConfig) on ``rm`` and
    localize every scan of ``query`` (a scan hearing none of the map's APs gets no estimate: NaN); raises
    InputError for an unknown name or bad config."""
    cfg = cfg or EvaluateConfig()
    loc = make_localizer(name, cfg).fit(rm)
    q = query.aligned(rm.bssids)
    xy = np.asarray(loc.predict(q), dtype=np.float64)
    n_aps = (~np.isnan(q.rss_dbm)).sum(axis=1).astype(np.int64)
    xy[n_aps == 0] = np.nan  # a scan that heard none of the map's APs says nothing about where it was
    unc = neighbourhood_spread(rm, q, xy, cfg)
    unc[~np.isfinite(xy).all(axis=1)] = np.nan
    return Localized(name, xy, unc, n_aps, loc.summary())


def positions_table(query: Query, res: Localized, ref_xy: np.ndarray | None = None) -> pd.DataFrame:
    """One row per scan (:data:`POSITION_COLUMNS`); with ``ref_xy`` (n, 2) reference positions in the map's
    frame (NaN = unknown) also x_true_m, y_true_m and error_m (m, NaN where either side is unknown)."""
    df = pd.DataFrame({
        "walk_id": query.walk_id.astype(str), "t_s": query.t_s, "x_m": res.xy[:, 0], "y_m": res.xy[:, 1],
        "uncertainty_m": res.uncertainty_m, "n_aps": res.n_aps,
    })
    if ref_xy is not None:
        df["x_true_m"] = ref_xy[:, 0]
        df["y_true_m"] = ref_xy[:, 1]
        df["error_m"] = np.hypot(res.xy[:, 0] - ref_xy[:, 0], res.xy[:, 1] - ref_xy[:, 1])
    return df
