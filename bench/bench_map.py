"""kNN throughput on >= 5,000 reference points vs scikit-learn's brute-force KNeighborsRegressor and faiss's exact
IndexFlatL2 (when installed: ``pip install 'rmbuild[bench]'``), interleaved rounds repeated until every ratio is
stable, the machine's load stated per round; and export-map time on the `large` preset. Writes
bench/results/map.json.

The map is built from the `large` preset's true positions (the RP set is the map nodes' fingerprint
database: every map node with readings); queries are the test walks' scans. Both methods see the same
filled matrices (missing = -110 dBm) and K; agreement is checked on every query, against an exact float64
brute force: a neighbour set that differs from scikit-learn's is counted as a tie when the K-th and
(K+1)-th distances are equal.
"""

from __future__ import annotations

import os
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
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic import simulate

    sd = simulate(preset_config(preset, seed))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    return ds, fp, sd.venue


def _rate(n: int, dt: float) -> float:
    return round(n / dt, 1) if dt > 0 else float("inf")


def _timed(f, reps: int) -> list[float]:
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return out


def _cpu(f, reps: int) -> float:
    """Median CPU time (s, this process, every thread) of ``f`` over ``reps`` runs."""
    out = []
    for _ in range(reps):
        t0 = time.process_time()
        f()
        out.append(time.process_time() - t0)
    return float(np.median(out))


#: repetitions of the interleaved timings: at least MIN_ROUNDS, then until the median ratios of the last
#: STABLE_ROUNDS rounds differ by less than STABLE_REL (relative), at most MAX_ROUNDS
MIN_ROUNDS = 5
STABLE_ROUNDS = 3
STABLE_REL = 0.03
MAX_ROUNDS = 30


def _faiss():
    """faiss (the optional bench dependency ``rmbuild[bench]``), or None when it is not installed."""
    try:
        import faiss
    except ImportError:
        return None
    return faiss


def _until_stable(methods: dict, ratios: dict) -> dict:
    """Time every method once per round, interleaved, until each ratio's running median is stable (module
    constants); ``ratios``: name -> (numerator method, denominator method). Returns the per-round seconds and
    load, the median ratios and how many rounds it took."""
    runs: dict[str, list[float]] = {n: [] for n in methods}
    loads: list[float] = []
    medians: dict[str, list[float]] = {r: [] for r in ratios}
    for rnd in range(1, MAX_ROUNDS + 1):
        loads.append(os.getloadavg()[0])
        for name, f in methods.items():
            runs[name] += _timed(f, 1)
        for r, (a, b) in ratios.items():
            medians[r].append(float(np.median(np.array(runs[a]) / np.array(runs[b]))))
        last = {r: m[-STABLE_ROUNDS:] for r, m in medians.items()}
        if rnd >= MIN_ROUNDS and all(max(v) - min(v) <= STABLE_REL * float(np.median(v)) for v in last.values()):
            break
    return {"rounds": rnd, "stable": rnd < MAX_ROUNDS, "load_per_round": [round(v, 2) for v in loads],
            "seconds": {n: [round(v, 5) for v in t] for n, t in runs.items()},
            "ratio": {r: round(m[-1], 2) for r, m in medians.items()},
            "ratio_each_round": {r: [round(float(a / b), 2) for a, b in zip(runs[ratios[r][0]], runs[ratios[r][1]])]
                                 for r in ratios}}


