"""`rmbuild evaluate`: localize held-out walks against radio maps built three ways and compare.

* **split** — by walk, never by reading: the given ``test_walks``; else the walks whose role is "test";
  else walk i (in ``walks`` order) is a test walk when ``i % split_every == split_offset`` (the last walk
  when that selects none). Every other walk is a map walk.
* **reference positions** of nodes — ``truth_poses`` when present; else, per walk, the fixes interpolated
  linearly in time, only within the walk's fix span (NaN outside; a walk with < 2 fixes has none).
* **maps**, on one grid (common origin) and AP list: "built" from the optimised positions, "surveyed" from
  the reference positions, "raw" from the raw PDR poses (each walk in its own frame: the floor).
* **gauge** — "anchors": the built positions are taken as they are (already in the building frame);
  "se2": one rigid transform fitted on ALL map-walk nodes (built -> reference) is applied to every built
  position, never one per walk. The raw map always gets its own single SE(2) fit (its walks have no common
  frame to be anchored in); the result's ``alignment`` says what was done.
* **errors** — per test scan, ‖predicted − reference position at the scan time‖ (reference interpolated
  in time; scans outside the reference span are not scored). Without any reference the error statistics
  cannot be computed; ``unavailable`` says so, and ``consistency`` (prediction vs. the optimised position
  of the scan's own node) is still reported.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rmbuild.config.evaluate import EvaluateConfig
from rmbuild.config.radiomap import MapConfig
from rmbuild.errors import InputError
from rmbuild.evaluate.trajectory import align_se2
from rmbuild.localize.base import Query, make_localizer
from rmbuild.radiomap.build import RadioMap, build_radio_map, grid_origin
from rmbuild.types import BUILDING_FRAME_GAUGES, Dataset, Fingerprints

MAP_NAMES = ("built", "surveyed", "raw")
STAT_KEYS = ("mean", "median", "p75", "p90", "rmse", "max", "p_lt_5m", "p_lt_10m", "n")


def error_stats(err: np.ndarray) -> dict:
    """evo-style statistics of position errors (m): mean, median, p75, p90, rmse, max, P(<5 m), P(<10 m), n.

    Non-finite errors are ignored (they are counted separately by the caller); n = finite errors.
    """
    e = np.asarray(err, dtype=float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {k: (0 if k == "n" else None) for k in STAT_KEYS}
    return {
        "mean": float(e.mean()),
        "median": float(np.median(e)),
        "p75": float(np.percentile(e, 75)),
        "p90": float(np.percentile(e, 90)),
        "rmse": float(np.sqrt((e ** 2).mean())),
        "max": float(e.max()),
        "p_lt_5m": float((e < 5.0).mean()),
        "p_lt_10m": float((e < 10.0).mean()),
        "n": int(e.size),
    }


def split_walks(
    dataset: Dataset, cfg: EvaluateConfig, test_walks: list[str] | None = None
) -> tuple[list[str], list[str], str]:
    """(map_walks, test_walks, rule) — see the module docstring. Raises InputError for bad choices."""
    ids = [str(w) for w in dataset.walks["walk_id"]]
    if len(ids) < 2:
        raise InputError(f"evaluation needs at least 2 walks (map + test), got {len(ids)}")
    if test_walks is not None:
        test = [str(w) for w in test_walks]
        unknown = sorted(set(test) - set(ids))
        if unknown:
            raise InputError(f"unknown test walk {unknown[0]!r}")
        rule = "given"
    elif "role" in dataset.walks and (dataset.walks["role"].astype(str) == "test").any():
        test = [w for w, r in zip(ids, dataset.walks["role"].astype(str), strict=True) if r == "test"]
        rule = "role"
    else:
        k, o = cfg.split_every, cfg.split_offset
        test = [w for i, w in enumerate(ids) if i % k == o] or [ids[-1]]
        rule = f"every {k}th walk from index {o}"
    tset = set(test)
    test = [w for w in ids if w in tset]
    maps = [w for w in ids if w not in tset]
    if not test:
        raise InputError("no test walks")
    if not maps:
        raise InputError("every walk is a test walk: no walks left to build the map from")
    return maps, test, rule


def _interp_track(t_track: np.ndarray, xy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of a track at times t; NaN outside [t_track.min, t_track.max]."""
    out = np.full((len(t), 2), np.nan)
    ok_tr = np.isfinite(t_track) & np.isfinite(xy).all(axis=1)
    t_track, xy = t_track[ok_tr], xy[ok_tr]
    if len(t_track) == 0:
        return out
    o = np.argsort(t_track, kind="stable")
    t_track, xy = t_track[o], xy[o]
    inside = (t >= t_track[0]) & (t <= t_track[-1])
    if len(t_track) == 1:
        out[inside] = xy[0]
        return out
    out[inside, 0] = np.interp(t[inside], t_track, xy[:, 0])
    out[inside, 1] = np.interp(t[inside], t_track, xy[:, 1])
    return out


