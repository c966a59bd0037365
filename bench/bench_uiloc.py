"""UILoc pieces on the synthetic venue: the self-building map (merge within 1 m) and the fusion localizer's parts.
Writes bench/results/uiloc.json. Run: ``nice -n 10 python -m bench.bench_uiloc`` (about a minute).

1. Self-building map: the map walks' scans, each at its reference position, folded in with
   :func:`rmbuild.baselines.selfbuild.merge_fingerprints` at merge radius 0 (every scan its own RP), 1 m (the
   paper) and 2 m, beside today's surveyed 2 m grid map of the same walks; kNN (K = 15) on the test walks'
   scans. Two venues: the `default` preset (seed 7, test device k = 1, b = 0) and the same venue walked by
   three times as many walks (18 long, 12 short).
2. The `uiloc` localizer's parts on the `default` case: kNN alone, least squares alone, the anchor O
   alone, the fusion; with AP positions and path-loss model fitted from the map, and with the simulator's
   true AP positions (path loss refitted) to separate AP placement from ranging error.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.bench_localizers import surveyed_case
from bench.common import write_result


def _case(n_long: int, n_short: int):
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.evaluate.localization import query_reference_xy, split_walks
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.localize.base import Query
    from rmbuild.synthetic import simulate

    c = preset_config("default", 7)
    c = dataclasses.replace(
        c, walkers=dataclasses.replace(c.walkers, n_test_walks=4, n_long_walks=n_long, n_short_walks=n_short),
        devices=dataclasses.replace(c.devices, test_device=(1.0, 0.0)))
    sd = simulate(c)
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    maps, test, _ = split_walks(ds, EvaluateConfig())
    rm, q, qxy = surveyed_case(ds, fp.bssids, maps, test, 2.0)
    mq = Query.from_dataset(ds, list(maps), np.asarray(fp.bssids, dtype=object))
    mxy = query_reference_xy(ds, mq)
    ok = np.isfinite(mxy).all(axis=1)
    return sd, rm, q, qxy, mq.subset(ok), mxy[ok], len(maps)


def _err(p: np.ndarray, qxy: np.ndarray) -> dict:
    e = np.hypot(*(p - qxy).T)
    return {"mean": round(float(np.nanmean(e)), 2), "median": round(float(np.nanmedian(e)), 2),
            "p90": round(float(np.nanpercentile(e, 90)), 2), "max": round(float(np.nanmax(e)), 2),
            "n": int(np.isfinite(e).sum())}


def selfbuild_study() -> dict:
    from rmbuild.baselines.selfbuild import merge_fingerprints
    from rmbuild.localize.knn import KnnLocalizer

    out = {}
    for label, nl, ns in (("default", 6, 4), ("default, 3x the walks", 18, 12)):
        _, rm, q, qxy, mq, mxy, n_maps = _case(nl, ns)
        qa = q.aligned(mq.bssids)
        cells = rm.reference_set("cells")
        res: dict = {"n_map_walks": n_maps, "n_map_scans": len(mq), "n_test_scans": len(q),
                     "grid 2 m cells": {"n_rps": len(cells), **_err(KnnLocalizer().fit(cells).predict_rss(
                         qa.rss_dbm), qxy)}}
        for r in (0.0, 1.0, 2.0):
            ref = merge_fingerprints(None, mxy, mq.rss_dbm, mq.bssids, radius_m=r)
            res[f"merge radius {r:g} m"] = {"n_rps": len(ref),
                                            **_err(KnnLocalizer().fit(ref).predict_rss(qa.rss_dbm), qxy)}
        print(label, res, flush=True)
        out[label] = res
    return out


def fusion_parts() -> dict:
    from rmbuild.baselines.uiloc import UilocLocalizer, fit_path_loss

    sd, rm, q, qxy, _, _, _ = _case(6, 4)
    loc = UilocLocalizer().fit(rm)
    qa = q.aligned(loc.ref.bssids)
    true_xy = sd.truth_aps.set_index("bssid").reindex(loc.ref.bssids.astype(str))[["x_m", "y_m"]].to_numpy()
    out = {}
    for label, ap_xy in (("APs fitted from the map", None), ("true AP positions", true_xy)):
        if ap_xy is not None:
            loc.ap_xy = ap_xy
            loc.p0, loc.eta = fit_path_loss(loc.ref, ap_xy)
        b, o = loc.ls_estimates(qa.rss_dbm)
        out[label] = {
            "ap_error_median_m": round(float(np.nanmedian(np.hypot(*(loc.ap_xy - true_xy).T))), 2),
            "path_loss": {"p0_dbm": round(loc.p0, 2), "eta": round(loc.eta, 3)},
            "knn": _err(loc.knn.predict_rss(qa.rss_dbm), qxy), "least squares": _err(b, qxy),
            "anchor O": _err(o, qxy), "fused": _err(loc.predict(q), qxy), "summary": loc.summary()}
        print(label, out[label], flush=True)
    return out


def main() -> None:
    p = write_result("uiloc", {"selfbuild": selfbuild_study(), "fusion_parts": fusion_parts()})
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
