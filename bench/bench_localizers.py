"""Every localizer side by side on five test beds, and per-scan latency on a map of >= 1,000 RPs.
Writes bench/results/localizers.json and bench/results/localizers.md (the table).
Run: ``nice -n 10 python -m bench.bench_localizers`` (about 10-15 minutes on the 2-core machine);
``python -m bench.bench_localizers latency`` re-measures only the per-scan latency section.

Test beds (the map is always *surveyed*: built from the map walks' reference positions, 2 m cells):
  synthetic / same device: the `default` preset (seed 7), 4 test walks on a device with k = 1, b = 0.
  synthetic / other device: the same walks and noise on a device φ = 1.25 ψ − 6 dB. Its offline fit:
      both devices stand at 60 spots on the test walks' tracks, 20 scans each, one session per spot and
      device; :func:`rmbuild.baselines.calibration.fit_device_model` on the per-(spot, AP) means.
  ILC site1/F1 (dev floor): map from 4 of every 5 walks, the others are tests (evaluate's default split);
      reference positions = waypoints interpolated in time; phone PDR from the ILC reader.
  IPIN 2023 floor -2: map from the Samsung A5 (SM-A520F) walks, tests on the Galaxy S7 (SM-G930F) walks;
      reference = POSI marks interpolated in time; phone PDR from the IPIN reader (which PDR: see
      ``pdr`` in the result). Offline fit per test route from the S7 walks of the *other* routes
      (co-located 2 m cells of an S7 map against the A5 map).
  UJI long-term month 25: map = training set trn01 (Galaxy S3), tests tst06-10 (Galaxy A5), per floor
      (floor known); one RP per surveyed point. No motion data: sequence localizers are n/a. Offline fit:
      trn01 against trn02 (the A5's training set at the same points).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from bench.common import write_result

DEVICE = (1.25, -6.0)
SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
UJI = SHARED / "uji-longterm" / "db"
#: every registered localizer but the Kalman-smoothed variants of nb and ssd (knn_kf and slac_kf stand for them)
NAMES = ("knn", "wknn", "uiloc", "nb", "ssd", "ssr", "hist", "hist_dir", "hist@paper", "hist_dir@paper", "mll", "pfl",
         "slac", "smartloc", "smartloc_static", "knn_kf", "slac_kf", "offline_cal:knn", "offline_cal:mll",
         "offline_cal:pfl")
#: localizers that need each test walk's steps ("offline_cal:<base>" is `offline_cal` running <base>, as
#: SLAC's comparison ran FL, MLL and PFL on offline-calibrated scans; "<hist>@paper" is the histogram
#: localizer with the paper's mark scoring on unsmoothed histograms)
SEQUENCE = {"hist_dir", "hist_dir@paper", "mll", "pfl", "slac", "smartloc", "smartloc_static", "knn_kf", "slac_kf",
            "offline_cal:mll", "offline_cal:pfl"}


# ------------------------------------------------------------------------------------------------ cases
def _scenario(preset: str, test_device, n_test: int | None, cell_m: float, seed: int = 7):
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic import simulate

    c = preset_config(preset, seed)
    walkers = c.walkers if n_test is None else dataclasses.replace(c.walkers, n_test_walks=n_test)
    c = dataclasses.replace(c, walkers=walkers, devices=dataclasses.replace(c.devices, test_device=test_device))
    sd = simulate(c)
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses,
                   truth_aps=sd.truth_aps, venue=sd.venue)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    from rmbuild.evaluate.localization import split_walks

    maps, test, _ = split_walks(ds, EvaluateConfig())
    rm, q, qxy = surveyed_case(ds, fp.bssids, maps, test, cell_m)
    return sd, c, rm, q, qxy


def surveyed_case(ds, bssids, map_walks, test_walks, cell_m: float = 2.0):
    """(surveyed RadioMap of ``map_walks``, Query of ``test_walks``' scans, their reference xy)."""
    from rmbuild.config.radiomap import MapConfig
    from rmbuild.evaluate.localization import query_reference_xy, reference_positions
    from rmbuild.localize.base import Query
    from rmbuild.radiomap import build_radio_map

    ref, _ = reference_positions(ds)
    walk_of = ds.poses["walk_id"].astype(str).to_numpy()
    wifi = ds.wifi[ds.wifi["walk_id"].astype(str).isin(set(map_walks))]
    bssids = np.asarray(bssids, dtype=object)
    rm = build_radio_map(wifi, ref, walk_of, MapConfig(cell_size_m=cell_m), bssids=bssids)
    q = Query.from_dataset(ds, list(test_walks), bssids)
    return rm, q, query_reference_xy(ds, q)


def standing_means(sd, cfg, spots_xy: np.ndarray, device, n_scans: int = 20, seed: int = 1):
    """The offline calibration's data on the simulator: the map's device (k = 1, b = 0) and the test device
    each scan every spot ``n_scans`` times, standing, one session per spot. Returns (map means, device
    means) per (spot, AP) over the scans that detected the AP, and each device's lowest reading."""
    from rmbuild.synthetic.radio import scan_readings

    rng = np.random.default_rng(seed)
    model = sd.radio
    n_b = len(model.bssid)
    means, floors = [], []
    for k, b in ((1.0, 0.0), device):
        acc = np.zeros((len(spots_xy), n_b))
        cnt = np.zeros((len(spots_xy), n_b))
        low = np.inf
        for i, spot in enumerate(spots_xy):
            xy = np.repeat(spot[None], n_scans, axis=0)
            field = model.mean_rss_radios(xy)
            _, bi, rssi = scan_readings(model, cfg.radio, field, field, xy, rng.uniform(-np.pi, np.pi, n_scans),
                                        k, b, rng)
            np.add.at(acc[i], bi, rssi)
            np.add.at(cnt[i], bi, 1.0)
            low = min(low, float(rssi.min())) if len(rssi) else low
        means.append(np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan))
        floors.append(low)
    return means[0], means[1], (floors[0], floors[1])