def _reference_tracks(dataset: Dataset) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], str | None]:
    """walk_id -> (t_s, xy) of its reference track, and the source ("truth_poses", "fixes" or None)."""
    tp = dataset.truth_poses
    if tp is not None and len(tp) == dataset.n_nodes and len(tp) > 0:
        src, df = "truth_poses", tp
    elif dataset.fixes is not None and len(dataset.fixes) > 0:
        src, df = "fixes", dataset.fixes
    else:
        return {}, None
    tracks = {}
    for wid, g in df.groupby(df["walk_id"].astype(str), sort=False):
        if src == "fixes" and len(g) < 2:
            continue
        tracks[str(wid)] = (g["t_s"].to_numpy(dtype=float), g[["x_m", "y_m"]].to_numpy(dtype=float))
    return tracks, src


def reference_positions(dataset: Dataset) -> tuple[np.ndarray, str | None]:
    """float64 (n_nodes, 2) reference position of every node (NaN = unknown) and its source."""
    ref = np.full((dataset.n_nodes, 2), np.nan)
    tp = dataset.truth_poses
    if tp is not None and len(tp) == dataset.n_nodes and len(tp) > 0:
        return tp[["x_m", "y_m"]].to_numpy(dtype=float), "truth_poses"
    tracks, src = _reference_tracks(dataset)
    if src is None:
        return ref, None
    t = dataset.poses["t_s"].to_numpy(dtype=float)
    for wid, sl in dataset.walk_slices().items():
        if wid in tracks:
            ref[sl] = _interp_track(*tracks[wid], t[sl])
    return ref, src


def query_reference_xy(dataset: Dataset, query: Query) -> np.ndarray:
    """float64 (n_queries, 2) reference position of every query scan: its walk's reference track (truth
    poses, else fixes) interpolated at the scan time; NaN outside the track or without one."""
    tracks, _ = _reference_tracks(dataset)
    out = np.full((len(query), 2), np.nan)
    for wid, rows in query.walks():
        if wid in tracks:
            out[rows] = _interp_track(*tracks[wid], query.t_s[rows])
    return out


def _apply(r: np.ndarray, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return xy @ r.T + t


def _fit_se2(src: np.ndarray, dst: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    ok = rows[np.isfinite(src[rows]).all(axis=1) & np.isfinite(dst[rows]).all(axis=1)]
    if len(ok) < 2:
        raise InputError(f"cannot align the map to score it: the map's walks have {len(ok)} node(s) with a "
                         "reference position (truth or fixes) and a rigid fit needs 2; too few walks were linked "
                         "into the map, or they carry no fixes")
    r, t = align_se2(src[ok], dst[ok])
    res = np.hypot(*(_apply(r, t, src[ok]) - dst[ok]).T)
    info = {"rotation_deg": float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))),
            "translation_m": [float(t[0]), float(t[1])], "n_points": int(len(ok)),
            "residual_rms_m": float(np.sqrt((res ** 2).mean()))}
    return r, t, info


