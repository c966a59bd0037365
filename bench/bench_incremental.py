"""`optimize --incremental` after `ingest --append` against a full `optimize` of the same walks (`make bench`).

Run from the repo root: ``python -m bench.bench_incremental [--splits ipin-trials,ipin-reps,site1/F1,site2/B1]
[--scratch DIR]``. Splits: IPIN 2023 -2 trials 21-24 | 25-27 and repetitions 1-2 | 3-4; two MS ILC floors
80/20 in time order (their trace files are named by MongoDB ObjectIds, which begin with their creation
time: file-name order is time order). Per split: ``ingest`` the old part, ``optimize``, ``ingest --append``
the new part; the workspace is copied twice, one copy runs ``optimize --incremental`` and the other a full
``optimize --force`` (each command timed), then ``export-map`` and ``evaluate --localizer knn``. Scored:
the linked walks' landmark error (optimize's report, one rigid fit on the linked walks), walks placed right
(:func:`bench.bench_real.consensus_errors`: mean waypoint error ≤ 8 m in the consensus frame), the kNN
median on the built map, and the time (command wall time; optimize's own time). Whether the incremental run
gave up (and ran the full optimization) is recorded with its reason. Writes bench/results/incremental.json
and incremental.md. Data: ``$RMBUILD_DATASETS`` (default ``<repo>/../shared/datasets``); skips cleanly when
absent.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from bench.bench_real import DEFAULT_DATASETS, consensus_errors, linked_walks, need_table, read_table, waypoint_errors
from bench.common import RESULTS, write_result

#: the issue's bar: incremental within this share (or ABS_TOLERANCE_M) of the full run, this much faster on ILC
TOLERANCE, ABS_TOLERANCE_M, SPEEDUP_TARGET = 0.10, 0.3, 3.0
RIGHT_M = 8.0
SPLITS = {  # name -> (folder under the data sets, ingest format, how the old part is chosen)
    "ipin-trials": ("ipin2023/logs", "ipin", "trials"),
    "ipin-reps": ("ipin2023/logs", "ipin", "repetitions"),
    "site1/F1": ("msft-ilc20/data/site1/F1/path_data_files", "msft-ilc", "time"),
    "site2/B1": ("msft-ilc20/data/site2/B1/path_data_files", "msft-ilc", "time"),
}


def cli(*args: str) -> float:
    """``rmbuild ARGS -q`` through the CLI; its wall time (s). Raises on failure."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rmbuild", *args, "-q"], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"rmbuild {' '.join(args)}: {proc.stderr.strip()[-400:]}")
    return time.perf_counter() - t0


def split_files(src: Path, how: str) -> tuple[list[Path], list[Path]]:
    files = sorted(src.glob("*.txt*"))
    if how == "trials":
        old = [f for f in files if any(f"Trial{t}_" in f.name for t in (21, 22, 23, 24))]
    elif how == "repetitions":
        old = [f for f in files if any(f"repetition0{r}" in f.name for r in (1, 2))]
    else:
        old = files[:round(0.8 * len(files))]
    return old, [f for f in files if f not in old]


def timed(base: Path, ws: Path, args: list[str]) -> float:
    """A fresh copy of ``base`` optimised with ``args``; the command's wall time (s)."""
    if ws.exists():
        shutil.rmtree(ws)
    shutil.copytree(base, ws, symlinks=True)
    return cli("optimize", "-w", str(ws), *args)


def run_split(src: Path, fmt: str, how: str, scratch: Path, repeat: int) -> dict:
    if scratch.exists():
        shutil.rmtree(scratch)
    old, new = split_files(src, how)
    (scratch / "old").mkdir(parents=True)
    for f in old:
        (scratch / "old" / f.name).symlink_to(f)
    base = scratch / "base"
    cli("ingest", str(scratch / "old"), "-w", str(base), "--format", fmt)
    cli("optimize", "-w", str(base))
    cli("ingest", "--append", *map(str, new), "-w", str(base))
    out: dict = {"walks_old": len(old), "walks_new": len(new), "runs": {}}
    plan = (("incremental", ["--incremental"]), ("full", ["--force"]))
    walls: dict[str, list[float]] = {name: [] for name, _ in plan}
    for _ in range(repeat):  # interleaved; the fastest of each kept (other jobs share the machine)
        for name, args in plan:
            walls[name].append(timed(base, scratch / name, args))
    for name, _ in plan:
        ws = scratch / name
        wall = min(walls[name])
        cli("export-map", "-w", str(ws))
        cli("evaluate", "-w", str(ws), "--localizer", "knn")
        out["runs"][name] = {"wall_s": round(wall, 2), "all_wall_s": [round(w, 2) for w in walls[name]],
                             **score(ws)}
    out["first_run_walks_right"] = first_run_walks_right(scratch)
    inc, full = out["runs"]["incremental"], out["runs"]["full"]
    out["within_bar"] = {k: within(inc[k], full[k]) for k in ("landmark_linked_m", "knn_median_m")}
    out["within_bar"]["placed_right"] = inc["placed_right"] >= full["placed_right"]
    out["speedup_wall"] = round(full["wall_s"] / inc["wall_s"], 2)
    out["speedup_optimize"] = round(full["optimize_s"] / inc["optimize_s"], 2)
    return out


