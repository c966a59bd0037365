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
    from rmbuild.stages.building.evaluate import floor_totals

    rep = json.loads((site_ws / "building" / "evaluate.json").read_text())
    return floor_totals(site_ws, rep["floors"], EvaluateConfig())


def sensitivity(site_ws: Path) -> dict:
    """The floor hit rate for each variant of the classifier's constants (the others at their defaults)."""
    import rmbuild.localize.floor as fl
    from rmbuild.config import EvaluateConfig
    from rmbuild.stages.building.evaluate import floor_totals

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
    from rmbuild.stages.building.evaluate import _floor_data, _refs

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


# ---- floor changes: the barometer on simulated stairs / lifts and on IPIN logfiles with a storey added ----

#: the storeys added to the IPIN walks' real pressure: (height m, duration s, where in the walk)
IPIN_STOREYS = ((3.5, 15.0, 0.4), (-3.5, 8.0, 0.4), (4.5, 25.0, 0.4))


def changes_synthetic(seeds: range, preset: str = "default") -> dict:
    """The barometer's floor changes on simulated three-floor buildings: per simulated change, the step where
    the walk is cut minus the first true step on the new floor; changes found on walks that stay put."""
    import numpy as np

    from rmbuild.config.simulate import preset_config
    from rmbuild.pdr.baro import floor_changes
    from rmbuild.synthetic.building import simulate_building

    errs: dict[str, list[int]] = {"stairs": [], "lift": []}
    missed = false = walks = 0
    for seed in seeds:
        cfg = _building_cfg(preset_config(preset, seed))
        d = simulate_building(cfg)
        truth = d.truth_floor_changes.set_index("walk_id")
        for w, g in d.poses.groupby("walk_id"):
            walks += 1
            t = g["t_s"].to_numpy(float)
            found = floor_changes(t, g["pressure_hpa"].to_numpy(float))
            if w not in truth.index:
                false += len(found)
            elif len(found) != 1:
                missed += 1
            else:
                cut = int(np.searchsorted(t, found[0].t_mid_s))
                errs[str(truth.loc[w, "kind"])].append(cut - int(truth.loc[w, "step"]))
    out = {"seeds": [seeds.start, seeds.stop], "preset": preset, "walks": walks, "missed": missed,
           "false_changes": false}
    for kind, e in errs.items():
        a = np.abs(np.array(e))
        out[kind] = {"n": len(e), "within_2_steps": int((a <= 2).sum()), "max_abs_steps": int(a.max()) if len(a)
                     else None, "errors": sorted(e)}
    return out


def split_synthetic(seeds: range, preset: str = "default") -> dict:
    """The barometer + Wi-Fi split alone (:func:`rmbuild.ingest.floors.split_floors`, the simulated floor
    columns dropped) on simulated three-floor buildings: per building, the share of steps on their true floor
    (the found floors named by their majority), the floors found, and the cut errors (steps)."""
    import numpy as np
    import pandas as pd

    from rmbuild.config.simulate import preset_config
    from rmbuild.ingest.floors import split_floors
    from rmbuild.io.formats.base import RawInput
    from rmbuild.synthetic.building import simulate_building

    out = {}
    for seed in seeds:
        d = simulate_building(_building_cfg(preset_config(preset, seed)))
        pressure = {w: (g["t_s"].to_numpy(float), g["pressure_hpa"].to_numpy(float))
                    for w, g in d.poses.groupby("walk_id")}
        raw = RawInput(walks=d.walks.drop(columns=["floor"]), poses=d.poses.drop(columns=["floor", "pressure_hpa"]),
                       wifi=d.wifi, fixes=d.fixes, pressure=pressure)
        floors = split_floors(raw) or {}
        got = pd.concat([r.poses[["walk_id", "t_s"]].assign(found=n, walk_id=r.poses["walk_id"].str.split("@").str[0])
                         for n, r in floors.items()])
        m = got.merge(d.poses[["walk_id", "t_s", "floor"]], on=["walk_id", "t_s"])
        name = m.groupby("found")["floor"].agg(lambda x: x.value_counts().index[0])
        truth = d.truth_floor_changes.set_index("walk_id")
        cuts = []
        for tr in raw.transitions:
            t = d.poses.loc[d.poses["walk_id"] == tr["walk"], "t_s"].to_numpy(float)
            if tr["walk"] in truth.index:
                cuts.append(int(np.searchsorted(t, tr["t_s"])) - int(truth.loc[tr["walk"], "step"]))
        out[str(seed)] = {"floors_found": len(floors), "steps_on_true_floor":
                          round(float((m["found"].map(name) == m["floor"]).mean()), 4),
                          "cuts": len(cuts), "true_changes": len(truth), "cut_errors_steps": sorted(cuts)}
        print("split", seed, out[str(seed)], flush=True)
    return out


