"""Buildings on the MS ILC sites: a whole site at once against its floors one at a time, and the floor hit rate.

Run from the repo root: ``python -m bench.bench_floors [--sites site1,site2] [--scratch DIR] [--reuse]``.
For each site, the pipeline (``ingest → optimize → export-map → evaluate``) runs through the CLI on the site
folder (a building workspace) and on each floor folder (single-floor workspaces); every floor's reports
are compared with its single-floor run's, and the building's floor classification is read back, then
recomputed for a few values of the classifier's constants (:mod:`rmbuild.localize.floor`) from the same
workspaces. Writes ``bench/results/floors.json`` and ``floors.md``. Data: ``$RMBUILD_DATASETS``, default
``<repo>/../shared/datasets``; skips cleanly when absent.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bench.bench_real import ilc_data_root, run_pipeline
from bench.common import RESULTS, write_result

#: per stage directory, the report keys that must be equal between a building's floor and its own run
COMPARED = {"data": ("walks", "poses", "readings", "scans", "aps", "nodes_with_fingerprint"),
            "optimize": ("factors", "raw", "optimized", "linked_walks"),
            "map": ("cells", "aps", "reference_nodes"),
            "evaluate": ("maps", "test_walks", "n_queries")}
#: the classifier constants tried (each varied alone around the defaults)
VARIANTS = {"K_NEAREST": (1, 3, 5), "TAU_DB": (5.0, 10.0, 20.0), "P_CHANGE": (0.001, 0.01, 0.1)}


def compare(site_ws: Path, floor_ws: dict[str, Path]) -> dict:
    """Per floor and stage: the compared keys that differ between the building's floor and its own run."""
    out = {}
    for name, single in floor_ws.items():
        diffs = {}
        for d, keys in COMPARED.items():
            a = json.loads((site_ws / "floors" / name / d / "report.json").read_text())
            b = json.loads((single / d / "report.json").read_text())
            diffs[d] = [k for k in keys if a.get(k) != b.get(k)]
        out[name] = diffs
    return out


def _building(site_ws: Path) -> dict:
    """The building's evaluate totals as the code computes them now (the evaluate run may be older)."""
    from rmbuild.config import EvaluateConfig
    from rmbuild.stages.floor_eval import floor_totals

    rep = json.loads((site_ws / "building" / "evaluate.json").read_text())
    return floor_totals(site_ws, rep["floors"], EvaluateConfig())


def sensitivity(site_ws: Path) -> dict:
    """The floor hit rate for each variant of the classifier's constants (the others at their defaults)."""
    import rmbuild.localize.floor as fl
    from rmbuild.config import EvaluateConfig
    from rmbuild.stages.floor_eval import floor_totals

    rep = json.loads((site_ws / "building" / "evaluate.json").read_text())
    out: dict = {}
    for const, values in VARIANTS.items():
        default = getattr(fl, const)
        for v in values:
            setattr(fl, const, v)
            try:
                fc = floor_totals(site_ws, rep["floors"], EvaluateConfig())["floor_classification"]
            finally:
                setattr(fl, const, default)
            out[f"{const}={v}"] = {"hit_rate": fc["hit_rate"], "single_scan": fc["hit_rate_single_scan"]}
    return out


def synthetic(scratch: Path) -> dict:
    """Floor hit rate on simulated three-floor buildings (seed 11) for several floor attenuations."""
    from dataclasses import replace

    from rmbuild.config import EvaluateConfig, IngestConfig, MapConfig, OptimizeConfig
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import evaluate, export_map, ingest, optimize, simulate

    out = {}
    for preset in ("tiny", "default"):
        for faf in (0.0, 3.0, 6.0, 10.0, 15.0):
            cfg = preset_config(preset, 11)
            cfg = replace(cfg, building=replace(cfg.building, floors=3, floor_attenuation_db=faf))
            d = scratch / f"synthetic-{preset}-{faf:g}"
            simulate.run(d / "in", cfg, force=True)
            ingest.run([d / "in"], d / "ws", IngestConfig(), force=True)
            optimize.run(d / "ws", OptimizeConfig(), force=True)
            export_map.run(d / "ws", MapConfig(), force=True)
            rep, _ = evaluate.run(d / "ws", EvaluateConfig(localizers=("knn",)), force=True)
            fc = rep["building"]["floor_classification"]
            out[f"{preset} {faf:g} dB"] = {k: fc[k] for k in ("n", "hit_rate", "hit_rate_single_scan")}
            print(preset, faf, out[f"{preset} {faf:g} dB"], flush=True)
    return out


