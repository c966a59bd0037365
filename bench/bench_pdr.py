"""Phone PDR on the Microsoft ILC 2.0 traces, measured against the surveyor's waypoints.

Per floor and PDR setting: walked PDR distance / waypoint path length between the first and last waypoint
(median, P10, P90), the global step length that makes the total ratio 1, waypoint error after fitting each
walk on its own with one SE(2) (mean / median / P90), and how well the rotation-vector yaw agrees across
walks (per walk: waypoint-segment direction minus mean absolute yaw over the segment; median / P90 of the
deviation from the floor's circular mean). Also the time to parse + PDR a floor.

    python -m bench.bench_pdr [--data ../shared/datasets/msft-ilc20/data] [--out bench/results/bench_pdr.json]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rmbuild.config.ingest import IngestConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.io.formats.msft_ilc import MsftIlcReader, parse_trace
from rmbuild.pdr import ImuSignals, rotation_vector_quat, run_pdr, wrap_angle, yaw_from_quat

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "msft-ilc20" / "data"
FLOORS = ("site1/F1", "site2/F4")


def _imu(tr) -> ImuSignals:
    yaw = yaw_from_quat(rotation_vector_quat(tr.rot.values))
    return ImuSignals(tr.acc.t_s, tr.acc.values, tr.rot.t_s, yaw, tr.rot.accuracy, tr.gyro.t_s,
                      tr.gyro.values)


def _path_len(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(x), np.diff(y))))


def _se2_fit_err(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    """Errors (n,) of the best rigid 2-D fit of points p onto q, and the rotation angle."""
    pc, qc = p - p.mean(0), q - q.mean(0)
    h = pc.T @ qc
    ang = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    return np.linalg.norm(pc @ r.T - qc, axis=1), float(ang)


def evaluate(traces: list, cfg: PdrConfig) -> dict:
    """Metrics of one PDR setting over parsed traces (see module docstring)."""
    steps_in, wp_len, errs, offsets, n_steps = [], [], [], [], 0
    for tr in traces:
        wp = tr.waypoints
        if len(wp) < 2:
            continue
        sp = run_pdr(_imu(tr), cfg)
        n_steps += len(sp) - 1
        t0, t1 = wp["t_s"].iat[0], wp["t_s"].iat[-1]
        inside = (sp.t_s > t0) & (sp.t_s <= t1)
        steps_in.append(float(sp.step_length_m[inside].sum()))
        wx, wy = wp["x_m"].to_numpy(), wp["y_m"].to_numpy()
        wp_len.append(_path_len(wx, wy))
        px = np.interp(wp["t_s"], sp.t_s, sp.x_m)
        py = np.interp(wp["t_s"], sp.t_s, sp.y_m)
        e, _ = _se2_fit_err(np.c_[px, py], np.c_[wx, wy])
        errs.append(e)
        # yaw agreement: per waypoint segment (>= 3 m), building-frame direction minus mean absolute yaw
        segs = []
        for k in range(len(wp) - 1):
            d = np.hypot(wx[k + 1] - wx[k], wy[k + 1] - wy[k])
            sel = (sp.t_s > wp["t_s"].iat[k]) & (sp.t_s <= wp["t_s"].iat[k + 1])
            if d >= 3.0 and sel.sum() >= 2 and np.isfinite(sp.yaw_abs_rad[sel]).all():
                yaw = np.angle(np.mean(np.exp(1j * sp.yaw_abs_rad[sel])))
                segs.append((d, np.arctan2(wy[k + 1] - wy[k], wx[k + 1] - wx[k]) - yaw))
        if segs:
            w = np.array([s[0] for s in segs])
            offsets.append(np.angle(np.sum(w * np.exp(1j * np.array([s[1] for s in segs])))))
    ratio_raw = np.array(steps_in) / np.maximum(np.array(wp_len), 1e-9)
    # global step-length scale that makes the total walked distance match the waypoint paths
    scale = float(np.sum(wp_len) / max(np.sum(steps_in), 1e-9))
    ratio = ratio_raw * scale
    e = np.concatenate(errs) if errs else np.zeros(0)
    off = np.array(offsets)
    mean_off = np.angle(np.mean(np.exp(1j * off))) if len(off) else np.nan
    dev = np.degrees(np.abs(wrap_angle(off - mean_off)))
    return {
        "walks": len(ratio), "steps": n_steps,
        "ratio_median": float(np.median(ratio_raw)), "ratio_p10": float(np.percentile(ratio_raw, 10)),
        "ratio_p90": float(np.percentile(ratio_raw, 90)),
        "calibrated_step_scale": scale,
        "calibrated_ratio_p10": float(np.percentile(ratio, 10)),
        "calibrated_ratio_median": float(np.median(ratio)),
        "calibrated_ratio_p90": float(np.percentile(ratio, 90)),
        "calibrated_ratio_iqr": float(np.percentile(ratio, 75) - np.percentile(ratio, 25)),
        "se2_err_mean_m": float(e.mean()), "se2_err_median_m": float(np.median(e)),
        "se2_err_p90_m": float(np.percentile(e, 90)),
        "yaw_dev_median_deg": float(np.median(dev)), "yaw_dev_p90_deg": float(np.percentile(dev, 90)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    base = PdrConfig()
    settings = {
        "default": base,
        "pan_tompkins": replace(base, step_detector="pan_tompkins"),
        "rotation_vector_heading": replace(base, heading_source="rotation_vector"),
        "fixed_length": replace(base, step_length_model="fixed"),
        "frequency_length": replace(base, step_length_model="frequency"),
    }
    results: dict = {}
    for floor in FLOORS:
        d = args.data / floor / "path_data_files"
        if not d.is_dir():
            print(f"skip {floor}: {d} not found")
            continue
        files = sorted(d.glob("*.txt*"))
        t, c = time.perf_counter(), time.process_time()
        raw = MsftIlcReader(base).read(files, IngestConfig())
        t_read, c_read = time.perf_counter() - t, time.process_time() - c
        t = time.perf_counter()
        traces = [parse_trace(f, base) for f in files]
        t_parse = time.perf_counter() - t
        res: dict = {"files": len(files), "read_with_pdr_s": round(t_read, 2),
                     "read_with_pdr_cpu_s": round(c_read, 2),
                     "parse_only_s": round(t_parse, 2), "wifi_rows_kept": len(raw.wifi), "notes": raw.notes,
                     "skipped": raw.skipped}
        for name, cfg in settings.items():
            res[name] = evaluate(traces, cfg)
        results[floor] = res
        print(json.dumps({floor: res}, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
