"""Phone PDR on all the real data and on synthetic ways of carrying a phone.

*Own-fit error*: each walk's PDR poses, interpolated at the times of its ground-truth marks, rigidly fitted
(SE(2), no scale) to those marks; the error at the marks. An evaluation only: it never enters the PDR.

- Microsoft ILC 2.0, five floors: per floor the own-fit error at the waypoints (mean / median / P90, pooled
  over the floor's walks, the figure the project quotes), PDR distance / waypoint polyline (median), steps,
  quality flags, parse + PDR time.
- IPIN 2023 floor -2: per walk the mean own-fit error over its POSI marks; median / mean / max over walks,
  walks above 5 m, by phone (median) and by route group (routes 21-23 / 24-27), PDR distance / straight path
  through the marks, cadence.
- Synthetic: per carrying mode and sample rate, seeded walks (pauses, turns on the spot, gentle to brisk
  gaits, a 0.3 °/s-per-axis gyro bias, timestamp jitter): step count error (total and worst walk) and
  heading drift (°/min, slope of the heading error over the walk; median and max over walks).

    python -m bench.bench_pdr [--data ../shared/datasets] [--seeds 4] [--out bench/results/bench_pdr.json]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common import write_result
from rmbuild.config.ingest import IngestConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.config.simulate import CARRY_MODES
from rmbuild.geometry import wrap as wrap_angle
from rmbuild.ingest.core import derive_poses
from rmbuild.io.formats.ipin import IpinReader
from rmbuild.io.formats.msft_ilc import MsftIlcReader
from rmbuild.pdr import run_pdr
from rmbuild.pdr.synth import synthesize_phone_imu

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets"
FLOORS = ("site1/F1", "site1/F2", "site2/B1", "site2/F4", "site2/F6")
RATES_HZ = (50.0, 100.0, 200.0)


def own_fit(poses: pd.DataFrame, marks: pd.DataFrame) -> np.ndarray:
    """Errors (m) at the marks of the walk's PDR positions after the best rigid 2-D fit onto the marks."""
    t = marks["t_s"].to_numpy(float)
    p = np.c_[np.interp(t, poses["t_s"], poses["x_m"]), np.interp(t, poses["t_s"], poses["y_m"])]
    q = marks[["x_m", "y_m"]].to_numpy(float)
    pc, qc = p - p.mean(0), q - q.mean(0)
    h = pc.T @ qc
    a = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return np.linalg.norm(pc @ r.T - qc, axis=1)


def _path_ratio(poses: pd.DataFrame, marks: pd.DataFrame) -> float:
    """PDR distance between the first and last mark / length of the polyline through the marks."""
    t0, t1 = marks["t_s"].min(), marks["t_s"].max()
    xy = poses[["x_m", "y_m"]].to_numpy(float)
    seg = np.r_[0.0, np.hypot(*np.diff(xy, axis=0).T)]
    inside = (poses["t_s"].to_numpy() > t0) & (poses["t_s"].to_numpy() <= t1)
    path = np.hypot(*np.diff(marks[["x_m", "y_m"]].to_numpy(float), axis=0).T).sum()
    return float(seg[inside].sum() / max(path, 1e-9))


def _walks(raw, min_marks: int) -> list[tuple[str, pd.DataFrame, pd.DataFrame]]:
    fx = raw.fixes.groupby("walk_id")
    ps = raw.poses.groupby("walk_id")
    return [(w, ps.get_group(w).sort_values("t_s"), m.sort_values("t_s")) for w, m in fx if len(m) >= min_marks]


def ilc_floor(folder: Path, cfg: PdrConfig) -> dict:
    files = sorted((folder / "path_data_files").glob("*.txt*"))
    t, c = time.perf_counter(), time.process_time()
    raw = MsftIlcReader().read(files, IngestConfig())
    reports, _ = derive_poses(raw, cfg)
    t_wall, t_cpu = time.perf_counter() - t, time.process_time() - c
    errs, walk_mean, ratios = [], [], []
    for _, poses, marks in _walks(raw, 2):
        e = own_fit(poses, marks)
        errs.append(e)
        walk_mean.append(e.mean())
        ratios.append(_path_ratio(poses, marks))
    e = np.concatenate(errs)
    q = pd.Series([r.quality for r in reports.values()]).value_counts().to_dict()
    return {"walks": len(errs), "steps": int(sum(r.steps for r in reports.values())),
            "own_fit_mean_m": round(float(e.mean()), 3), "own_fit_median_m": round(float(np.median(e)), 3),
            "own_fit_p90_m": round(float(np.percentile(e, 90)), 3),
            "walk_mean_error_median_m": round(float(np.median(walk_mean)), 3),
            "path_ratio_median": round(float(np.median(ratios)), 3), "quality": q,
            "read_pdr_wall_s": round(t_wall, 1), "read_pdr_cpu_s": round(t_cpu, 1)}


