"""`rmbuild localize` against `rmbuild evaluate` on the same test walks, and what the uncertainty is worth.
Writes bench/results/localize.json and bench/results/localize.md.
Run: ``nice -n 10 python -m bench.bench_localize [SCRATCH_DIR]`` (about 4 minutes on the 2-core machine).

Two venues: the synthetic ``default`` preset (seed 7; its test walks are those with role "test") and MS ILC
site1/F1 (evaluate's default split: every 5th walk from the third). Three numbers per localizer:

* ``evaluate``: `rmbuild evaluate` on a workspace of every walk — its "built" map is rasterised from the map
  walks' optimised positions after the SE(2) to the truth;
* ``same positions``: the same optimised positions of the map walks rasterised in the map's own frame, as
  export-map does, the test scans localized through the localize path (`rmbuild.localize.apply`) and the
  truth brought into the map's frame — only the grid differs from evaluate's map;
* ``localize --hold-out``: `rmbuild localize --hold-out` of the test walks' input files against the workspace
  of every walk: evaluate's built map of the other walks, so evaluate's errors exactly;
* ``localize``: `rmbuild localize` of the test walks' input files against a workspace built (ingest,
  optimize, export-map) from the map walks alone — what a user who walks the test walks later gets.

And the uncertainty: Spearman's rank correlation of ``uncertainty_m`` with the error, and the share of
scans whose error is below it, on the ``localize`` runs.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common import RESULTS, write_result

SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
ILC_F1 = SHARED / "msft-ilc20" / "data" / "site1" / "F1"
LOCALIZERS = ("knn", "wknn")


def cli(*args) -> str:
    r = subprocess.run([sys.executable, "-m", "rmbuild", *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"rmbuild {args[0]} failed: {r.stderr.strip()}")
    return r.stdout


def build(inp: Path, ws: Path, evaluate: bool) -> None:
    cli("ingest", inp, "-w", ws, "-q", "--force")
    cli("optimize", "-w", ws, "-q", "--force")
    cli("export-map", "-w", ws, "-q", "--force")
    if evaluate:
        cli("evaluate", "-w", ws, "-q", "--force", "--localizer", ",".join(LOCALIZERS))


def split_synthetic(src: Path, dst: Path) -> tuple[Path, Path]:
    walks = pd.read_csv(src / "walks.csv", dtype={"walk_id": str})
    test = set(walks.loc[walks["role"] == "test", "walk_id"])
    for sub, want in (("map", False), ("test", True)):
        for f in src.rglob("*"):
            if f.is_dir():
                continue
            out = dst / sub / f.relative_to(src)
            out.parent.mkdir(parents=True, exist_ok=True)
            if f.suffix == ".csv":
                df = pd.read_csv(f, dtype={"walk_id": str})
                if "walk_id" in df:
                    df = df[df["walk_id"].isin(test) == want]
                df.to_csv(out, index=False)
            else:
                shutil.copy(f, out)
    return dst / "map", dst / "test"


def split_ilc(src: Path, dst: Path) -> tuple[Path, Path]:
    """Links to the floor's files: the walks evaluate tests (every 5th from index 2, file order) apart."""
    files = sorted((src / "path_data_files").iterdir())
    for sub in ("map", "test"):
        (dst / sub / "path_data_files").mkdir(parents=True, exist_ok=True)
        for f in src.iterdir():
            if f.is_file():
                (dst / sub / f.name).symlink_to(f)
    for i, f in enumerate(files):
        (dst / ("test" if i % 5 == 2 else "map") / "path_data_files" / f.name).symlink_to(f)
    return dst / "map", dst / "test"


