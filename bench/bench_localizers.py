"""Every localizer side by side under device heterogeneity, and per-scan latency on a map of >= 1,000 RPs.
Writes bench/results/localizers.json. Run: ``python -m bench.bench_localizers`` (about 2-4 minutes).

Accuracy: the `default` preset (seed 7) with 4 test walks, the surveyed map (true positions of the map
walks, 2 m cells) and the test walks' scans:
  (a) same device: test walks on a device with k = 1, b = 0 (the map devices are k ~ 1 ± 0.05, b ~ 0 ± 2 dB);
  (b) different device, uncalibrated: k = 1.25, b = −6 dB (φ_device = k ψ + b) — same walks and noise;
  (c) (b) with the offline linear fit from co-located readings: both devices scan 60 spots on the test
      walks' tracks 20 times each, standing; per (spot, AP) means where both detect the AP in >= 60 % of
      scans; OLS device = k · map + b (He et al. 2015, ref. [21]). Queries mapped back with it; SLAC then
      runs with [k, b] fixed at (1, 0) (P = 1); kNN "true calibration" maps them back with the true k, b.
Real data: UJI long-term month 25 (Galaxy S3 map, Galaxy A5 test sets), fingerprint-only localizers.
Latency: the `large` preset's surveyed map (1 m cells, >= 1,000 RPs); per-scan wall time of each localizer
over the test walks' scans, one walk after the other (SLAC: P = 60, M = 7, with and without convergence).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from bench.common import write_result

DEVICE = (1.25, -6.0)


def _scenario(preset: str, test_device, n_test: int | None, cell_m: float, seed: int = 7):
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.radiomap import MapConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.evaluate.localization import reference_positions, split_walks
    from rmbuild.ingest_core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.localize.base import Query
    from rmbuild.radiomap import build_radio_map
    from rmbuild.synthetic import simulate

    c = preset_config(preset, seed)
    walkers = c.walkers if n_test is None else dataclasses.replace(c.walkers, n_test_walks=n_test)
    c = dataclasses.replace(c, walkers=walkers, devices=dataclasses.replace(c.devices, test_device=test_device))
    sd = simulate(c)
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    maps, test, _ = split_walks(ds, EvaluateConfig())
    ref, _ = reference_positions(ds)
    walk_of = ds.poses["walk_id"].astype(str).to_numpy()
    wifi = ds.wifi[ds.wifi["walk_id"].astype(str).isin(maps)]
    bssids = np.asarray(fp.bssids, dtype=object)
    rm = build_radio_map(wifi, ref, walk_of, MapConfig(cell_size_m=cell_m), bssids=bssids)
    q = Query.from_dataset(ds, test, bssids)
    tp = ds.truth_poses
    qxy = np.full((len(q), 2), np.nan)
    for wid, rows in q.walks():
        g = tp[tp["walk_id"].astype(str) == wid]
        qxy[rows, 0] = np.interp(q.t_s[rows], g["t_s"], g["x_m"])
        qxy[rows, 1] = np.interp(q.t_s[rows], g["t_s"], g["y_m"])
    return sd, c, rm, q, qxy


def offline_fit(sd, cfg, spots_xy: np.ndarray, device, n_scans: int = 20, seed: int = 1):
    """Seed 000's offline calibration on the simulator: map device (k = 1, b = 0) and test device scan the
    same spots ``n_scans`` times each, standing; OLS over per-(spot, AP) means both detect >= 60 %."""
    from rmbuild.localize.slac import fit_device_model
    from rmbuild.synthetic.radio import scan_readings

    rng = np.random.default_rng(seed)
    model = sd.radio
    field = model.mean_rss_radios(spots_xy)
    n_b = len(model.bssid)
    means = []
    for k, b in ((1.0, 0.0), device):
        acc = np.zeros((len(spots_xy), n_b))
        cnt = np.zeros((len(spots_xy), n_b))
        for _ in range(n_scans):
            heading = rng.uniform(-np.pi, np.pi, len(spots_xy))
            si, bi, rssi = scan_readings(model, cfg.radio, field, field, spots_xy, heading, k, b, rng)
            np.add.at(acc, (si, bi), rssi)
            np.add.at(cnt, (si, bi), 1.0)
        with np.errstate(invalid="ignore"):
            means.append(np.where(cnt >= 0.6 * n_scans, acc / np.maximum(cnt, 1), np.nan))
    return fit_device_model(means[0], means[1])


def _localizers(case: str, calib: tuple[float, float] | None):
    from rmbuild.config.evaluate import KnnConfig
    from rmbuild.config.localize import SlacConfig
    from rmbuild.localize.bayes import NaiveBayesLocalizer
    from rmbuild.localize.knn import KnnLocalizer, WeightedKnnLocalizer
    from rmbuild.localize.pfl import PflLocalizer
    from rmbuild.localize.slac import SlacLocalizer
    from rmbuild.localize.smoothing import KalmanSmoothed
    from rmbuild.localize.ssd import SsdLocalizer

    slac_cfg = SlacConfig() if case != "c" else SlacConfig(k_range=(1.0, 1.0), b_range_db=(0.0, 0.0),
                                                           n_particles=1)
    return {
        "knn": KnnLocalizer(), "wknn": WeightedKnnLocalizer(),
        "knn_exclude": KnnLocalizer(KnnConfig(missing="exclude")),
        "nb": NaiveBayesLocalizer(), "ssd": SsdLocalizer(), "pfl": PflLocalizer(),
        "slac": SlacLocalizer(slac_cfg),
        "knn_kf": KalmanSmoothed(KnnLocalizer()), "slac_kf": KalmanSmoothed(SlacLocalizer(slac_cfg)),
    }


def _stats(e: np.ndarray) -> dict:
    from rmbuild.evaluate.localization import error_stats

    s = error_stats(e)
    s["n_unlocalized"] = int(np.isnan(e).sum())
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in s.items()}


def accuracy() -> dict:
    from rmbuild.localize.knn import KnnLocalizer
    from rmbuild.localize.slac import calibrate_query

    out: dict = {"preset": "default", "seed": 7, "n_test_walks": 4, "cell_size_m": 2.0, "map": "surveyed",
                 "test_device": {"k": DEVICE[0], "b": DEVICE[1], "model": "phi_device = k * psi_map + b"}}
    cases = {}
    for case, dev in (("a_same_device", (1.0, 0.0)), ("b_uncalibrated", DEVICE), ("c_offline_fit", DEVICE)):
        sd, cfg, rm, q, qxy = _scenario("default", dev, 4, 2.0)
        calib = None
        res: dict = {}
        if case.startswith("c"):
            rng = np.random.default_rng(0)
            pick = rng.choice(np.flatnonzero(np.isfinite(qxy).all(axis=1)), 60, replace=False)
            k, b, n = offline_fit(sd, cfg, qxy[pick], dev)
            calib = (k, b)
            res["offline_fit"] = {"k": round(k, 4), "b": round(b, 3), "n_pairs": n}
            q = calibrate_query(q, k, b)
        res["n_scans"] = int(len(q))
        res["n_rps"] = int(rm.n_cells)
        loc_out = {}
        for name, loc in _localizers(case[0], calib).items():
            t0 = time.perf_counter()
            p = loc.fit(rm).predict(q)
            dt = time.perf_counter() - t0
            e = np.hypot(*(np.asarray(p) - qxy).T)
            entry = _stats(e)
            entry["ms_per_scan"] = round(1000 * dt / len(q), 2)
            summ = loc.summary() if name not in ("knn", "wknn", "knn_exclude") else {}
            if summ:
                entry["summary"] = summ
            if name == "slac":
                entry["walks"] = [r.to_json() for r in loc.diagnostics.values()]
            loc_out[name] = entry
        if case.startswith("b"):
            for name, cfgk in (("knn_true_calibration", None),):
                p = KnnLocalizer(cfgk).fit(rm).predict(calibrate_query(q, *dev))
                loc_out[name] = _stats(np.hypot(*(p - qxy).T))
        res["localizers"] = loc_out
        cases[case] = res
        print(case, {k: v["mean"] for k, v in loc_out.items()}, flush=True)
    out["cases"] = cases
    b = cases["b_uncalibrated"]["localizers"]
    s = b["slac"]["summary"]
    out["done_when"] = {
        "slac_k": s["k"], "slac_b": s["b"],
        "k_within_10pct": abs(s["k"] - DEVICE[0]) <= 0.1 * DEVICE[0],
        "b_within_2db": abs(s["b"] - DEVICE[1]) <= 2.0,
        "slac_vs_uncalibrated_knn": round(b["slac"]["mean"] / b["knn"]["mean"], 3),
        "slac_vs_true_calibrated_knn": round(b["slac"]["mean"] / b["knn_true_calibration"]["mean"], 3),
    }
    return out


def latency() -> dict:
    from rmbuild.config.localize import SlacConfig
    from rmbuild.localize.slac import SlacLocalizer

    sd, cfg, rm, q, qxy = _scenario("large", DEVICE, 2, 1.0)
    walks = q.walks()
    rows = np.concatenate([r for _, r in walks[:2]])
    q2 = q.subset(np.sort(rows))
    out = {"preset": "large", "cell_size_m": 1.0, "n_rps": int(rm.n_cells), "n_aps": int(len(rm.bssids)),
           "n_scans": int(len(q2)), "realtime_budget_ms": 2000.0, "localizers": {}}
    locs = dict(_localizers("b", None))
    locs["slac_no_convergence"] = SlacLocalizer(SlacConfig(converge=False))
    for name, loc in locs.items():
        loc.fit(rm)
        t0 = time.perf_counter()
        p = loc.predict(q2)
        dt = time.perf_counter() - t0
        e = np.hypot(*(np.asarray(p) - qxy[np.sort(rows)]).T)
        out["localizers"][name] = {"ms_per_scan": round(1000 * dt / len(q2), 3),
                                   "mean_error_m": round(float(np.nanmean(e)), 2)}
        print("latency", name, out["localizers"][name], flush=True)
    return out


def main() -> None:
    res = {"accuracy": accuracy(), "latency": latency(), "uji_month25": uji_device_change()}
    p = write_result("localizers", res)
    print(f"wrote {p}")



UJI = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "uji-longterm" / "db"


def read_uji(month: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    """UJI long-term set ``db/MM/<name>{rss,crd}.csv.gz``: (RSSI (n, 620) float32 dBm with NaN = not
    detected (the file's 100), coordinates (n, 3) x m, y m, floor)."""
    import pandas as pd

    d = UJI / f"{month:02d}"
    rss = pd.read_csv(d / f"{name}rss.csv.gz", header=None).to_numpy(dtype=np.float32)
    crd = pd.read_csv(d / f"{name}crd.csv.gz", header=None).to_numpy(dtype=np.float64)
    rss[rss == 100] = np.nan
    return rss, crd


def _uji_reference(rss: np.ndarray, crd: np.ndarray):
    """One RP per distinct (x, y, floor): per-AP mean and unbiased std of its samples."""
    from rmbuild.localize.base import ReferenceSet  # noqa: F811

    key, inv = np.unique(np.round(crd, 3), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n, m = len(key), rss.shape[1]
    det = ~np.isnan(rss)
    v = np.nan_to_num(rss).astype(np.float64)
    cnt = np.zeros((n, m))
    s = np.zeros((n, m))
    s2 = np.zeros((n, m))
    np.add.at(cnt, inv, det)
    np.add.at(s, inv, v)
    np.add.at(s2, inv, v * v)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, s / cnt, np.nan)
        var = np.where(cnt > 1, (s2 - cnt * mean ** 2) / (cnt - 1), np.nan)
    std = np.sqrt(np.maximum(var, 0.0))
    return ReferenceSet(key[:, :2], mean.astype(np.float32), np.array([f"ap{j:03d}" for j in range(m)], dtype=object),
                        std.astype(np.float32)), key[:, 2]


def uji_device_change() -> dict:
    """Month 25: map from trn01 (Galaxy S3); tests tst01-05 (S3) vs tst06-10 (Galaxy A5, a real device
    change); (c) A5 queries mapped back by an offline fit A5 = k S3 + b on the co-located training sets
    trn01 (S3) / trn02 (A5) (same RPs). Fingerprint-only localizers, per floor (floor taken as known)."""
    from rmbuild.localize.base import Query
    from rmbuild.localize.bayes import NaiveBayesLocalizer
    from rmbuild.localize.knn import KnnLocalizer, WeightedKnnLocalizer
    from rmbuild.localize.slac import calibrate_query, fit_device_model
    from rmbuild.localize.ssd import SsdLocalizer

    if not UJI.is_dir():
        return {"unavailable": "../shared/datasets/uji-longterm not present"}
    m_rss, m_crd = read_uji(25, "trn01")
    a5_rss, a5_crd = read_uji(25, "trn02")
    ref, floor = _uji_reference(m_rss, m_crd)
    ref_a5, floor_a5 = _uji_reference(a5_rss, a5_crd)
    # co-located per-RP means: S3 map vs A5 training set at the same points
    pos = {tuple(np.round(np.r_[p, f], 3)): i for i, (p, f) in enumerate(zip(ref.xy, floor, strict=True))}
    rows = [(pos[tuple(np.round(np.r_[p, f], 3))], j) for j, (p, f) in enumerate(zip(ref_a5.xy, floor_a5, strict=True))
            if tuple(np.round(np.r_[p, f], 3)) in pos]
    ia, ib = np.array(rows).T
    k, b, n_pairs = fit_device_model(ref.rss_dbm[ia], ref_a5.rss_dbm[ib])
    out: dict = {"map": "month 25 trn01 (Galaxy S3)", "n_rps": int(len(ref)),
                 "offline_fit_a5_vs_s3": {"k": round(k, 4), "b": round(b, 3), "n_pairs": n_pairs}, "cases": {}}
    sets = {"a_same_device": ["tst01", "tst02", "tst03", "tst04", "tst05"],
            "b_uncalibrated": ["tst06", "tst07", "tst08", "tst09", "tst10"],
            "c_offline_fit": ["tst06", "tst07", "tst08", "tst09", "tst10"]}
    for case, names in sets.items():
        parts = [read_uji(25, nm) for nm in names]
        rss = np.vstack([p[0] for p in parts])
        crd = np.vstack([p[1] for p in parts])
        q = Query(rss, ref.bssids, np.arange(len(rss), dtype=float), np.array(["q"] * len(rss), dtype=object),
                  np.full(len(rss), -1, np.int64))
        if case.startswith("c"):
            q = calibrate_query(q, k, b)
        res = {}
        for name, mk in (("knn", KnnLocalizer), ("wknn", WeightedKnnLocalizer), ("nb", NaiveBayesLocalizer),
                         ("ssd", SsdLocalizer)):
            err = np.full(len(rss), np.nan)
            for f in np.unique(floor):
                rp = floor == f
                sub = _rows_of(ref, rp)
                qi = np.flatnonzero(crd[:, 2] == f)
                p = mk().fit(sub).predict(q.subset(qi))
                err[qi] = np.hypot(*(p - crd[qi, :2]).T)
            res[name] = _stats(err)
        out["cases"][case] = {"n_scans": int(len(rss)), "localizers": res}
        print("uji", case, {k2: v["mean"] for k2, v in res.items()}, flush=True)
    return out


def _rows_of(ref, rows):
    """The RPs ``rows`` of a ReferenceSet."""
    from rmbuild.localize.base import ReferenceSet

    return ReferenceSet(ref.xy[rows], ref.rss_dbm[rows], ref.bssids, None if ref.std_db is None else ref.std_db[rows])


if __name__ == "__main__":
    main()