def standing_fit(sd, cfg, spots_xy: np.ndarray, device, seed: int = 1, margins=(None,)):
    """(DeviceFit per margin (None = the default), OLS (k, b) on the same pairs) from :func:`standing_means`."""
    from rmbuild.baselines.calibration import FLOOR_MARGIN_DB, fit_device_model

    x, y, floors = standing_means(sd, cfg, spots_xy, device, seed=seed)
    ok = np.isfinite(x) & np.isfinite(y)
    ols = np.polyfit(x[ok], y[ok], 1)
    fits = [fit_device_model(x, y, floors, FLOOR_MARGIN_DB if m is None else m) for m in margins]
    return (fits[0] if len(fits) == 1 else fits), (float(ols[0]), float(ols[1]))


def fit_study(draws: int = 8) -> dict:
    """The offline fit's bias on the simulator: OLS vs :func:`fit_device_model` (floor margins 10 and 15 dB)
    over ``draws`` random draws of 60 and of 240 standing spots (the `default` venue, device 1.25 / -6 dB)."""
    sd, cfg, _, _, qxy = _scenario("default", DEVICE, 4, 2.0)
    inside = np.flatnonzero(np.isfinite(qxy).all(axis=1))
    out: dict = {"device": {"k": DEVICE[0], "b": DEVICE[1]}, "draws": draws}
    for n_spots in (60, 240):
        ks: dict[str, list] = {"ols": [], "fit_device_model (margin 10 dB)": [],
                               "fit_device_model (margin 15 dB, default)": []}
        for d in range(draws):
            rng = np.random.default_rng(100 + d)
            spots = qxy[rng.choice(inside, n_spots, replace=n_spots > len(inside))] + rng.normal(0, 0.5, (n_spots, 2))
            (f10, f15), ols = standing_fit(sd, cfg, spots, DEVICE, seed=200 + d, margins=(10.0, 15.0))
            ks["ols"].append(ols)
            ks["fit_device_model (margin 10 dB)"].append((f10.k, f10.b))
            ks["fit_device_model (margin 15 dB, default)"].append((f15.k, f15.b))
        out[f"{n_spots}_spots"] = {m: {"k_mean": round(float(np.mean([v[0] for v in r])), 3),
                                       "k_sd": round(float(np.std([v[0] for v in r])), 3),
                                       "b_mean": round(float(np.mean([v[1] for v in r])), 2),
                                       "b_sd": round(float(np.std([v[1] for v in r])), 2)} for m, r in ks.items()}
    print("fit study", out, flush=True)
    return out