def ipin_floor(folder: Path, cfg: PdrConfig) -> dict:
    files = sorted(folder.glob("*.txt*"))
    t = time.perf_counter()
    raw = IpinReader().read(files, IngestConfig())
    reports, _ = derive_poses(raw, cfg)
    t_wall = time.perf_counter() - t
    device = dict(zip(raw.walks["walk_id"], raw.walks["device_id"]))
    rows = []
    for w, poses, marks in _walks(raw, 3):
        q = marks[["x_m", "y_m"]].to_numpy(float)
        d = np.hypot(*np.diff(q, axis=0).T).sum()
        walked = np.hypot(*np.diff(poses[["x_m", "y_m"]].to_numpy(float), axis=0).T)
        tp = poses["t_s"].to_numpy()[1:]
        inside = (tp > marks["t_s"].min()) & (tp <= marks["t_s"].max())
        r = reports[w]
        rows.append({"walk": w, "phone": device[w].split()[-1], "route": int(w.split("Trial")[1][:2]),
                     "error_m": float(own_fit(poses, marks).mean()), "ratio": float(walked[inside].sum() / d),
                     "steps": r.steps, "cadence_hz": r.cadence_hz, "bias_dps": r.gyro_bias_dps,
                     "bias_from": r.bias_source, "quality": r.quality})
    df = pd.DataFrame(rows)
    e = df["error_m"]
    by_phone = df.groupby("phone")["error_m"].median().round(3).to_dict()
    return {"walks": len(df), "own_fit_median_m": round(float(e.median()), 3),
            "own_fit_mean_m": round(float(e.mean()), 3), "own_fit_max_m": round(float(e.max()), 3),
            "walks_above_5m": int((e > 5).sum()), "by_phone_median_m": by_phone,
            "phone_ratio": round(max(by_phone.values()) / min(by_phone.values()), 3),
            "routes_21_23_median_m": round(float(e[df["route"] <= 23].median()), 3),
            "routes_24_27_median_m": round(float(e[df["route"] >= 24].median()), 3),
            "path_ratio_median": round(float(df["ratio"].median()), 3),
            "cadence_median_hz": round(float(df["cadence_hz"].median()), 3),
            "read_pdr_wall_s": round(t_wall, 1),
            "per_walk": df.round(3).to_dict("records")}


def _synthetic_walk(seed: int) -> tuple[np.ndarray, np.ndarray, np.random.Generator]:
    """Four bouts of 25-60 steps (1.4-2.2 steps/s, slow turns and some 22.5° corners), each followed by a 5-20 s
    pause that ends in a turn on the spot."""
    rng = np.random.default_rng([seed, 18])
    ts, hs, t, h = [], [], 0.0, rng.uniform(-np.pi, np.pi)
    f = rng.uniform(1.4, 2.2)
    for _ in range(4):
        for _ in range(int(rng.integers(25, 60))):
            t += rng.uniform(0.95, 1.05) / f
            h += rng.normal(0, 0.03) + (rng.choice([-1, 1]) * np.pi / 8 if rng.random() < 0.03 else 0.0)
            ts.append(t)
            hs.append(h)
        t += rng.uniform(5.0, 20.0)
        h += rng.uniform(-np.pi, np.pi)
    return np.array(ts), np.array(hs), rng


def drift_deg_per_min(t_s: np.ndarray, heading_rad: np.ndarray, st: np.ndarray, hd: np.ndarray) -> float:
    """Drift (°/min) of the PDR heading: robust (Theil-Sen) slope of its error at the true step times, over the
    steps on straight stretches (a stride-averaged heading lags at corners: an error, but not a drift)."""
    from scipy.stats import theilslopes

    err = np.unwrap(wrap_angle(np.interp(st, t_s, np.unwrap(heading_rad)) - (hd - hd[0])))
    steady = np.abs(np.r_[hd[2:], [hd[-1]] * 2] - np.r_[[hd[0]] * 2, hd[:-2]]) < np.deg2rad(5.0)
    return float(theilslopes(np.degrees(err[steady]), st[steady] / 60.0)[0])


def synthetic(cfg: PdrConfig, seeds: int) -> dict:
    out: dict = {}
    for mode in CARRY_MODES:
        for fs in RATES_HZ:
            d_steps, n_true, worst, drift = 0, 0, 0.0, []
            for s in range(seeds):
                st, hd, rng = _synthetic_walk(1000 * s + int(fs))
                bounce = (0.6, 1.0, 1.4)[s % 3]
                imu = synthesize_phone_imu(st, hd, rng, mode=mode, fs_hz=fs, bounce_scale=bounce,
                                           gyro_bias_radps=np.deg2rad(rng.normal(0.0, 0.3, 3)))
                p = run_pdr(imu, cfg).poses
                d_steps += len(p) - 1 - len(st)
                n_true += len(st)
                worst = max(worst, abs(len(p) - 1 - len(st)) / len(st))
                drift.append(drift_deg_per_min(p.t_s, p.heading_rad, st, hd))
            a = np.abs(drift)
            out[f"{mode} {fs:g} Hz"] = {"steps_true": n_true, "step_error_pct": round(100 * d_steps / n_true, 2),
                                        "worst_walk_pct": round(100 * worst, 2),
                                        "drift_median_dpm": round(float(np.median(a)), 2),
                                        "drift_max_dpm": round(float(a.max()), 2)}
            print(mode, fs, out[f"{mode} {fs:g} Hz"], flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--seeds", type=int, default=6, help="synthetic walks per carrying mode and rate")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a [pdr] setting to measure instead of the default (repeatable)")
    ap.add_argument("--out", default="bench_pdr", help="result name in bench/results (without .json)")
    args = ap.parse_args(argv)
    cfg = PdrConfig()
    for kv in args.set:
        k, v = kv.split("=", 1)
        cfg = replace(cfg, **{k: type(getattr(cfg, k))(v)})
    res: dict = {"config": {k: v for k, v in vars(cfg).items() if not hasattr(v, "validate")}}
    ilc = args.data / "msft-ilc20" / "data"
    res["ilc"] = {f: ilc_floor(ilc / f, cfg) for f in FLOORS if (ilc / f).is_dir()}
    for f, r in res["ilc"].items():
        print(f, json.dumps(r), flush=True)
    ipin = args.data / "ipin2023" / "logs"
    if ipin.is_dir():
        res["ipin"] = ipin_floor(ipin, cfg)
        print("ipin", json.dumps({k: v for k, v in res["ipin"].items() if k != "per_walk"}), flush=True)
    res["synthetic"] = synthetic(cfg, args.seeds)
    print("results in", write_result(args.out, res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
