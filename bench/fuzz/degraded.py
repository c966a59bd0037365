"""Degraded evidence on the synthetic default venue (seed 7): Wi-Fi readings dropped (50-99 %), one walk's
RSS offset by ±10 dB, a walk duplicated under another id, a walk cut to 3 steps. For each: what ingest
warns, whether optimize runs, walks linked, landmark error. ``python -m bench.fuzz.degraded`` writes
bench/results/degraded.json."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from bench.fuzz.faults import rmbuild
from rmbuild.io.workspace import Workspace


def _scenario(src: Path, dst: Path, name: str) -> None:
    shutil.copytree(src, dst)
    wifi = pd.read_parquet(dst / "wifi.parquet")
    walks = pd.read_parquet(dst / "walks.parquet")
    poses = pd.read_parquet(dst / "poses.parquet")
    wid = str(walks["walk_id"].iloc[1])
    if name.startswith("drop"):
        frac = int(name.removeprefix("drop")) / 100
        wifi = wifi[np.random.default_rng(1).random(len(wifi)) >= frac]
    elif name in ("offset+10", "offset-10"):
        wifi.loc[wifi["walk_id"] == wid, "rssi_dbm"] += 10.0 if name == "offset+10" else -10.0
    elif name == "duplicate":
        truth = pd.read_parquet(dst / "truth" / "poses.parquet")
        pd.concat([truth, truth[truth["walk_id"] == wid].assign(walk_id=wid + "_copy")], ignore_index=True
                  ).to_parquet(dst / "truth" / "poses.parquet", index=False)
        wifi = pd.concat([wifi, wifi[wifi["walk_id"] == wid].assign(walk_id=wid + "_copy")], ignore_index=True)
        poses = pd.concat([poses, poses[poses["walk_id"] == wid].assign(walk_id=wid + "_copy")], ignore_index=True)
        walks = pd.concat([walks, walks[walks["walk_id"] == wid].assign(walk_id=wid + "_copy")], ignore_index=True)
    elif name == "3-step walk":
        first = poses.groupby("walk_id").cumcount() < 3
        poses = poses[(poses["walk_id"] != wid) | first]
        t_end = poses.loc[poses["walk_id"] == wid, "t_s"].max()
        wifi = wifi[(wifi["walk_id"] != wid) | (wifi["t_s"] <= t_end)]
    wifi.to_parquet(dst / "wifi.parquet", index=False)
    walks.to_parquet(dst / "walks.parquet", index=False)
    poses.to_parquet(dst / "poses.parquet", index=False)


def run(scenarios: list[str]) -> dict:
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="rmbuild-degraded-") as tmp:
        src = Path(tmp) / "in"
        assert rmbuild(["simulate", str(src), "--preset", "default", "--seed", "7", "--format", "parquet", "-q"]
                       ).returncode == 0
        for name in scenarios:
            d = Path(tmp) / name.replace(" ", "_")
            _scenario(src, d / "in", name)
            ing = rmbuild(["ingest", str(d / "in"), "-w", str(d / "ws")])
            row: dict = {"ingest_exit": ing.returncode,
                         "ingest_warnings": [ln for ln in ing.stderr.splitlines() if ln.startswith("WARNING")],
                         "ingest_error": ing.stderr.strip().splitlines()[-1:] if ing.returncode else []}
            if ing.returncode == 0:
                opt = rmbuild(["optimize", "-w", str(d / "ws"), "-q"])
                row["optimize_exit"] = opt.returncode
                row["optimize_error"] = opt.stderr.strip().splitlines()[-1:] if opt.returncode else []
                if opt.returncode == 0:
                    ws = Workspace.open(d / "ws")
                    rep = ws.read_report("optimize") or {}
                    walks = ws.read_table("optimize.walks")
                    lm = ((rep.get("optimized") or {}).get("landmark_error_m") or {})
                    row.update({"walks": len(walks), "linked": int(walks["linked"].sum()),
                                "landmark_error_mean_m": lm.get("mean"),
                                "optimize_warnings": rep.get("warnings", [])})
            out[name] = row
            print(name, {k: v for k, v in row.items() if "warnings" not in k}, file=sys.stderr, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.fuzz.degraded", description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("bench/results/degraded.json"))
    args = ap.parse_args()
    res = run(["drop0", "drop50", "drop75", "drop90", "drop95", "drop99", "offset+10", "offset-10", "duplicate",
               "3-step walk"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