def read_real(folder: Path, fmt: str):
    """A real data set read with rmbuild's own reader and ingest (default [pdr] and [ingest] config)."""
    from rmbuild.config import IngestConfig
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats import choose_reader, expand_inputs

    files = expand_inputs([folder])
    reader = choose_reader(files, fmt)
    raw = reader.read(files, IngestConfig())
    ds, fp, summary = build_dataset(raw, IngestConfig(), source=reader.name)
    pdr = [n for n in summary.get("notes", []) if "PDR" in n or "pdr" in n]
    return ds, fp, pdr


# ------------------------------------------------------------------------------------------------ runs
def _stats(e: np.ndarray, n_unlocalized: int | None = None) -> dict:
    """error_stats rounded; ``n_unlocalized``: scored scans without an estimate (n counts the others)."""
    from rmbuild.evaluate.localization import error_stats

    s = error_stats(e)
    if n_unlocalized is not None:
        s["n_unlocalized"] = n_unlocalized
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in s.items()}


def run_one(name: str, rm, q, qxy, calib=None, cfg=None) -> tuple[np.ndarray | None, dict]:
    """One localizer on one case: (per-scan errors (n,) m or None when n/a, extras for the report)."""
    from rmbuild.baselines.config import OfflineCalibrationConfig
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.localize.base import make_localizer

    cfg = cfg or EvaluateConfig()
    has_steps = q.steps is not None and any(len(v) for v in q.steps.values())
    if name in SEQUENCE and not has_steps:
        return None, {"n/a": "no step events"}
    reg_name = name
    if name.endswith("@paper"):
        hist = dataclasses.replace(cfg.baselines.hist, scoring="mark", smooth_db=0.0)
        cfg = dataclasses.replace(cfg, baselines=dataclasses.replace(cfg.baselines, hist=hist))
        reg_name = name.split("@")[0]
    if name.startswith("offline_cal"):
        if calib is None:
            return None, {"n/a": "no offline fit (same device)"}
        base = name.split(":")[1] if ":" in name else "knn"
        cal = OfflineCalibrationConfig(calib[0], calib[1], base)
        cfg = dataclasses.replace(cfg, baselines=dataclasses.replace(cfg.baselines, offline_cal=cal))
        reg_name = "offline_cal"
    t0 = time.perf_counter()
    loc = make_localizer(reg_name, cfg).fit(rm)
    p = np.asarray(loc.predict(q), dtype=float)
    scored = np.isfinite(qxy).all(axis=1)
    extra: dict = {"ms_per_scan": round(1000 * (time.perf_counter() - t0) / max(len(q), 1), 2),
                   "n_unlocalized": int((scored & ~np.isfinite(p).all(axis=1)).sum())}
    summ = {k: v for k, v in loc.summary().items() if v not in ([], None, {})}
    if summ:
        extra["summary"] = summ
    return np.hypot(*(p - qxy).T), extra


def run_case(rm, q, qxy, calib=None, names=NAMES, cfg=None) -> dict:
    """Every localizer of ``names`` on one case: error statistics, ms per scan, summary()."""
    out: dict = {}
    for name in names:
        e, extra = run_one(name, rm, q, qxy, calib, cfg)
        out[name] = extra if e is None else {**_stats(e), **extra}
    return out


