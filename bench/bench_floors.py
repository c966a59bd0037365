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
import os
from pathlib import Path

from bench.bench_real import DEFAULT_DATASETS, run_pipeline
from bench.common import RESULTS, write_result

#: per stage directory, the report keys that must be equal between a building's floor and its own run
COMPARED = {"data": ("walks", "poses", "readings", "scans", "aps", "nodes_with_fingerprint"),
            "optimize": ("factors", "raw", "optimized", "linked_walks"),
            "map": ("cells", "aps", "reference_nodes"),
            "evaluate": ("maps", "test_walks", "n_queries")}
#: the classifier constants tried (each varied alone around the defaults)
VARIANTS = {"K_NEAREST": (1, 3, 5), "TAU_DB": (2.0, 5.0, 10.0), "P_CHANGE": (0.001, 0.01, 0.1)}


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sites", default="site1,site2")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-floors"))
    ap.add_argument("--reuse", action="store_true", help="Reuse the workspaces of an earlier run.")
    args = ap.parse_args()
    root = Path(os.environ.get("RMBUILD_DATASETS", DEFAULT_DATASETS)) / "msft-ilc20" / "data"
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
        building = json.loads((site_ws / "building" / "evaluate.json").read_text())["building"]
        result[site] = {"runs": runs, "differences": compare(site_ws, ws), "building": building,
                        "sensitivity": sensitivity(site_ws)}
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
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