def change_delay(site_ws: Path, pairs: int = 120, seed: int = 0) -> dict:
    """Scans the filter takes to follow a floor change: a test walk of one floor chained to one of another,
    per value of TAU_DB (90th percentile and maximum over random pairs)."""
    import numpy as np

    import rmbuild.localize.floor as fl
    from rmbuild.localize.base import Query
    from rmbuild.stages.floor_eval import _floor_data, _refs

    rep = json.loads((site_ws / "building" / "evaluate.json").read_text())
    floors = {n: site_ws / "floors" / n for n in rep["floors"]}
    data = {n: _floor_data(p) for n, p in floors.items()}
    bssids = np.array(sorted(set().union(*(set(map(str, fp.bssids)) for _, fp in data.values()))), dtype=object)
    refs = [_refs(ds, fp, rep["floors"][n]["map_walks"], bssids) for n, (ds, fp) in data.items()]
    walks = []
    for i, n in enumerate(floors):
        q = Query.from_dataset(data[n][0], rep["floors"][n]["test_walks"], bssids)
        d = fl.floor_distances(refs, q.rss_dbm)
        walks += [(i, d[rows]) for _, rows in q.walks()]
    out = {}
    default = fl.TAU_DB
    for tau in VARIANTS["TAU_DB"]:
        fl.TAU_DB = tau
        rng = np.random.default_rng(seed)
        delays = []
        for _ in range(pairs):
            a, b = rng.choice(len(walks), 2, replace=False)
            if walks[a][0] == walks[b][0]:
                continue
            d = np.vstack([walks[a][1], walks[b][1]])
            pred = fl.filter_floors(d, np.zeros(len(d)), np.arange(len(d), dtype=float)).argmax(axis=1)
            ok = np.flatnonzero(pred[len(walks[a][1]):] == walks[b][0])
            delays.append(int(ok[0]) if len(ok) else len(walks[b][1]))
        out[f"TAU_DB={tau:g}"] = {"pairs": len(delays), "p90": float(np.percentile(delays, 90)),
                                  "max": int(max(delays))}
    fl.TAU_DB = default
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sites", default="site1,site2")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-floors"))
    ap.add_argument("--reuse", action="store_true", help="Reuse the workspaces of an earlier run.")
    ap.add_argument("--synthetic", action="store_true",
                    help="Only the simulated buildings (floor attenuation sweep): floors_synthetic.json.")
    args = ap.parse_args()
    if args.synthetic:
        write_result("floors_synthetic", synthetic(args.scratch))
        return
    root = ilc_data_root()
    if not root.is_dir():
        print(f"skipped: {root} absent")
        return
    result: dict = {}
    for site in args.sites.split(","):
        src = root / site
        floors = sorted(p.name for p in src.iterdir() if p.is_dir())
        ws = {f: args.scratch / f"{site}-{f}" for f in floors}
        site_ws = args.scratch / site
        runs = {}
        if not args.reuse:
            runs["building"] = run_pipeline(src, "msft-ilc", site_ws)
            runs.update({f: run_pipeline(src / f, "msft-ilc", ws[f]) for f in floors})
        building = _building(site_ws)
        result[site] = {"runs": runs, "differences": compare(site_ws, ws), "building": building,
                        "sensitivity": sensitivity(site_ws), "change_delay": change_delay(site_ws)}
    write_result("floors", result)
    (RESULTS / "floors.md").write_text(markdown(result))
    print(markdown(result))


def markdown(result: dict) -> str:
    lines = ["# Buildings: MS ILC sites at once vs floor by floor", "",
             "| site | floor | test scans | floor hit rate | reports equal to the single-floor run |",
             "|---|---|---|---|---|"]
    for site, r in result.items():
        fc = r["building"]["floor_classification"]
        for f, d in r["differences"].items():
            same = "yes" if not any(d.values()) else "; ".join(f"{k}: {v}" for k, v in d.items() if v)
            pf = fc["per_floor"].get(f, {})
            lines.append(f"| {site} | {f} | {pf.get('n')} | {pf.get('hit_rate', 0):.1%} | {same} |")
        lines.append(f"| {site} | all | {fc['n']} | {fc['hit_rate']:.1%} (single scans "
                     f"{fc['hit_rate_single_scan']:.1%}) | |")
    lines += ["", "Combined error (x, y + 15 m per floor off), building, knn / wknn, mean and p75 (m):", "",
              "| site | map | localizer | x, y all scans mean | x, y correct floor mean | combined mean | "
              "combined p75 |",
              "|---|---|---|---|---|---|---|"]
    for site, r in result.items():
        for m, d in r["building"]["maps"].items():
            for loc, s in d.items():
                lines.append(f"| {site} | {m} | {loc} | {s['xy_all_scans']['mean']:.2f} | "
                             f"{s['xy_correct_floor']['mean']:.2f} | {s['combined']['mean']:.2f} | "
                             f"{s['combined']['p75']:.2f} |")
    lines += ["", "Floor hit rate (filtered / single scans) for other values of the classifier's constants:", "",
              "| variant | " + " | ".join(result) + " |", "|---|" + "---|" * len(result)]
    variants = next(iter(result.values()))["sensitivity"]
    for v in variants:
        cells = [f"{r['sensitivity'][v]['hit_rate']:.1%} / {r['sensitivity'][v]['single_scan']:.1%}"
                 for r in result.values()]
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    lines += ["", "Scans the filter takes to follow a floor change (test walks of two floors chained; p90 / max):", "",
              "| variant | " + " | ".join(result) + " |", "|---|" + "---|" * len(result)]
    for v in next(iter(result.values()))["change_delay"]:
        lines.append(f"| {v} | " + " | ".join(f"{r['change_delay'][v]['p90']:g} / {r['change_delay'][v]['max']}"
                                             for r in result.values()) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
