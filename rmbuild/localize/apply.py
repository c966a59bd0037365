"""Localizing scans against a finished radio map: positions, a per-scan uncertainty, and a tidy table.

The uncertainty is localizer-agnostic: for each scan, the K reference points nearest in signal space
(kNN's neighbours, K = ``knn.k``, the same reference view and distance as the ``knn`` localizer) are
taken as the places the scan could have come from, and ``uncertainty_m`` is the root-mean-square
distance of their positions from the estimate: the spread of the signal-space neighbourhood around
the answer. It is a figure of the map's ambiguity at that scan, not a calibrated standard deviation; docs/api.md reports
how it ranks the errors on the test walks.

A scan taken where the map has no walks still gets an estimate inside the map, with a spread no larger than
anywhere else. What gives it away is how badly it matches: its distance in signal space to the nearest
reference point. :func:`outside_threshold` measures how well the map's own node fingerprints match the
nearest cell other than their own; a scan matching worse than :data:`OUTSIDE_QUANTILE` of them is flagged
``outside_map``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rmbuild.config.evaluate import EvaluateConfig, KnnConfig
from rmbuild.localize.base import Query, make_localizer
from rmbuild.localize.knn import KnnLocalizer
from rmbuild.radiomap.build import RadioMap
from rmbuild.radiomap.reference import ReferenceSet

#: Columns of :func:`positions_table` (then x_true_m, y_true_m, error_m when a reference is given).
POSITION_COLUMNS = ("walk_id", "t_s", "x_m", "y_m", "uncertainty_m", "n_aps", "outside_map")
#: share of the map's own node fingerprints that match a neighbouring cell better than a scan flagged as
#: taken outside the map
OUTSIDE_QUANTILE = 0.99


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
    #: (n,) distance (dB) of each scan to its nearest reference point; NaN without one
    match_db: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: (n,) bool: the scan matches the map worse than the map's own scans match a neighbouring cell
    outside_map: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: dB; the match distance above which a scan is outside the map (None: the map cannot tell)
    outside_db: float | None = None


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


#: the distance :func:`match_distances` and :func:`outside_threshold` compare fingerprints by: the RMS RSS
#: difference over the APs either side detected, a missing reading counting as -110 dBm (Gu et al. 2017
#: eq. 9): it does not grow with the number of APs a scan hears, as the plain Euclidean distance does
MATCH_METRIC = KnnConfig(metric="rms", missing="fill", reference="cells")
#: candidates searched for a node's nearest cell its own walk did not fill
_OWN_WALK_CANDIDATES = 30


def match_distances(rm: RadioMap, query: Query) -> np.ndarray:
    """float64 (n,) distance (dB, :data:`MATCH_METRIC`) of each scan to the map's nearest cell; NaN when
    the scan hears none of the map's APs."""
    knn = KnnLocalizer(MATCH_METRIC).fit(rm.reference_set("cells"))
    q = query.aligned(rm.bssids)
    dist, idx = knn.kneighbors(q.rss_dbm, k=1)
    heard = (~np.isnan(q.rss_dbm)).any(axis=1)
    return np.where(heard & (idx[:, 0] >= 0) & np.isfinite(dist[:, 0]), dist[:, 0], np.nan)


def outside_threshold(rm: RadioMap) -> float | None:
    """dB: the :data:`OUTSIDE_QUANTILE` quantile, over the map's node fingerprints, of the distance from a
    node to the nearest cell its own walk did not fill (as a scan of another walk taken there matches the
    map); None with fewer than 20 such nodes (the map cannot tell)."""
    cells, nodes = rm.reference_set("cells"), rm.reference_set("nodes")
    if len(nodes) < 20 or len(cells) < 2:
        return None
    cell_of = {(int(i), int(j)): c for c, (i, j) in enumerate(zip(rm.cells["ix"], rm.cells["iy"]))}
    ij = np.floor((nodes.xy - rm.origin_xy) / rm.cell_size_m).astype(np.int64)
    walk = np.asarray(rm.node_walk).astype(str)
    own: dict[str, set[int]] = {}
    for w, (i, j) in zip(walk, ij):
        own.setdefault(w, set()).add(cell_of.get((int(i), int(j)), -1))
    knn = KnnLocalizer(MATCH_METRIC).fit(cells)
    dist, idx = knn.kneighbors(nodes.rss_dbm, k=min(_OWN_WALK_CANDIDATES, len(cells)))
    other = np.array([[c >= 0 and c not in own[w] for c in row] for w, row in zip(walk, idx)]) & np.isfinite(dist)
    first = dist[np.flatnonzero(other.any(axis=1)), other.argmax(axis=1)[other.any(axis=1)]]
    return float(np.quantile(first, OUTSIDE_QUANTILE)) if len(first) >= 20 else None


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
    match, limit = match_distances(rm, q), outside_threshold(rm)
    outside = np.isfinite(xy).all(axis=1) & (match > limit) if limit is not None else np.zeros(len(xy), bool)
    return Localized(name, xy, unc, n_aps, loc.summary(), match, outside, limit)


def positions_table(query: Query, res: Localized, ref_xy: np.ndarray | None = None) -> pd.DataFrame:
    """One row per scan (:data:`POSITION_COLUMNS`); with ``ref_xy`` (n, 2) reference positions in the map's
    frame (NaN = unknown) also x_true_m, y_true_m and error_m (m, NaN where either side is unknown)."""
    df = pd.DataFrame({
        "walk_id": query.walk_id.astype(str), "t_s": query.t_s, "x_m": res.xy[:, 0], "y_m": res.xy[:, 1],
        "uncertainty_m": res.uncertainty_m, "n_aps": res.n_aps,
        "outside_map": res.outside_map if len(res.outside_map) == len(res.xy) else np.zeros(len(res.xy), bool),
    })
    if ref_xy is not None:
        df["x_true_m"] = ref_xy[:, 0]
        df["y_true_m"] = ref_xy[:, 1]
        df["error_m"] = np.hypot(res.xy[:, 0] - ref_xy[:, 0], res.xy[:, 1] - ref_xy[:, 1])
    return df