def synthetic_cases() -> dict:
    out = {}
    _, _, rm, q, qxy = _scenario("default", (1.0, 0.0), 4, 2.0)
    out["synthetic / same device"] = {"n_scans": len(q), "n_rps": rm.n_cells, "localizers": run_case(rm, q, qxy)}
    print("synthetic same", _means(out["synthetic / same device"]), flush=True)
    sd, cfg, rm, q, qxy = _scenario("default", DEVICE, 4, 2.0)
    rng = np.random.default_rng(0)
    spots = qxy[rng.choice(np.flatnonzero(np.isfinite(qxy).all(axis=1)), 60, replace=False)]
    fit, ols = standing_fit(sd, cfg, spots, DEVICE)
    res = run_case(rm, q, qxy, (fit.k, fit.b))
    from rmbuild.baselines.calibration import calibrate_query
    from rmbuild.localize.knn import KnnLocalizer

    res["knn (true k, b)"] = _stats(np.hypot(*(KnnLocalizer().fit(rm).predict(calibrate_query(q, *DEVICE)) - qxy).T))
    out["synthetic / other device"] = {
        "n_scans": len(q), "n_rps": rm.n_cells, "device": {"k": DEVICE[0], "b": DEVICE[1]},
        "offline_fit": fit.to_json(), "offline_fit_ols": {"k": round(ols[0], 4), "b": round(ols[1], 3)},
        "localizers": res}
    print("synthetic device", _means(out["synthetic / other device"]), fit, ols, flush=True)
    return out


def ilc_case() -> dict:
    folder = SHARED / "msft-ilc20" / "data" / "site1" / "F1"
    if not folder.is_dir():
        return {"unavailable": "msft-ilc20 site1/F1 not present"}
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.evaluate.localization import split_walks

    ds, fp, pdr = read_real(folder, "msft-ilc")
    maps, test, rule = split_walks(ds, EvaluateConfig())
    rm, q, qxy = surveyed_case(ds, fp.bssids, maps, test)
    res = {"split": rule, "n_map_walks": len(maps), "n_test_walks": len(test), "n_scans": len(q),
           "n_rps": rm.n_cells, "pdr": pdr, "localizers": run_case(rm, q, qxy)}
    print("ilc F1", _means(res), flush=True)
    return res


def ipin_case() -> dict:
    folder = SHARED / "ipin2023" / "logs"
    if not folder.is_dir():
        return {"unavailable": "ipin2023 not present"}
    ds, fp, pdr = read_real(folder, "ipin")
    dev = dict(zip(ds.walks["walk_id"].astype(str), ds.walks["device_id"].astype(str), strict=True))
    a5 = [w for w, d in dev.items() if "A520F" in d]
    s7 = [w for w, d in dev.items() if "G930F" in d]
    rm, q, qxy = surveyed_case(ds, fp.bssids, a5, s7)
    fits = ipin_route_fits(ds, fp, rm, a5, s7)
    # offline_cal: each test route's scans mapped with the fit from the other routes' S7 walks
    from rmbuild.baselines.calibration import calibrate_query

    rss = q.rss_dbm.copy()
    for route, f in fits.items():
        rows = np.flatnonzero(np.char.find(q.walk_id.astype(str), route) >= 0)
        rss[rows] = calibrate_query(q.subset(rows), f.k, f.b).rss_dbm
    q_cal = dataclasses.replace(q, rss_dbm=rss)
    res = run_case(rm, q, qxy, names=[n for n in NAMES if not n.startswith("offline_cal")])
    for n in [n for n in NAMES if n.startswith("offline_cal")]:
        res[n] = run_case(rm, q_cal, qxy, names=[n.split(":")[1]])[n.split(":")[1]]
        res[n]["note"] = "S7 scans mapped by the fit from the other routes' S7 walks"
    first = {}
    for w in sorted(a5):
        first.setdefault(w.split("_repetition")[0], w)
    a5_map = sorted(first.values())
    same = run_case(*surveyed_case(ds, fp.bssids, a5_map, [w for w in a5 if w not in a5_map]),
                    names=("knn", "nb", "ssd", "hist", "hist_dir", "mll", "pfl", "slac", "smartloc", "smartloc_static"))
    out = {"map": f"{len(a5)} Galaxy A5 walks", "tests": f"{len(s7)} Galaxy S7 walks", "n_scans": len(q),
           "n_rps": rm.n_cells, "pdr": pdr, "offline_fits": {r: f.to_json() for r, f in fits.items()},
           "localizers": res, "same_device_reference": {
               "what": "map from the first A5 walk of each route, tests on the other A5 walk (same device)",
               "localizers": same}}
    print("ipin", _means(out), flush=True)
    return out


