"""`rmbuild simulate`: write a seeded synthetic venue as input files a user would hand to `ingest`."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Literal

import pandas as pd

from rmbuild.config import SimulateConfig, to_toml
from rmbuild.errors import InputError
from rmbuild.io.atomic import clean_json, recover_dir, replacing_dir
from rmbuild.stages.common import Progress, ensure_progress

MARKER = "truth/simulate.toml"

#: SimulatedData attribute -> file stem relative to OUT_DIR
TABLE_FILES = {
    "walks": "walks",
    "poses": "poses",
    "wifi": "wifi",
    "ble": "ble",
    "fixes": "fixes",
    "truth_poses": "truth/poses",
    "truth_aps": "truth/aps",
    "truth_walks": "truth/walks",
    "truth_devices": "truth/devices",
    "truth_users": "truth/users",
    "truth_landmarks": "truth/landmarks",
    "truth_floor_changes": "truth/floor_changes",
    "truth_beacons": "truth/beacons",
}


def _write_table(df: pd.DataFrame, path_stem: Path, fmt: str) -> None:
    path_stem.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "parquet":
        df.to_parquet(path_stem.with_name(path_stem.name + ".parquet"), index=False)
    else:
        df.to_csv(path_stem.with_name(path_stem.name + ".csv"), index=False, float_format="%.6f",
                  lineterminator="\n")


def run(
    out_dir: str | Path,
    cfg: SimulateConfig,
    fmt: Literal["csv", "parquet"] = "csv",
    force: bool = False,
    progress: Progress | None = None,
    raw_imu: bool = False,
) -> dict:
    """Simulate and write OUT_DIR (input tables + truth/). Returns a summary dict.

    ``raw_imu``: write each walk's raw phone-IMU signals (``imu``) instead of its dead-reckoned ``poses``,
    so that ingest derives the steps with the PDR.
    """
    from rmbuild.synthetic import simulate

    progress = ensure_progress(progress)
    out = Path(out_dir)
    recover_dir(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        if not (out / MARKER).exists():
            raise InputError(f"{out} exists, is not empty and was not written by `rmbuild simulate`; "
                             "refusing to touch it")
        if not force:
            raise InputError(f"{out} already exists; pass --force to replace it")
    t0 = time.perf_counter()
    progress.phase("simulating venue")
    if cfg.building.floors > 1:
        from rmbuild.synthetic.building import simulate_building

        data = simulate_building(cfg)
    else:
        data = simulate(cfg)
    t_sim = time.perf_counter() - t0
    progress.message(f"{len(data.walks)} walks, {len(data.poses):,} steps, {len(data.wifi):,} Wi-Fi readings")
    imu = None
    if raw_imu:
        from rmbuild.synthetic.imu import phone_imu_table

        progress.phase("synthesising phone IMU")
        imu, phones = phone_imu_table(data.truth_poses, data.poses, cfg.seed, cfg.phone)
        data.truth_walks = data.truth_walks.merge(phones, on="walk_id", how="left")
        progress.message(f"{len(imu):,} samples")
    progress.phase("writing files")
    with replacing_dir(out) as tmp:
        for attr, stem in TABLE_FILES.items():
            df = getattr(data, attr, None)
            if df is not None and not (raw_imu and attr == "poses"):
                _write_table(df, tmp / stem, fmt)
        if imu is not None:
            _write_table(imu, tmp / "imu", fmt)
        (tmp / "truth").mkdir(exist_ok=True)
        (tmp / "truth" / "venue.json").write_text(json.dumps(clean_json(data.venue)) + "\n")
        (tmp / MARKER).write_text(to_toml(cfg, "simulate"))
    return {
        "out_dir": str(out),
        "walks": len(data.walks),
        "steps": len(data.poses),
        "readings": len(data.wifi),
        "scans": int(data.wifi.groupby(["walk_id", "t_s"]).ngroups),
        "aps": len(data.truth_aps) if data.truth_aps is not None else None,
        "fixes": len(data.fixes),
        **({"ble_readings": len(data.ble)} if data.ble is not None else {}),
        "imu_samples": len(imu) if imu is not None else 0,
        "time_s": {"simulate": round(t_sim, 3), "total": round(time.perf_counter() - t0, 3)},
    }