def score(ws: Path) -> dict:
    opt = json.loads((ws / "optimize" / "report.json").read_text())
    ev = json.loads((ws / "evaluate" / "report.json").read_text())
    linked = linked_walks(read_table(ws, "optimize.walks"), need_table(ws, "optimize.poses"))
    err = consensus_errors(waypoint_errors(ws, linked))
    inc = opt.get("incremental") or {}
    tried = inc.get("tried_s") or 0.0  # a run that gave up: its incremental try and the full run
    return {"optimize_s": round(opt["time_s"].get("total") + tried, 3), "stage_s": opt["time_s"].get("stage_total"),
            "landmark_linked_m": round((opt["optimized"].get("landmark_error_fitted_walks_m") or {}).get("mean"), 2),
            "placed_right": int((err <= RIGHT_M).sum()), "scored": int(len(err)), "linked": len(linked),
            "knn_median_m": round(ev["maps"]["built"]["knn"]["median"], 2),
            "gave_up": inc.get("gave_up"), "new_walks_placed": inc.get("new_walks_placed"),
            "held_walks": inc.get("held_walks"), "held_walks_moved": len(inc.get("held_walks_moved") or [])}


def first_run_walks_right(scratch: Path) -> dict:
    """The walks the first optimize linked: how many are placed right after it, after the incremental run
    (held, so the same unless it gave up) and after the full run; in each run's own consensus frame."""
    err = {}
    for name in ("base", "incremental", "full"):
        ws = scratch / name
        err[name] = consensus_errors(waypoint_errors(ws, linked_walks(read_table(ws, "optimize.walks"),
                                                                      need_table(ws, "optimize.poses"))))
    first = err["base"].index
    return {"walks": len(first), **{("first_run" if k == "base" else k): int((v.reindex(first) <= RIGHT_M).sum())
                                    for k, v in err.items()}}


def within(a: float, b: float) -> bool:
    return a <= b * (1 + TOLERANCE) or a <= b + ABS_TOLERANCE_M


def markdown(result: dict) -> str:
    lines = ["# `optimize --incremental` after `ingest --append` vs a full optimize "
             "(`python -m bench.bench_incremental`)",
             "", "Old part ingested and optimised, new part appended; then the same workspace optimised with "
             "`--incremental` and in full. Landmark: optimize's linked-walk landmark error (m, mean); right: walks "
             f"placed right (consensus error ≤ {RIGHT_M:g} m) of the linked walks with waypoints; kNN: median (m) on "
             "the built map; wall: the optimize command (s, the fastest of the interleaved repeats), optimize's own "
             "time in brackets (a run that gave up: its try and the full run). Bar: within "
             f"{TOLERANCE:.0%} (or {ABS_TOLERANCE_M} m), no fewer walks right, ≥ {SPEEDUP_TARGET:g}× faster on ILC.",
             "", "| split | walks old + new | incremental: what ran | landmark m full / incr | right full / incr | "
             "kNN m full / incr | wall s full / incr (optimize s) | speed-up wall (optimize) | within bar | "
             "first run's linked walks right: first run / incr / full |", "|---" * 10 + "|"]
    for name, r in result["splits"].items():
        if "error" in r or "skipped" in r:
            lines.append(f"| {name} | {r.get('error') or r.get('skipped')} | | | | | | | | |")
            continue
        f, i, ok = r["runs"]["full"], r["runs"]["incremental"], r["within_bar"]
        bad = [k for k, v in ok.items() if not v]
        fr = r["first_run_walks_right"]
        ran = f"gave up → full ({i['gave_up']})" if i["gave_up"] else \
            f"incremental: {i['new_walks_placed']} of {r['walks_new']} new placed on {i['held_walks']} held"
        lines.append(f"| {name} | {r['walks_old']} + {r['walks_new']} | {ran} | {f['landmark_linked_m']:.2f} / "
                     f"{i['landmark_linked_m']:.2f} | {f['placed_right']}/{f['scored']} / "
                     f"{i['placed_right']}/{i['scored']} | {f['knn_median_m']:.2f} / {i['knn_median_m']:.2f} | "
                     f"{f['wall_s']:.1f} ({f['optimize_s']:.1f}) / {i['wall_s']:.1f} ({i['optimize_s']:.1f}) | "
                     f"{r['speedup_wall']:.1f}× ({r['speedup_optimize']:.1f}×) | "
                     + ("yes" if not bad else "no: " + ", ".join(bad))
                     + f" | {fr['first_run']} / {fr['incremental']} / {fr['full']} of {fr['walks']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--splits", default=",".join(SPLITS))
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-incremental"))
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each optimize command (the fastest kept)")
    args = ap.parse_args([] if __name__ != "__main__" else None)
    root = Path(os.environ.get("RMBUILD_DATASETS", DEFAULT_DATASETS))
    if not root.is_dir():
        print(f"skipped: {root} absent")
        return
    result: dict = {"repeat": args.repeat, "tolerance": TOLERANCE, "abs_tolerance_m": ABS_TOLERANCE_M,
                    "speedup_target": SPEEDUP_TARGET,
                    "splits": {}}
    for name in args.splits.split(","):
        rel, fmt, how = SPLITS[name]
        if not (root / rel).is_dir():
            result["splits"][name] = {"skipped": f"{rel} absent"}
            continue
        try:
            result["splits"][name] = run_split(root / rel, fmt, how, args.scratch.resolve() / name.replace("/", "-"),
                                               args.repeat)
        except RuntimeError as e:
            result["splits"][name] = {"error": str(e)}
        print(name, json.dumps(result["splits"][name].get("runs", result["splits"][name]))[:400], flush=True)
    write_result("incremental", result)
    (RESULTS / "incremental.md").write_text(markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main()