def ipin_route_fits(ds, fp, rm, a5: list[str], s7: list[str]) -> dict:
    """Per test route (TrainingTrialNN): the S7-vs-A5 fit from the S7 walks of every other route."""
    from rmbuild.baselines.calibration import colocated_pairs, fit_device_model

    routes = sorted({w.split("_repetition")[0] for w in s7})
    fits = {}
    for r in routes:
        others = [w for w in s7 if not w.startswith(r)]
        rm_s7, _, _ = surveyed_case(ds, fp.bssids, others, others[:1])
        # same grid: both maps' cells snap to multiples of the cell size from the same origin convention
        m, d = colocated_pairs(rm.reference_set("cells"), rm_s7.reference_set("cells"))
        fits[r] = fit_device_model(m, d)
    return fits


def _means(case: dict) -> dict:
    return {k: v.get("mean") for k, v in case["localizers"].items() if isinstance(v, dict)}


# ------------------------------------------------------------------------------------------------ UJI
def read_uji(month: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    """UJI long-term set ``db/MM/<name>{rss,crd}.csv.gz``: (RSSI (n, 620) float32 dBm with NaN = not
    detected (the file's 100), coordinates (n, 3) x m, y m, floor)."""
    import pandas as pd

    d = UJI / f"{month:02d}"
    rss = pd.read_csv(d / f"{name}rss.csv.gz", header=None).to_numpy(dtype=np.float32)
    crd = pd.read_csv(d / f"{name}crd.csv.gz", header=None).to_numpy(dtype=np.float64)
    rss[rss == 100] = np.nan
    return rss, crd


def uji_map(rss: np.ndarray, xy: np.ndarray, bssids: np.ndarray):
    """A RadioMap with one 0.5 m cell per surveyed point (every sample its own node and walk: no direction)."""
    import pandas as pd

    from rmbuild.config.radiomap import MapConfig
    from rmbuild.radiomap import build_radio_map

    r, c = np.nonzero(~np.isnan(rss))
    wifi = pd.DataFrame({"node": r, "t_s": 0.0, "bssid": bssids[c], "rssi_dbm": rss[r, c].astype(float)})
    return build_radio_map(wifi, xy, np.array([f"s{i}" for i in range(len(xy))]), MapConfig(cell_size_m=0.5),
                           bssids=bssids)


def uji_case() -> dict:
    if not UJI.is_dir():
        return {"unavailable": "uji-longterm not present"}
    from rmbuild.baselines.calibration import colocated_pairs, fit_device_model
    from rmbuild.localize.base import Query

    bssids = np.array([f"ap{j:03d}" for j in range(620)], dtype=object)
    m_rss, m_crd = read_uji(25, "trn01")
    a5_rss, a5_crd = read_uji(25, "trn02")
    parts = [read_uji(25, f"tst{i:02d}") for i in range(6, 11)]
    t_rss = np.vstack([p[0] for p in parts])
    t_crd = np.vstack([p[1] for p in parts])
    floors = np.unique(m_crd[:, 2])
    maps, pairs_m, pairs_d = {}, [], []
    for f in floors:
        maps[f] = uji_map(m_rss[m_crd[:, 2] == f], m_crd[m_crd[:, 2] == f, :2], bssids)
        rm_a5 = uji_map(a5_rss[a5_crd[:, 2] == f], a5_crd[a5_crd[:, 2] == f, :2], bssids)
        pm, pdv = colocated_pairs(maps[f].reference_set("cells"), rm_a5.reference_set("cells"))
        pairs_m.append(pm)
        pairs_d.append(pdv)
    fit = fit_device_model(np.vstack(pairs_m), np.vstack(pairs_d))
    out_loc: dict = {}
    for name in NAMES:
        if name in SEQUENCE:
            out_loc[name] = {"n/a": "no motion data in UJI"}
            continue
        err = np.full(len(t_rss), np.nan)
        for f in floors:
            qi = np.flatnonzero(t_crd[:, 2] == f)
            q = Query(t_rss[qi], bssids, np.arange(len(qi), dtype=float),
                      np.array(["q"] * len(qi), dtype=object), np.full(len(qi), -1, np.int64))
            e, _ = run_one(name, maps[f], q, t_crd[qi, :2], (fit.k, fit.b))
            err[qi] = e
        out_loc[name] = _stats(err)
    out = {"map": "month 25 trn01 (Galaxy S3), one RP per point, per floor", "tests": "tst06-10 (Galaxy A5)",
           "n_scans": len(t_rss), "offline_fit": fit.to_json(), "localizers": out_loc}
    print("uji", _means(out), flush=True)
    return out


# ------------------------------------------------------------------------------------------------ table
def table(cases: dict) -> list[str]:
    """Markdown: one row per localizer, mean / median (m) per case."""
    heads = [c for c in cases if "localizers" in cases[c]]
    names = list(dict.fromkeys(n for c in heads for n in cases[c]["localizers"]))
    lines = ["| localizer | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for n in names:
        cells = []
        for c in heads:
            e = cases[c]["localizers"].get(n)
            if e is None or "n/a" in e or e.get("mean") is None:
                cells.append("n/a")
            else:
                cells.append(f"{e['mean']:.2f} / {e['median']:.2f}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("mean / median position error in m over the test scans; n/a: the localizer needs step "
                 "events the data set has not, or (offline_cal) there is no device to calibrate.")
    return lines


def latency(reps: int = 3) -> dict:
    from rmbuild.baselines.config import SlacConfig
    from rmbuild.baselines.slac import SlacLocalizer
    from rmbuild.localize.base import make_localizer

    _, _, rm, q, qxy = _scenario("large", DEVICE, 2, 1.0)
    walks = q.walks()
    rows = np.sort(np.concatenate([r for _, r in walks[:2]]))
    q2 = q.subset(rows)
    out = {"preset": "large", "cell_size_m": 1.0, "n_rps": int(rm.n_cells), "n_aps": int(len(rm.bssids)),
           "n_scans": int(len(q2)), "realtime_budget_ms": 2000.0, "localizers": {}}
    locs = {n: make_localizer(n) for n in NAMES if not n.startswith("offline_cal") and "@" not in n}
    locs["slac_no_convergence"] = SlacLocalizer(SlacConfig(converge=False))
    out["repetitions"] = reps
    for name, loc in locs.items():
        loc.fit(rm)
        dts = []
        for _ in range(reps):  # median of reps: the shared machine's load changes between runs
            t0 = time.perf_counter()
            p = loc.predict(q2)
            dts.append(time.perf_counter() - t0)
        e = np.hypot(*(np.asarray(p) - qxy[rows]).T)
        out["localizers"][name] = {"ms_per_scan": round(1000 * float(np.median(dts)) / len(q2), 3),
                                   "mean_error_m": round(float(np.nanmean(e)), 2)}
        print("latency", name, out["localizers"][name], flush=True)
    return out


def main() -> None:
    cases = synthetic_cases()
    cases["ILC site1/F1 (surveyed)"] = ilc_case()
    cases["IPIN -2: A5 map, S7 tests"] = ipin_case()
    cases["UJI month 25: S3 map, A5 tests"] = uji_case()
    lines = table(cases)
    (Path(__file__).resolve().parent / "results" / "localizers.md").write_text("\n".join(lines) + "\n")
    p = write_result("localizers", {"table": lines, "cases": cases, "offline_fit_study": fit_study(),
                                    "latency": latency()})
    print("\n".join(lines))
    print(f"wrote {p}")


def update_latency() -> None:
    """Re-measure only the latency section (a few minutes), keeping the rest of localizers.json."""
    import json

    from bench.common import RESULTS

    p = RESULTS / "localizers.json"
    data = json.loads(p.read_text()) if p.exists() else {}
    data.pop("machine", None)
    data["latency"] = latency()
    print(f"wrote {write_result('localizers', data)}")


if __name__ == "__main__":
    import sys

    update_latency() if sys.argv[1:] == ["latency"] else main()