def _building_cfg(cfg):
    from dataclasses import replace

    return replace(cfg, building=replace(cfg.building, floors=3))


def changes_ipin(logs: Path) -> dict:
    """A storey added to each IPIN 2023 walk's real pressure (:data:`IPIN_STOREYS`): found, and the found
    start, midpoint and end minus the true ones (s; median and max of the absolute values)."""
    import gzip

    import numpy as np

    from rmbuild.pdr.baro import M_PER_HPA, floor_changes

    err: dict[str, list[float]] = {"start": [], "mid": [], "end": []}
    found = cases = 0
    for f in sorted(logs.glob("*.txt.gz")):
        rows = [ln.split(";") for ln in gzip.open(f, "rt", errors="replace") if ln.startswith("PRES;")]
        t = np.array([float(r[1]) for r in rows])
        p = np.array([float(r[3]) for r in rows])
        for dh, dur, at in IPIN_STOREYS:
            cases += 1
            t0 = t[0] + at * (t[-1] - t[0])
            ch = floor_changes(t, p - np.clip((t - t0) / dur, 0.0, 1.0) * dh / M_PER_HPA)
            if len(ch) == 1 and abs(ch[0].dh_m - dh) < 1.0:
                found += 1
                err["start"].append(abs(ch[0].t_start_s - t0))
                err["mid"].append(abs(ch[0].t_mid_s - (t0 + dur / 2)))
                err["end"].append(abs(ch[0].t_end_s - (t0 + dur)))
    return {"cases": cases, "found": found,
            **{k: {"median_s": round(float(np.median(v)), 2), "max_s": round(float(np.max(v)), 2)}
               for k, v in err.items() if v}}


def ipin_mixed(logs: Path, scratch: Path) -> dict:
    """A mixed call: every IPIN 2023 logfile, two of them given a storey's pressure step (one up at 40 %, one
    down at 60 %, as if the walks had taken the stairs), ingested without options: the floors and walks."""
    import gzip

    import numpy as np

    from rmbuild.config import IngestConfig
    from rmbuild.pdr.baro import M_PER_HPA
    from rmbuild.stages import ingest

    src = scratch / "ipin-mixed-in"
    src.mkdir(parents=True, exist_ok=True)
    files = sorted(logs.glob("*.txt.gz"))
    steps = {files[0].name: (3.5, 0.4), files[5].name: (-3.5, 0.6)}
    for f in files:
        out = src / f.name.removesuffix(".gz")
        lines = gzip.open(f, "rt", errors="replace").read().splitlines(keepends=True)
        if f.name in steps:
            dh, at = steps[f.name]
            pres = [ln.split(";") for ln in lines if ln.startswith("PRES;")]
            t_first, t_last = float(pres[0][1]), float(pres[-1][1])
            t0 = t_first + at * (t_last - t_first)
            for k, ln in enumerate(lines):
                if ln.startswith("PRES;"):
                    r = ln.split(";")
                    r[3] = f"{float(r[3]) - np.clip((float(r[1]) - t0) / 15.0, 0.0, 1.0) * dh / M_PER_HPA:.4f}"
                    lines[k] = ";".join(r)
        out.write_text("".join(lines))
    rep = ingest.run([src], scratch / "ipin-mixed-ws", IngestConfig(), force=True)
    floors = {n: {"walks": r["walks"], "poses": r["poses"]} for n, r in rep["floors"].items()}
    return {"changed": {k.removesuffix(".txt.gz"): v for k, v in steps.items()}, "floors": floors,
            "transitions": rep.get("transitions", [])}