def same_positions(ws_all: Path, name: str) -> dict:
    """Errors of the localize path on a map of the map walks' optimised positions, in the map's frame."""
    from rmbuild.config import EvaluateConfig
    from rmbuild.evaluate.localization import error_stats, query_reference_xy, reference_positions, split_walks
    from rmbuild.evaluate.trajectory import align_se2
    from rmbuild.io.map_store import read_map_config
    from rmbuild.io.workspace import Workspace
    from rmbuild.localize.apply import localize_query
    from rmbuild.localize.base import Query
    from rmbuild.radiomap import build_radio_map
    from rmbuild.stages.mapping import built_positions

    ws = Workspace.open(ws_all)
    ds, fp, mcfg = ws.read_dataset(), ws.read_fingerprints(), read_map_config(ws)
    xy, _ = built_positions(ws, ds, mcfg)
    cfg = EvaluateConfig()
    maps, test, _ = split_walks(ds, cfg)
    wid = ds.poses["walk_id"].astype(str).to_numpy()
    xy[~np.isin(wid, maps)] = np.nan
    rm = build_radio_map(ds.wifi[ds.wifi["walk_id"].astype(str).isin(maps)], xy, wid, mcfg, bssids=fp.bssids)
    q = Query.from_dataset(ds, test, rm.bssids)
    res = localize_query(rm, q, name, cfg)
    ref, _ = reference_positions(ds)
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(ref).all(axis=1)
    r, t = align_se2(xy[ok], ref[ok])
    truth = (query_reference_xy(ds, q) - t) @ r
    return error_stats(np.hypot(*(res.xy - truth).T))


def map_only_on_evaluates_grid(ws_all: Path, ws_map: Path, name: str) -> dict:
    """Errors of the test scans on evaluate's kind of built map (SE(2) to the truth, evaluate's grid) made
    from the map-walk-only workspace's optimised positions: what the optimisation without the test walks
    alone changes. Also each workspace's SE(2) residual and its linked map walks."""
    from rmbuild.config import EvaluateConfig
    from rmbuild.evaluate.localization import error_stats, evaluation_maps, query_reference_xy, split_walks
    from rmbuild.io.map_store import read_map_config
    from rmbuild.io.workspace import Workspace
    from rmbuild.localize.apply import localize_query
    from rmbuild.localize.base import Query
    from rmbuild.stages.mapping import built_positions

    cfg = EvaluateConfig()
    wa = Workspace.open(ws_all)
    da = wa.read_dataset()
    maps, test, _ = split_walks(da, cfg)
    out: dict = {}
    for label, path in (("all", ws_all), ("map", ws_map)):
        ws = Workspace.open(path)
        ds, fp, mcfg = ws.read_dataset(), ws.read_fingerprints(), read_map_config(ws)
        xy, info = built_positions(ws, ds, mcfg)
        mine = [w for w in ds.walks["walk_id"].astype(str) if w in set(maps)]
        em = evaluation_maps(ds, fp, xy, mine, info["gauge"], mcfg)
        q = Query.from_dataset(da, test, em.maps["built"].bssids, unit=cfg.query)
        res = localize_query(em.maps["built"], q, name, cfg)
        walks = ws.read_table("optimize.walks")
        linked = set(walks.loc[walks["linked"].astype(bool), "walk_id"].astype(str)) & set(mine)
        out[label] = {"errors": error_stats(np.hypot(*(res.xy - query_reference_xy(da, q)).T)),
                      "se2_residual_rms_m": (em.alignment.get("built_se2") or {}).get("residual_rms_m"),
                      "linked_map_walks": len(linked), "map_walks": len(mine)}
    return out


def uncertainty_quality(table: pd.DataFrame) -> dict:
    ok = table["error_m"].notna() & table["uncertainty_m"].notna()
    e, u = table.loc[ok, "error_m"], table.loc[ok, "uncertainty_m"]
    return {"spearman": float(e.rank().corr(u.rank())), "share_error_below": float((e <= u).mean()),
            "median_uncertainty_m": float(u.median()), "n": int(ok.sum())}