def _cpu_one_thread(ours, sk, fa, q: np.ndarray, xq: np.ndarray, ns: int, reps: int, k: int) -> dict:
    """CPU time of every side on one thread each: every BLAS / OpenMP pool at one thread (faiss's too), and our
    batch's worker threads (``knn_search.THREADS``) too — the work each does, which other jobs on the machine
    hardly change (wall-clock ratios swing with load: scikit-learn's thread pools slow most when the cores are
    busy). Our batch with its default two workers is timed beside it (``ours_batch_two_workers``: the two
    threads' CPU time together)."""
    from threadpoolctl import threadpool_limits

    from rmbuild.localize import knn_search

    xq32 = xq.astype(np.float32)
    with threadpool_limits(1):
        workers = knn_search.THREADS
        t = {"ours_batch_two_workers": _cpu(lambda: ours.predict_rss(q), reps)}
        knn_search.THREADS = 1
        try:
            t.update({"ours_batch": _cpu(lambda: ours.predict_rss(q), reps),
                      "sklearn_batch": _cpu(lambda: sk.predict(xq), reps),
                      "ours_single": _cpu(lambda: [ours.predict_rss(q[i:i + 1]) for i in range(ns)], reps),
                      "sklearn_single": _cpu(lambda: [sk.predict(xq[i:i + 1]) for i in range(ns)], reps)})
            if fa is not None:
                faiss, index = fa
                faiss.omp_set_num_threads(1)
                t.update({"faiss_batch": _cpu(lambda: index.search(xq32, k), reps),
                          "faiss_single": _cpu(lambda: [index.search(xq32[i:i + 1], k) for i in range(ns)], reps)})
        finally:
            knn_search.THREADS = workers
    out = {"speedup_batch": round(t["sklearn_batch"] / t["ours_batch"], 2),
           "speedup_batch_two_workers": round(t["sklearn_batch"] / t["ours_batch_two_workers"], 2),
           "speedup_one_at_a_time": round(t["sklearn_single"] / t["ours_single"], 2),
           "cpu_s": {k2: round(v, 4) for k2, v in t.items()}}
    if fa is not None:
        out["vs_faiss_batch"] = round(t["faiss_batch"] / t["ours_batch"], 2)
        out["vs_faiss_one_at_a_time"] = round(t["faiss_single"] / t["ours_single"], 2)
    return out