def building_pipeline(scratch: Path, seeds: tuple[int, ...] = (11, 12), preset: str = "default") -> dict:
    """The pipeline on simulated three-floor buildings with stairs and a lift, floors from the input (the
    simulated ``floor`` columns) and from the barometer and Wi-Fi alone (columns dropped), against the same
    venue's single floor: floor hit rate and per-floor landmark error."""
    from dataclasses import replace

    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate

    out = {}
    for seed in seeds:
        base = preset_config(preset, seed)
        d = scratch / f"changes-{preset}-{seed}"
        simulate.run(d / "in", _building_cfg(base), force=True)
        simulate.run(d / "in1", replace(base, building=replace(base.building, floors=1)), force=True)
        simulate.run(d / "in0", replace(_building_cfg(base), building=replace(_building_cfg(base).building,
                                                                              floor_change_walks=0)), force=True)
        _drop_floor_columns(d / "in", d / "in-baro")
        out[str(seed)] = {"floor_columns": _run(d / "in", d / "ws"), "barometer": _run(d / "in-baro", d / "ws-baro"),
                          "single_floor": _run(d / "in1", d / "ws1"), "no_floor_changes": _run(d / "in0", d / "ws0"),
                          "barometer_split": _split_accuracy(d / "in", d / "ws-baro")}
        print(seed, json.dumps(out[str(seed)]), flush=True)
    return out


def frames_accuracy(scratch: Path, seeds: tuple[int, ...] = (11, 12), preset: str = "default") -> dict:
    """The floors' frames stacked by the transitions (``building/optimize.json`` → ``floor_frames``) against
    the truth: each floor's optimised poses mapped onto the reference floor's frame by the estimate and by
    the true transform (each frame aligned to the building's true one), mean distance (m) and rotation
    error (degrees)."""
    import numpy as np
    import pandas as pd

    from rmbuild.geometry import align_se2
    from rmbuild.io.workspace import building_floors
    from rmbuild.stages.building.frames import floor_frames

    out = {}
    for seed in seeds:
        for how in ("ws", "ws-baro"):
            ws = scratch / f"changes-{preset}-{seed}" / how
            frames = floor_frames(ws)
            if frames is None:
                out[f"{seed} {how}"] = None
                continue
            to_true = {}
            for name, f in (building_floors(ws) or {}).items():
                est = pd.read_parquet(f / "optimize" / "poses.parquet")
                est = est[est["linked"]] if "linked" in est else est
                tru = pd.read_parquet(f / "data" / "truth" / "poses.parquet")
                m = est.merge(tru, on=["walk_id", "t_s"], suffixes=("", "_true"))
                xy = m[["x_m", "y_m"]].to_numpy(float)
                to_true[name] = (align_se2(xy, m[["x_m_true", "y_m_true"]].to_numpy(float)), xy)
            (r_ref, t_ref), _ = to_true[frames["reference"]]
            res = {}
            for name, fr in frames["floors"].items():
                (r_f, t_f), xy = to_true[name]
                true_xy = (xy @ r_f.T + t_f - t_ref) @ r_ref  # floor -> building -> reference frame
                a = np.radians(fr["rotation_deg"])
                r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
                est_xy = xy @ r.T + np.array([fr["dx_m"], fr["dy_m"]])
                rot_true = np.degrees(np.arctan2((r_ref.T @ r_f)[1, 0], (r_ref.T @ r_f)[0, 0]))
                res[name] = {"transitions": fr["transitions"], "rotation_known": fr["rotation_known"],
                             "mean_error_m": round(float(np.hypot(*(est_xy - true_xy).T).mean()), 2),
                             "rotation_error_deg": round(float((np.degrees(a) - rot_true + 180) % 360 - 180), 2)}
            out[f"{seed} {how}"] = {"reference": frames["reference"], "floors": res}
    return out


def _drop_floor_columns(src: Path, dst: Path) -> None:
    import shutil

    import pandas as pd

    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    for name in ("walks.csv", "poses.csv"):
        df = pd.read_csv(dst / name)
        df.drop(columns=["floor"]).to_csv(dst / name, index=False)