def _nan_to_none(x):
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_nan_to_none(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


@dataclass
class EvalResult:
    """Everything `evaluate` computed. ``stats[map][localizer]`` has :data:`STAT_KEYS`; ``errors[map][loc]``
    float64 (n_queries,) per-scan errors in m (NaN = not scored); ``predictions[map][loc]`` (n_queries, 2).
    ``query``: the test scans; ``query_ref_xy`` (n_queries, 2) their reference positions (NaN unknown).
    ``unavailable``: what could not be computed -> why. ``maps``: the radio maps (name -> RadioMap).
    """

    gauge: str
    test_walks: list[str]
    map_walks: list[str]
    split_rule: str
    reference_source: str | None
    stats: dict[str, dict[str, dict]]
    errors: dict[str, dict[str, np.ndarray]]
    predictions: dict[str, dict[str, np.ndarray]]
    query: Query
    query_ref_xy: np.ndarray
    alignment: dict
    unavailable: dict[str, str]
    consistency: dict[str, dict[str, dict]]
    maps: dict[str, RadioMap] = field(repr=False)
    localizers: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        """``{"gauge", "test_walks", "maps": {map: {localizer: stats}}}`` plus extra keys (JSON-safe)."""
        failed = {m: {loc: int(np.isnan(p[:, 0]).sum()) for loc, p in d.items()}
                  for m, d in self.predictions.items()}
        out = {
            "gauge": self.gauge,
            "test_walks": list(self.test_walks),
            "maps": {m: {loc: dict(s) for loc, s in d.items()} for m, d in self.stats.items()},
            "map_walks": list(self.map_walks),
            "split": self.split_rule,
            "reference": self.reference_source,
            "n_queries": int(len(self.query)),
            "n_scored": int(np.isfinite(self.query_ref_xy).all(axis=1).sum()),
            "n_unlocalized": failed,
            "alignment": self.alignment,
            "consistency": self.consistency,
            "map_info": {m: {"n_cells": rm.n_cells, "n_nodes": len(rm.nodes), "n_aps": len(rm.bssids),
                             "cell_size_m": rm.cell_size_m} for m, rm in self.maps.items()},
            "unavailable": dict(self.unavailable),
        }
        return _nan_to_none(out)

    def table(self) -> str:
        """A short fixed-width text table: one row per map and localizer."""
        w = max([len("localizer")] + [len(loc) for d in self.stats.values() for loc in d]) + 1
        head = f"{'map':<9}{'localizer':<{w}}{'mean':>7}{'median':>8}{'p90':>7}{'rmse':>7}{'max':>7}" \
               f"{'<5m':>6}{'<10m':>6}{'n':>6}"
        lines = [head, "-" * len(head)]

        def f(v, w, p=2):
            return f"{'-':>{w}}" if v is None else f"{v:>{w}.{p}f}"

        for m in MAP_NAMES:
            for loc, s in self.stats.get(m, {}).items():
                lines.append(f"{m:<9}{loc:<{w}}{f(s['mean'], 7)}{f(s['median'], 8)}{f(s['p90'], 7)}"
                             f"{f(s['rmse'], 7)}{f(s['max'], 7)}{f(s['p_lt_5m'], 6)}{f(s['p_lt_10m'], 6)}"
                             f"{s['n']:>6d}")
        lines.append(f"{self.frame_note()}; test walks: {len(self.test_walks)} ({self.split_rule}); errors in m")
        for what, why in self.unavailable.items():
            lines.append(f"not computed: {what}: {why}")
        return "\n".join(lines)

    def frame_note(self) -> str:
        """How the built map was compared with the reference positions, in plain words."""
        how = self.alignment.get("built")
        if how == "se2":
            return "built map: one rigid fit to the reference positions (its own frame is one walk's)"
        if how in BUILDING_FRAME_GAUGES:
            return f"built map: in the building frame as placed ({'anchors' if how == 'anchors' else 'floor plan'})"
        return "built map: in its own frame (no reference positions to fit it to)"

    def errors_by_label(self) -> dict[str, np.ndarray]:
        """Per "map / localizer" the per-scan errors (m), maps in :data:`MAP_NAMES` order."""
        return {f"{m} / {loc}": e for m in MAP_NAMES for loc, e in self.errors.get(m, {}).items()}


def evaluate(
    dataset: Dataset,
    fingerprints: Fingerprints,
    built_xy: np.ndarray,
    cfg: EvaluateConfig | None = None,
    test_walks: list[str] | None = None,
    gauge: str = "se2",
    *,
    map_cfg: MapConfig | None = None,
    progress: Callable[[str, dict], None] | None = None,
) -> EvalResult:
    """Build the built / surveyed / raw maps from the map walks and localize every test scan against each.

    ``built_xy``: float (n_nodes, 2) optimised node positions (row = node id). ``fingerprints``: the
    per-node fingerprints (their ``bssids`` fix the AP order of all maps).
    ``gauge``: "se2" or one of :data:`rmbuild.types.BUILDING_FRAME_GAUGES`.
    ``map_cfg``: how the maps are rasterised (default MapConfig()). ``progress(phase, info)``: called with
    ("maps", {"maps": n, "total"}) once the maps are built, ("localize_start", {"map", "localizer", "scans"})
    before and ("localize", {"map", "localizer", "scans", "done", "total", "time_s"}) after each localizer
    has localized every test scan with a map. Raises InputError for
    bad input.
    """
    cfg = cfg or EvaluateConfig()
    map_cfg = map_cfg or MapConfig()
    built_xy = _checked_inputs(dataset, built_xy, cfg, map_cfg, gauge)
    map_walks, test, rule = split_walks(dataset, cfg, test_walks)
    em = evaluation_maps(dataset, fingerprints, built_xy, map_walks, gauge, map_cfg)
    maps, alignment, unavailable, src = em.maps, em.alignment, em.unavailable, em.reference_source
    bssids = np.asarray(fingerprints.bssids, dtype=object)
    query = Query.from_dataset(dataset, test, bssids, unit=cfg.query)
    if len(query) == 0:
        raise InputError("the test walks have no Wi-Fi scans")
    q_ref = query_reference_xy(dataset, query)
    q_node = query.node
    q_built = np.where((q_node >= 0)[:, None], em.built_xy[np.maximum(q_node, 0)], np.nan)

    stats, errors, preds, consistency = _localize_all(maps, cfg, query, q_ref, q_built, src is not None, progress)
    if src is None:
        stats, errors = {}, {}
    return EvalResult(
        gauge=gauge, test_walks=test, map_walks=map_walks, split_rule=rule, reference_source=src,
        stats=stats, errors=errors, predictions=preds, query=query, query_ref_xy=q_ref, alignment=alignment,
        unavailable=unavailable, consistency=consistency, maps=maps, localizers=list(cfg.localizers),
    )


@dataclass
class EvaluationMaps:
    """What :func:`evaluation_maps` builds: ``maps`` (name -> RadioMap, :data:`MAP_NAMES` that could be
    built), ``built_xy`` (n_nodes, 2) the optimised positions in the frame the built map is in (after the
    gauge's SE(2) when there is one), ``alignment`` and ``unavailable`` (as in :class:`EvalResult`), and
    the reference positions' source (None: no ground truth)."""

    maps: dict[str, RadioMap]
    built_xy: np.ndarray
    alignment: dict
    unavailable: dict[str, str]
    reference_source: str | None


def evaluation_maps(dataset: Dataset, fingerprints: Fingerprints, built_xy: np.ndarray, map_walks: list[str],
                    gauge: str, map_cfg: MapConfig) -> EvaluationMaps:
    """The built / surveyed / raw maps of the walks ``map_walks`` on one grid (common origin) and AP list
    (``fingerprints.bssids``), with the gauge of the module docstring. `rmbuild localize --hold-out` builds
    evaluate's built map through here. Raises InputError when the map walks have no readings."""
    unavailable: dict[str, str] = {}
    ref_xy, src = reference_positions(dataset)
    walk_of_node = dataset.poses["walk_id"].astype(str).to_numpy()
    map_nodes = np.flatnonzero(np.isin(walk_of_node, map_walks))
    raw_xy = dataset.poses[["x_m", "y_m"]].to_numpy(dtype=float)
    alignment: dict = {"built": gauge, "raw": "none"}
    built_al = built_xy
    if src is None:
        unavailable["errors"] = "no ground truth (neither truth poses nor fixes): no reference positions"
        unavailable["maps.surveyed"] = "no ground truth to build a surveyed map from"
        if gauge == "se2":
            unavailable["gauge"] = "se2 alignment needs reference positions; built map left in its own frame"
            alignment["built"] = "none"
    else:
        if gauge == "se2":
            r, t, info = _fit_se2(built_xy, ref_xy, map_nodes)
            built_al = _apply(r, t, built_xy)
            alignment["built_se2"] = info
        r, t, info = _fit_se2(raw_xy, ref_xy, map_nodes)
        raw_xy = _apply(r, t, raw_xy)
        alignment["raw"] = "se2"
        alignment["raw_se2"] = info
    positions = {"built": built_al, "raw": raw_xy}
    if src is not None:
        positions["surveyed"] = ref_xy
    origin = grid_origin(np.vstack([p[map_nodes] for p in positions.values()]), map_cfg.cell_size_m)
    wifi = dataset.wifi[dataset.wifi["walk_id"].astype(str).isin(set(map_walks))]
    wifi = wifi[pd.to_numeric(wifi["node"], errors="coerce").notna()]
    if len(wifi) == 0:
        raise InputError("the map walks have no Wi-Fi readings attached to nodes")
    bssids = np.asarray(fingerprints.bssids, dtype=object)
    maps: dict[str, RadioMap] = {}
    for name in MAP_NAMES:
        if name not in positions:
            continue
        frame = "building" if (name == "surveyed" or alignment.get(name) in (*BUILDING_FRAME_GAUGES, "se2")) else ""
        maps[name] = build_radio_map(wifi, positions[name], walk_of_node, map_cfg, origin, bssids=bssids,
                                     frame=frame)
    return EvaluationMaps(maps, built_al, alignment, unavailable, src)


def _checked_inputs(dataset: Dataset, built_xy: np.ndarray, cfg: EvaluateConfig, map_cfg: MapConfig,
                    gauge: str) -> np.ndarray:
    """``built_xy`` as float; InputError for a bad config, gauge, shape, no readings or unknown localizer."""
    for c in (cfg, map_cfg):
        try:
            c.validate()
        except ValueError as e:
            raise InputError(f"config: {e}") from None
    if gauge not in (*BUILDING_FRAME_GAUGES, "se2"):
        raise InputError(f"gauge must be one of {', '.join((*BUILDING_FRAME_GAUGES, 'se2'))}, got {gauge!r}")
    built_xy = np.asarray(built_xy, dtype=float)
    if built_xy.shape != (dataset.n_nodes, 2):
        raise InputError(f"built positions have shape {built_xy.shape}, expected ({dataset.n_nodes}, 2)")
    if dataset.wifi is None or len(dataset.wifi) == 0:
        raise InputError("no Wi-Fi readings: nothing to build a map from or to localize")
    from rmbuild.localize.base import localizer_class

    for name in cfg.localizers:
        localizer_class(name)  # unknown names fail before any work
    return built_xy


def _localize_all(maps: dict[str, RadioMap], cfg: EvaluateConfig, query: Query, q_ref: np.ndarray,
                  q_built: np.ndarray, have_truth: bool, progress: Callable[[str, dict], None] | None):
    """Every localizer on every map: (stats, errors, predictions, consistency) per map and localizer."""
    stats: dict[str, dict[str, dict]] = {}
    errors: dict[str, dict[str, np.ndarray]] = {}
    preds: dict[str, dict[str, np.ndarray]] = {}
    consistency: dict[str, dict[str, dict]] = {}
    total = len(maps) * len(cfg.localizers) * len(query)
    if progress:
        progress("maps", {"maps": len(maps), "total": total})
    for mname, rm in maps.items():
        stats[mname], errors[mname], preds[mname] = {}, {}, {}
        for lname in cfg.localizers:
            t_loc = time.perf_counter()
            if progress:
                progress("localize_start", {"map": mname, "localizer": lname, "scans": len(query)})
            loc = make_localizer(lname, cfg).fit(rm)
            p = np.asarray(loc.predict(query), dtype=float)
            preds[mname][lname] = p
            if progress:
                progress("localize", {"map": mname, "localizer": lname, "scans": len(query), "total": total,
                                      "done": sum(len(d) for d in preds.values()) * len(query),
                                      "time_s": time.perf_counter() - t_loc})
            if have_truth:
                err = np.hypot(*(p - q_ref).T)
                errors[mname][lname] = err
                # localizer-specific figures (e.g. SLAC's calibrated k, b, alpha, beta) beside the errors
                stats[mname][lname] = {**error_stats(err), **loc.summary()}
            if mname == "built":
                consistency.setdefault("built", {})[lname] = error_stats(np.hypot(*(p - q_built).T))
    return stats, errors, preds, consistency