def knn_bench(rm, q: np.ndarray, k: int = 15, n_single: int = 300, reps: int = 5) -> dict:
    """Our kNN against scikit-learn's brute force and faiss's exact IndexFlatL2 (when installed) on the map's
    node RPs (>= 5,000): batch and one query at a time, interleaved rounds repeated until the ratios are stable
    (:func:`_until_stable`), with the load of each round; neighbour sets compared with ties resolved."""
    from sklearn.neighbors import KNeighborsRegressor

    from rmbuild.localize.knn import KnnLocalizer

    ref = rm.reference_set("nodes")
    if len(ref) < 5000:
        ref = rm.reference_set("cells") if rm.n_cells > len(ref) else ref
    ours = KnnLocalizer(KnnConfig(k=k, reference="nodes"))
    fit_s = _timed(lambda: ours.fit(ref), 1)[0]
    xq = np.where(np.isnan(q), -110.0, q).astype(np.float64)
    xr = np.where(np.isnan(ref.rss_dbm), -110.0, ref.rss_dbm).astype(np.float64)
    sk = KNeighborsRegressor(n_neighbors=k, algorithm="brute").fit(xr, ref.xy)
    sk32 = KNeighborsRegressor(n_neighbors=k, algorithm="brute").fit(xr.astype(np.float32), ref.xy)
    xq32 = xq.astype(np.float32)
    faiss = _faiss()
    fa = None
    if faiss is not None:
        index = faiss.IndexFlatL2(xr.shape[1])
        index.add(xr.astype(np.float32))
        fa = (faiss, index)
    ours.predict_rss(q[:50])  # warm-up
    sk.predict(xq[:50])
    ns = min(n_single, len(q))
    methods = {"ours_batch": lambda: ours.predict_rss(q), "sklearn_batch": lambda: sk.predict(xq),
               "sklearn_batch_float32": lambda: sk32.predict(xq32),
               "ours_single": lambda: [ours.predict_rss(q[i:i + 1]) for i in range(ns)],
               "sklearn_single": lambda: [sk.predict(xq[i:i + 1]) for i in range(ns)]}
    ratios = {"batch": ("sklearn_batch", "ours_batch"), "one_at_a_time": ("sklearn_single", "ours_single")}
    if fa is not None:
        methods["faiss_batch"] = lambda: index.search(xq32, k)
        methods["faiss_single"] = lambda: [index.search(xq32[i:i + 1], k) for i in range(ns)]
        ratios.update({"faiss_batch": ("faiss_batch", "ours_batch"), "faiss_one_at_a_time": ("faiss_single",
                                                                                           "ours_single")})
    timing = _until_stable(methods, ratios)
    t = {n: float(np.median(v)) for n, v in timing["seconds"].items()}
    p_ours, p_sk = ours.predict_rss(q), sk.predict(xq)
    _, i_ours = ours.kneighbors(q)
    d_sk, i_sk = sk.kneighbors(xq)
    d_all = np.stack([((xr - x) ** 2).sum(axis=1) for x in xq])  # exact float64 brute force, row by row
    same = np.array([set(a) == set(b) for a, b in zip(i_ours, i_sk, strict=True)])
    # a differing set is right when the K-th and (K+1)-th distances tie exactly
    kth = np.sort(np.partition(d_all, k, axis=1)[:, :k + 1], axis=1)[:, k - 1:k + 1]
    tied = kth[:, 0] == kth[:, 1]
    ok = np.all(np.take_along_axis(d_all, i_ours, axis=1) <= kth[:, :1], axis=1)
    out = {
        "reference_points": int(len(ref)), "reference_kind": ref.kind, "aps": int(ref.rss_dbm.shape[1]),
        "queries": int(len(q)), "k": k, "single_queries": ns, "fit_s": round(fit_s, 3),
        "rounds": timing["rounds"], "stable": timing["stable"], "load_per_round": timing["load_per_round"],
        "queries_per_s": {n: _rate(len(q) if "batch" in n else ns, v) for n, v in t.items()},
        "speedup_batch": timing["ratio"]["batch"],
        "speedup_batch_each_run": timing["ratio_each_round"]["batch"],
        "speedup_one_at_a_time": timing["ratio"]["one_at_a_time"],
        "speedup_one_at_a_time_each_run": timing["ratio_each_round"]["one_at_a_time"],
        "faiss": ({"version": faiss.__version__, "index": "IndexFlatL2 (exact, float32)",
                   "speedup_batch": timing["ratio"]["faiss_batch"],
                   "speedup_one_at_a_time": timing["ratio"]["faiss_one_at_a_time"],
                   "speedup_batch_each_run": timing["ratio_each_round"]["faiss_batch"],
                   "speedup_one_at_a_time_each_run": timing["ratio_each_round"]["faiss_one_at_a_time"]}
                  if fa is not None else "not installed (pip install 'rmbuild[bench]')"),
        "one_thread_cpu": _cpu_one_thread(ours, sk, fa, q, xq, ns, reps, k),
        "target": {"speedup_batch": 3.0, "speedup_one_at_a_time": 10.0},
        "same_neighbour_sets": round(float(same.mean()), 4),
        "differing_sets_at_exact_ties": int((~same & tied).sum()),
        "differing_sets_not_ties": int((~same & ~tied).sum()),
        "all_sets_correct_up_to_ties": bool(ok.all()),
        "max_prediction_diff_m": round(float(np.abs(p_ours - p_sk).max()), 4),
        "max_distance_diff_db": round(float(np.abs(ours.kneighbors(q)[0] - d_sk).max()), 9),
    }
    return out


def main(preset: str = "large", seed: int = 7, k: int = 15, n_single: int = 300) -> dict:
    from rmbuild.localize.base import Query
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

    knn = knn_bench(rm, Query.from_dataset(ds, test, fp.bssids).rss_dbm, k, n_single)
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
        "knn": knn,
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }
    p = write_result("map", res)
    print(json.dumps(res, indent=1))
    print(f"wrote {p}")
    return res


if __name__ == "__main__":
    main()