def _run(src: Path, ws: Path) -> dict:
    """ingest, optimize, export-map, evaluate (knn): floor hit rate and landmark error per floor."""
    from rmbuild.config import EvaluateConfig, IngestConfig, MapConfig, OptimizeConfig
    from rmbuild.stages import evaluate, export_map, ingest, optimize

    ingest.run([src], ws, IngestConfig(), force=True)
    optimize.run(ws, OptimizeConfig(), force=True)
    export_map.run(ws, MapConfig(), force=True)
    rep, _ = evaluate.run(ws, EvaluateConfig(localizers=("knn",)), force=True)
    from rmbuild.io.workspace import building_floors

    floors = building_floors(ws) or {"all": ws}
    lm = {}
    for name, p in floors.items():
        r = json.loads((p / "optimize" / "report.json").read_text())
        lm[name] = {k: r[k]["landmark_error_m"]["mean"] for k in ("raw", "optimized")}
    fc = rep.get("building", {}).get("floor_classification")
    return {"landmark_m": lm, "floor_hit_rate": None if fc is None else
            {k: fc[k] for k in ("n", "hit_rate", "hit_rate_single_scan")}}


def _split_accuracy(src: Path, ws: Path) -> dict:
    """How the barometer + Wi-Fi split matches the simulated floors: steps whose floor (the named floors
    mapped to the true ones by their majority) is right, and the cuts against the true changes (steps)."""
    import numpy as np
    import pandas as pd

    poses = pd.read_csv(src / "poses.csv", usecols=["walk_id", "t_s", "floor"])
    changes = pd.read_csv(src / "truth" / "floor_changes.csv")
    from rmbuild.io.workspace import building_floors

    rep = json.loads((ws / "building" / "ingest.json").read_text())
    got = []
    for name, path in (building_floors(ws) or {}).items():
        p = pd.read_parquet(path / "data" / "poses.parquet", columns=["walk_id", "t_s"])
        got.append(p.assign(found=name, walk_id=p["walk_id"].str.split("@").str[0]))
    got = pd.concat(got).merge(poses, on=["walk_id", "t_s"], how="inner")
    mapping = got.groupby("found")["floor"].agg(lambda s: s.value_counts().index[0]).to_dict()
    ok = (got["found"].map(mapping) == got["floor"]).to_numpy()
    errs = []
    for tr in rep.get("transitions", []):
        t = poses.loc[poses["walk_id"] == tr["walk"], "t_s"].to_numpy(float)
        true = changes[changes["walk_id"] == tr["walk"]]
        if len(true):
            errs.append(int(np.searchsorted(t, tr["t_s"])) - int(true["step"].iloc[0]))
    return {"mapping": mapping, "steps": int(len(ok)), "steps_on_true_floor": round(float(ok.mean()), 4),
            "cuts": len(errs), "true_changes": int(len(changes)), "cut_errors_steps": sorted(errs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sites", default="site1,site2")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-floors"))
    ap.add_argument("--reuse", action="store_true", help="Reuse the workspaces of an earlier run (with --changes: "
                    "only the floor frames are measured anew).")
    ap.add_argument("--synthetic", action="store_true",
                    help="Only the simulated buildings (floor attenuation sweep): floors_synthetic.json.")
    ap.add_argument("--changes", action="store_true",
                    help="Only the floor changes (barometer on simulated stairs / lift and on IPIN 2023 with a "
                         "storey added; mixed IPIN ingest; the pipeline on buildings with stairs and a lift): "
                         "floors_changes.json, and its section of floors.md.")
    args = ap.parse_args()
    if args.synthetic:
        write_result("floors_synthetic", synthetic(args.scratch))
        return
    if args.changes and args.reuse:
        res = json.loads((RESULTS / "floors_changes.json").read_text())
        res["floor_frames"] = frames_accuracy(args.scratch)
        write_result("floors_changes", res)
        _write_markdown()
        return
    if args.changes:
        logs = ilc_data_root().parent.parent / "ipin2023" / "logs"
        res = {"synthetic": changes_synthetic(range(0, 10)), "split": split_synthetic(range(0, 10)),
               "ipin_storey": changes_ipin(logs) if logs.is_dir() else None,
               "ipin_mixed": ipin_mixed(logs, args.scratch) if logs.is_dir() else None,
               "pipeline": building_pipeline(args.scratch)}
        res["floor_frames"] = frames_accuracy(args.scratch)
        write_result("floors_changes", res)
        _write_markdown()
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
    _write_markdown()


def _write_markdown() -> None:
    """floors.md from the results at hand: the ILC sites (floors.json) and the floor changes."""
    text = ""
    if (RESULTS / "floors.json").exists():
        ilc = json.loads((RESULTS / "floors.json").read_text())
        text += markdown({k: v for k, v in ilc.items() if k != "machine"})
    if (RESULTS / "floors_changes.json").exists():
        text += "\n" + changes_markdown(json.loads((RESULTS / "floors_changes.json").read_text()))
    (RESULTS / "floors.md").write_text(text)
    print(text)


