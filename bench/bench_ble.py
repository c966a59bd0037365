"""BLE beacons against Wi-Fi as fingerprints: kNN / WkNN localization with a surveyed map of each modality.
Writes bench/results/ble.json and bench/results/ble.md. Run: ``nice python -m bench.bench_ble`` (about
2 minutes on the 2-core machine; needs the MS ILC traces beside the project).

Per floor: ingest (the BLE readings are TYPE_BEACON rows, beacon id = MAC), evaluate's split (every 5th walk
from the third is a test walk), the *surveyed* map of the map walks (node positions interpolated between
their waypoints, as evaluate's "surveyed" map) on one grid for every modality, and the test walks' queries
localized against it. Queries are per node (the readings attached to one step): a BLE "scan" is a single
beacon at one time on these phones, so per-scan queries would be one beacon each; BLE is also given per
time window (every beacon heard within 2 s / 5 s), Wi-Fi also per scan (evaluate's default). Modalities:
Wi-Fi alone, BLE alone, and both as one fingerprint (beacon ids prefixed, so a column is either an AP or a
beacon). Errors on each modality's own queries and on the nodes that have both kinds of reading.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common import RESULTS, write_result
from rmbuild.config import EvaluateConfig, IngestConfig, MapConfig
from rmbuild.evaluate.localization import query_reference_xy, reference_positions, split_walks
from rmbuild.io.workspace import Workspace
from rmbuild.localize.base import Query, make_localizer
from rmbuild.radiomap.build import build_radio_map, grid_origin
from rmbuild.types import Dataset

SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
FLOORS = ("site1/F1", "site2/F6", "site2/B1")
LOCALIZERS = ("knn", "wknn")
#: s; BLE queries over time windows: every beacon heard within one window is one query
WINDOWS_S = (2.0, 5.0)


def _with(ds: Dataset, readings: pd.DataFrame) -> Dataset:
    return Dataset(walks=ds.walks, poses=ds.poses, wifi=readings, fixes=ds.fixes)


def _modalities(ds: Dataset) -> dict[str, pd.DataFrame]:
    ble = ds.ble.assign(bssid="ble:" + ds.ble["bssid"].astype(str)) if ds.ble is not None else ds.wifi.iloc[:0]
    return {"wifi": ds.wifi, "ble": ble, "wifi+ble": pd.concat([ds.wifi, ble], ignore_index=True)}


def _stats(err: np.ndarray) -> dict:
    e = err[np.isfinite(err)]
    return {"n": int(e.size), "median_m": round(float(np.median(e)), 2) if e.size else None,
            "p75_m": round(float(np.percentile(e, 75)), 2) if e.size else None,
            "mean_m": round(float(e.mean()), 2) if e.size else None}


def floor_figures(ds: Dataset) -> dict:
    cfg, mcfg = EvaluateConfig(), MapConfig()
    map_walks, test, _ = split_walks(ds, cfg)
    ref_xy, _ = reference_positions(ds)
    walk_of_node = ds.poses["walk_id"].astype(str).to_numpy()
    map_nodes = np.flatnonzero(np.isin(walk_of_node, map_walks))
    origin = grid_origin(ref_xy[map_nodes][np.isfinite(ref_xy[map_nodes]).all(axis=1)], mcfg.cell_size_m)
    mods = _modalities(ds)
    nodes_of = {m: set(r.loc[r["walk_id"].astype(str).isin(test), "node"].astype(int)) for m, r in mods.items()}
    common = nodes_of["wifi"] & nodes_of["ble"]
    out: dict = {"map_walks": len(map_walks), "test_walks": len(test),
                 "beacons": int(ds.ble["bssid"].nunique()) if ds.ble is not None else 0,
                 "aps": int(ds.wifi["bssid"].nunique()), "test_nodes_with_both": len(common), "results": {}}
    runs = [(m, "node") for m in mods] + [("wifi", "scan")] + [("ble", f"{w:g} s window") for w in WINDOWS_S]
    for mod, unit in runs:
        r = mods[mod]
        rm = build_radio_map(r[r["walk_id"].astype(str).isin(map_walks)], ref_xy, walk_of_node, mcfg, origin,
                             frame="building")
        if unit.endswith("window"):  # the readings of each window form one query, timed at its centre
            w = float(unit.split()[0])
            r = r.assign(t_s=np.floor(r["t_s"].to_numpy(float) / w) * w + w / 2)
        q = Query.from_dataset(_with(ds, r), test, rm.bssids, unit="node" if unit == "node" else "scan")
        q_ref = query_reference_xy(ds, q)
        res = {"cells": int(rm.n_cells), "ids": len(rm.bssids)}
        for lname in LOCALIZERS:
            p = np.asarray(make_localizer(lname, cfg).fit(rm).predict(q), dtype=float)
            err = np.hypot(*(p - q_ref).T)
            res[lname] = _stats(err)
            if unit == "node":
                res[f"{lname}_common"] = _stats(err[np.isin(q.node, list(common))])
        out["results"][f"{mod} per {unit}"] = res
    return out


def main(scratch: Path | None = None) -> dict:
    from rmbuild.stages import ingest

    tmp = Path(tempfile.mkdtemp(prefix="rmbuild-bench-ble-", dir=scratch))
    res: dict = {"floors": {}}
    try:
        for fl in FLOORS:
            src = SHARED / "msft-ilc20" / "data" / fl
            if not src.is_dir():
                continue
            ws = tmp / fl.replace("/", "_")
            ingest.run([src], ws, IngestConfig())
            res["floors"][fl] = floor_figures(Workspace.open(ws).read_dataset())
            print(fl, res["floors"][fl], flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    write_result("ble", res)
    (RESULTS / "ble.md").write_text(table(res))
    return res


def table(res: dict) -> str:
    lines = ["| floor | fingerprint | queries | kNN median (m) | WkNN median (m) | kNN / WkNN median on nodes with "
             "both (m) |",
             "|---|---|---|---|---|---|"]
    for fl, f in res["floors"].items():
        for name, r in f["results"].items():
            both = (f"{r['knn_common']['median_m']} / {r['wknn_common']['median_m']} (n={r['knn_common']['n']})"
                    if "knn_common" in r else "")
            lines.append(f"| {fl} | {name} | {r['knn']['n']} | {r['knn']['median_m']} | {r['wknn']['median_m']} "
                         f"| {both} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else None)
