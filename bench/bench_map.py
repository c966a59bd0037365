"""kNN throughput on >= 5,000 reference points vs scikit-learn's brute-force KNeighborsRegressor (one run),
and export-map time on the `large` preset. Writes bench/results/map.json.

The map is built from the `large` preset's true positions (the RP set is the map nodes' fingerprint
database: every map node with readings); queries are the test walks' scans. Both methods see the same
filled matrices (missing = -110 dBm) and K; agreement is checked on every query.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import peak_rss_mb, write_result
from rmbuild.config.evaluate import KnnConfig
from rmbuild.config.radiomap import MapConfig
from rmbuild.viz.figures import coverage_figure, heatmaps_figure


def _dataset(preset: str, seed: int):
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.ingest_core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic import simulate

    sd = simulate(preset_config(preset, seed))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    return ds, fp, sd.venue


def _rate(n: int, dt: float) -> float:
    return round(n / dt, 1) if dt > 0 else float("inf")


def main(preset: str = "large", seed: int = 7, k: int = 15, n_single: int = 300) -> dict:
    from sklearn.neighbors import KNeighborsRegressor

    from rmbuild.localize.base import Query
    from rmbuild.localize.knn import KnnLocalizer
    from rmbuild.radiomap.build import build_radio_map

    t0 = time.perf_counter()
    ds, fp, venue = _dataset(preset, seed)
    t_data = time.perf_counter() - t0
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    test = [w for w, r in zip(ds.walks.walk_id, ds.walks.role, strict=True) if r == "test"]
    wifi_map = ds.wifi[~ds.wifi.walk_id.isin(test)]
    node_walk = ds.poses.walk_id.to_numpy()

    # ---- export-map: rasterise + tables + sidecar + figures, then the file writes
    times: dict[str, float] = {}
    cfg = MapConfig()
    t0 = time.perf_counter()
    rm = build_radio_map(wifi_map, truth, node_walk, cfg, bssids=fp.bssids, frame="building")
    times["build_radio_map"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    long, wide, side = rm.long_table(), rm.wide_table(), rm.sidecar()
    times["tables"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    figs = [coverage_figure(rm.cells, rm.cell_size_m, venue), heatmaps_figure(long, cfg.heatmap_top_n, venue)]
    times["figures_build"] = time.perf_counter() - t0
    tmp = Path(tempfile.mkdtemp(prefix="rmbuild-bench-map-"))
    try:
        t0 = time.perf_counter()
        long.to_parquet(tmp / "radiomap.parquet", index=False)
        wide.to_csv(tmp / "radiomap_uji.csv", index=False)
        import json

        (tmp / "radiomap.json").write_text(json.dumps(side))
        times["write_tables"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        for i, f in enumerate(figs):
            f.savefig(tmp / f"fig{i}.png", dpi=110)
        times["write_figures"] = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    t0 = time.perf_counter()
    from rmbuild.config.radiomap import FillConfig

    rm_idw = build_radio_map(wifi_map, truth, node_walk, MapConfig(fill=FillConfig(method="idw")),
                             bssids=fp.bssids)
    times["build_radio_map_idw_fill"] = time.perf_counter() - t0

    # ---- kNN throughput on the node reference set (>= 5,000 RPs)
    ref = rm.reference_set("nodes")
    if len(ref) < 5000:
        ref = rm.reference_set("cells") if rm.n_cells > len(ref) else ref
    q = Query.from_dataset(ds, test, fp.bssids).rss_dbm
    ours = KnnLocalizer(KnnConfig(k=k, reference="nodes")).fit(ref)
    xq = np.where(np.isnan(q), -110.0, q).astype(np.float64)
    xr = np.where(np.isnan(ref.rss_dbm), -110.0, ref.rss_dbm).astype(np.float64)
    sk = KNeighborsRegressor(n_neighbors=k, algorithm="brute").fit(xr, ref.xy)
    ours.predict_rss(q[:50])  # warm-up
    sk.predict(xq[:50])
    res_t: dict[str, float] = {}
    t0 = time.perf_counter()
    p_ours = ours.predict_rss(q)
    res_t["ours_batch"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    p_sk = sk.predict(xq)
    res_t["sklearn_batch"] = time.perf_counter() - t0
    xr32 = xr.astype(np.float32)
    sk32 = KNeighborsRegressor(n_neighbors=k, algorithm="brute").fit(xr32, ref.xy)
    t0 = time.perf_counter()
    sk32.predict(xq.astype(np.float32))
    res_t["sklearn_batch_float32"] = time.perf_counter() - t0
    ns = min(n_single, len(q))
    t0 = time.perf_counter()
    for i in range(ns):
        ours.predict_rss(q[i:i + 1])
    res_t["ours_single"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    for i in range(ns):
        sk.predict(xq[i:i + 1])
    res_t["sklearn_single"] = time.perf_counter() - t0
    _, i_ours = ours.kneighbors(q)
    _, i_sk = sk.kneighbors(xq)
    same = float(np.mean([set(a) == set(b) for a, b in zip(i_ours, i_sk, strict=True)]))
    max_diff = float(np.abs(p_ours - p_sk).max())

    res = {
        "preset": preset,
        "seed": seed,
        "dataset": {"nodes": int(ds.n_nodes), "readings": int(len(ds.wifi)), "aps": int(len(fp.bssids)),
                    "simulate_ingest_s": round(t_data, 2)},
        "export_map": {
            "cell_size_m": cfg.cell_size_m, "cells": rm.n_cells, "cells_idw_fill": rm_idw.n_cells,
            "long_rows": int(len(long)), "map_readings": int(len(wifi_map)),
            "time_s": {k2: round(v, 3) for k2, v in times.items()},
            "total_s": round(sum(v for k2, v in times.items() if k2 != "build_radio_map_idw_fill"), 3),
        },
        "knn": {
            "reference_points": int(len(ref)), "reference_kind": ref.kind, "aps": int(ref.rss_dbm.shape[1]),
            "queries": int(len(q)), "k": k, "single_queries": ns,
            "queries_per_s": {
                "ours_batch": _rate(len(q), res_t["ours_batch"]),
                "sklearn_brute_batch": _rate(len(q), res_t["sklearn_batch"]),
                "sklearn_brute_batch_float32": _rate(len(q), res_t["sklearn_batch_float32"]),
                "ours_one_at_a_time": _rate(ns, res_t["ours_single"]),
                "sklearn_brute_one_at_a_time": _rate(ns, res_t["sklearn_single"]),
            },
            "speedup_batch": round(res_t["sklearn_batch"] / res_t["ours_batch"], 2),
            "speedup_one_at_a_time": round(res_t["sklearn_single"] / res_t["ours_single"], 2),
            "same_neighbour_sets": same,
            "max_prediction_diff_m": max_diff,
        },
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }
    p = write_result("map", res)
    print(json.dumps(res, indent=1))
    print(f"wrote {p}")
    return res


if __name__ == "__main__":
    main()