def changes_markdown(r: dict) -> str:
    """The floor-change section of floors.md."""
    sy = r["synthetic"]
    lines = ["# Floor changes from the barometer", "",
             f"Simulated three-floor buildings (`{sy['preset']}` preset, seeds {sy['seeds'][0]}-{sy['seeds'][1] - 1}; "
             f"{sy['walks']} walks): cut step minus the first true step on the new floor.", "",
             "| transition | changes | found within ±2 steps | max abs error (steps) |", "|---|---|---|---|"]
    for kind in ("stairs", "lift"):
        k = sy[kind]
        lines.append(f"| {kind} | {k['n']} | {k['within_2_steps']} | {k['max_abs_steps']} |")
    lines += ["", f"Missed changes: {sy['missed']}; changes found on walks that stay on one floor: "
              f"{sy['false_changes']}.", ""]
    if r.get("split"):
        lines += ["The same buildings without their floor columns, split by the barometer and named by the Wi-Fi "
                  "(`split_floors`):", "", "| seed | floors found | steps on their true floor | cuts / true changes | "
                  "cut errors (steps) |", "|---|---|---|---|---|"]
        for seed, v in r["split"].items():
            lines.append(f"| {seed} | {v['floors_found']} | {v['steps_on_true_floor']:.2%} | {v['cuts']} / "
                         f"{v['true_changes']} | {v['cut_errors_steps']} |")
        lines.append("")
    ip = r.get("ipin_storey")
    if ip:
        lines += [f"IPIN 2023 walks with a storey added to the real pressure: {ip['found']} of {ip['cases']} found; "
                  "absolute error (s), median / max: " + ", ".join(
                      f"{k} {ip[k]['median_s']} / {ip[k]['max_s']}" for k in ("start", "mid", "end") if k in ip)
                  + ".", ""]
    mx = r.get("ipin_mixed")
    if mx:
        lines += ["IPIN 2023 mixed call (all logfiles, two with a storey step), `rmbuild ingest` without options: "
                  + "; ".join(f"floor {n}: {v['walks']} walks, {v['poses']} steps" for n, v in mx["floors"].items())
                  + f"; {len(mx['transitions'])} transitions.", ""]
    lines += ["Pipeline on the simulated buildings (knn; landmark error of the optimised walks, mean m):", "",
              "| seed | floors from | floor hit rate (single scans) | landmark error per floor | single floor |",
              "|---|---|---|---|---|"]
    for seed, v in r["pipeline"].items():
        single = v["single_floor"]["landmark_m"]["all"]["optimized"]
        for how in ("floor_columns", "barometer", "no_floor_changes"):
            if how not in v:
                continue
            fc = v[how]["floor_hit_rate"]
            lm = ", ".join(f"{n} {x['optimized']:.2f}" for n, x in v[how]["landmark_m"].items())
            rate = f"{fc['hit_rate']:.1%} ({fc['hit_rate_single_scan']:.1%})"
            lines.append(f"| {seed} | {how.replace('_', ' ')} | {rate} | {lm} | {single:.2f} |")
        sp = v["barometer_split"]
        lines.append(f"| {seed} | barometer split | steps on their true floor {sp['steps_on_true_floor']:.2%}; "
                     f"{sp['cuts']} cuts / {sp['true_changes']} changes, errors {sp['cut_errors_steps']} steps | | |")
    if r.get("floor_frames"):
        lines += ["", "Floors stacked by the transitions (building optimize report `floor_frames`) against the "
                  "truth: mean distance of each floor's poses mapped onto the reference floor, rotation error:", "",
                  "| seed, workspace | floor | transitions | rotation known | mean error (m) | rotation error (°) |",
                  "|---|---|---|---|---|---|"]
        for key, v in r["floor_frames"].items():
            for name, f in (v or {}).get("floors", {}).items():
                lines.append(f"| {key} | {name} | {f['transitions']} | {f['rotation_known']} | "
                             f"{f['mean_error_m']:.2f} | {f['rotation_error_deg']:.1f} |")
    return "\n".join(lines) + "\n"


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