def venue(name: str, inp: Path, scratch: Path, splitter) -> dict:
    t0 = time.perf_counter()
    map_in, test_in = splitter(inp, scratch / "split")
    build(inp, scratch / "ws_all", evaluate=True)
    build(map_in, scratch / "ws_map", evaluate=False)
    ev = json.loads((scratch / "ws_all" / "evaluate" / "report.json").read_text())
    out: dict = {"test_walks": len(ev["test_walks"]), "localizers": {}}
    for loc in LOCALIZERS:
        pos = scratch / f"{loc}.parquet"
        cli("localize", "-w", scratch / "ws_map", test_in, "-o", pos, "--localizer", loc, "--force", "-q")
        from rmbuild.evaluate.localization import error_stats

        table = pd.read_parquet(pos)
        held = scratch / f"{loc}_hold_out.parquet"
        cli("localize", "-w", scratch / "ws_all", test_in, "-o", held, "--localizer", loc, "--hold-out", "--force",
            "-q")
        out["localizers"][loc] = {"evaluate": ev["maps"]["built"][loc], "same_positions": same_positions(
            scratch / "ws_all", loc), "hold_out": error_stats(pd.read_parquet(held)["error_m"].to_numpy()),
            "localize": error_stats(table["error_m"].to_numpy()), "uncertainty": uncertainty_quality(table),
            "evaluates_grid": map_only_on_evaluates_grid(scratch / "ws_all", scratch / "ws_map", loc)}
        print(name, loc, {k: round(v["mean"], 2) for k, v in out["localizers"][loc].items() if "mean" in v},
              flush=True)
    out["time_s"] = round(time.perf_counter() - t0, 1)
    return out


def md(res: dict) -> list[str]:
    lines = ["# `rmbuild localize` vs `rmbuild evaluate` on the same test walks", "",
             "mean / median / P90 error (m), scans scored; `bench/bench_localize.py` (setup in its docstring).", "",
             "| venue | localizer | evaluate | localize --hold-out (workspace of every walk) | same positions, "
             "map frame | localize (map walks only) | uncertainty: Spearman / share error <= it |",
             "|---|---|---|---|---|---|---|"]

    def s(e: dict) -> str:
        return f"{e['mean']:.2f} / {e['median']:.2f} / {e['p90']:.2f} ({e['n']})"

    for v, d in res.items():
        if "localizers" not in d:
            lines.append(f"| {v} | {d.get('unavailable', '')} | | | | | |")
            continue
        for loc, r in d["localizers"].items():
            u = r["uncertainty"]
            lines.append(f"| {v} | {loc} | {s(r['evaluate'])} | {s(r['hold_out'])} | {s(r['same_positions'])} | "
                         f"{s(r['localize'])} | "
                         f"{u['spearman']:.2f} / {u['share_error_below']:.2f} |")
    lines += ["", "Where the difference between `evaluate` and `localize` (map walks only) comes from: "
              "evaluate's kind of built map (SE(2) to the truth, its grid) made from each workspace's optimised "
              "map walks; mean / median / P90 (m), the SE(2)'s residual RMS, linked map walks.", "",
              "| venue | localizer | optimised with the test walks | optimised without them |", "|---|---|---|---|"]
    for v, d in res.items():
        for loc, r in d.get("localizers", {}).items():
            g = r["evaluates_grid"]
            lines.append(f"| {v} | {loc} | " + " | ".join(
                f"{s(g[k]['errors'])}; {_fit(g[k]['se2_residual_rms_m'])}; {g[k]['linked_map_walks']} of "
                f"{g[k]['map_walks']}" for k in ("all", "map")) + " |")
    return lines


def _fit(rms: float | None) -> str:
    """The SE(2)'s residual RMS, or why there is none (a map in the building frame is not fitted)."""
    return "no fit (building frame)" if rms is None else f"{rms:.2f} m"


def main() -> None:
    scratch = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="bench_localize_"))
    res: dict = {}
    syn = scratch / "synthetic"
    cli("simulate", syn / "in", "--preset", "default", "--seed", "7", "-q", "--force")
    res["synthetic default (seed 7)"] = venue("synthetic", syn / "in", syn, split_synthetic)
    if ILC_F1.is_dir():
        res["ILC site1/F1"] = venue("F1", ILC_F1, scratch / "F1", split_ilc)
    else:
        res["ILC site1/F1"] = {"unavailable": "msft-ilc20 not present"}
    write_result("localize", {"venues": res})
    (RESULTS / "localize.md").write_text("\n".join(md(res)) + "\n")
    print("\n".join(md(res)))


if __name__ == "__main__":
    main()
