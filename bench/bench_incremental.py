"""`rmbuild optimize --incremental` against a full re-run, on MS ILC floors.

Run from the repo root: ``python -m bench.bench_incremental [--floors site1/F1,site2/B1] [--share 0.2]
[--scratch DIR] [--bytecode]``. Per floor, the traces are split in file-name order (the last ``share`` of them are the
"new" walks): ``ingest`` the first part, ``optimize``, ``ingest --append`` the rest; the workspace is then
copied twice and one copy runs ``optimize --incremental``, the other a full ``optimize --force`` (one after
the other, each through the CLI). Both then run ``export-map`` and ``evaluate --localizer knn``. Recorded:
the wall and CPU time of each optimize command (the fastest of ``--repeat`` runs) and its stage time, the
landmark error against the waypoints (optimize's report: all walks, and the linked walks only), the kNN
median error on the built map (evaluate), linked walk counts and how many new walks were placed. Writes
``bench/results/incremental.json`` and ``incremental.md``. Data: ``$RMBUILD_DATASETS``, default
``<repo>/../shared/datasets``; skips cleanly when absent. ``--before DIR``: the same commands with the code of
another checkout too, in the same run (before/after a change). About two minutes of CPU per floor and version.

Byte code: every command of one run starts in the same state. By default that is the environment's: with
``PYTHONDONTWRITEBYTECODE=1`` and no ``__pycache__`` in the checkout, each command compiles the rmbuild
modules it imports (~0.1 s of CPU for the incremental command's); without it, the set-up commands leave the
byte code the timed ones use. ``--bytecode`` compiles each checkout's modules first (``compileall``, writing
``__pycache__`` into the checkouts), as installing a package does: both commands then load cached byte code.
The results record which.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

from bench.bench_real import ilc_data_root
from bench.common import RESULTS, write_result

#: the issue's targets: the incremental run at least this many times faster, accuracy within this share
SPEEDUP_TARGET = 5.0
ACCURACY_TOLERANCE = 0.05


def cli(*args: str, tree: Path | None = None) -> tuple[float, float]:
    """Run ``rmbuild ARGS -q`` through the CLI (the code of ``tree`` first on the path when given); its
    (wall time, CPU time: user + system) in s. The CPU time moves less with the load of other processes on a
    shared machine than the wall time, but it does: multi-threaded matrix products (the full run's) spend
    more CPU under contention. Raises on failure."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rmbuild", *args, "-q"], capture_output=True, text=True, env=env,
                          cwd=tree)  # `python -m` puts the working directory first on the path
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"rmbuild {' '.join(args)}: {proc.stderr.strip()[-400:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def split_inputs(src: Path, scratch: Path, share: float) -> tuple[Path, Path, int, int]:
    """Symlink the floor's traces into ``old/`` and ``new/`` (the last ``share`` in file-name order)."""
    files = sorted(src.glob("*.txt*"))
    n_new = max(1, round(share * len(files)))
    old, new = scratch / "old", scratch / "new"
    for d, part in ((old, files[:-n_new]), (new, files[-n_new:])):
        d.mkdir(parents=True)
        for f in part:
            (d / f.name).symlink_to(f)
    return old, new, len(files) - n_new, n_new


def run_floor(src: Path, scratch: Path, share: float, before: Path | None, repeat: int) -> dict:
    """Per code version (this checkout; ``before`` too when given): the incremental and the full optimize
    of the appended workspace, each timed ``repeat`` times (interleaved; the fastest kept), then scored."""
    if scratch.exists():
        shutil.rmtree(scratch)
    old, new, n_old, n_new = split_inputs(src, scratch, share)
    base = scratch / "base"
    cli("ingest", str(old), "-w", str(base), "--format", "msft-ilc")
    t_first, _ = cli("optimize", "-w", str(base))
    cli("ingest", "--append", str(new), "-w", str(base))
    versions = {"": None} if before is None else {"": None, "before_": before}
    plan = [(f"{v}{name}", args, tree) for v, tree in versions.items()
            for name, args in (("incremental", ["--incremental"]), ("full", ["--force"]))]
    times: dict[str, list[tuple[float, float, float]]] = {name: [] for name, _, _ in plan}
    for _ in range(repeat):
        for name, args, tree in plan:
            ws = scratch / name
            if ws.exists():
                shutil.rmtree(ws)
            shutil.copytree(base, ws, symlinks=True)
            load0 = os.getloadavg()[0]
            times[name].append((*cli("optimize", "-w", str(ws), *args, tree=tree), load0))
    runs = {name: _scored(scratch / name, times[name], tree) for name, _, tree in plan}
    out = {"walks_old": n_old, "walks_new": n_new, "first_optimize_wall_s": round(t_first, 2), "repeat": repeat,
           "runs": runs}
    for v in versions:
        inc, full = runs[f"{v}incremental"], runs[f"{v}full"]
        out[f"{v}ratios"] = {
            "speedup_wall": round(full["wall_s"] / inc["wall_s"], 2),
            "speedup_cpu": round(full["cpu_s"] / inc["cpu_s"], 2),
            "speedup_optimize": round(full["optimize_s"] / inc["optimize_s"], 2),
            "landmark_ratio": _ratio(inc["landmark_error_m"], full["landmark_error_m"]),
            "landmark_linked_ratio": _ratio(inc["landmark_error_linked_m"], full["landmark_error_linked_m"]),
            "knn_median_ratio": _ratio(inc["knn_median_m"], full["knn_median_m"])}
    return out


def _scored(ws: Path, times: list[tuple[float, float, float]], tree: Path | None) -> dict:
    """The fastest of ``times`` (wall, cpu, load average before), the last run's report figures, and
    export-map + evaluate --localizer knn on it."""
    cli("export-map", "-w", str(ws), tree=tree)
    cli("evaluate", "-w", str(ws), "--localizer", "knn", tree=tree)
    opt = json.loads((ws / "optimize" / "report.json").read_text())
    ev = json.loads((ws / "evaluate" / "report.json").read_text())
    o = opt.get("optimized") or {}
    inc = opt.get("incremental") or {}
    return {
        "wall_s": round(min(t[0] for t in times), 2), "cpu_s": round(min(t[1] for t in times), 2),
        "all_wall_s": [round(t[0], 2) for t in times], "all_cpu_s": [round(t[1], 2) for t in times],
        "load_average_before": [t[2] for t in times],
        "stage_s": opt["time_s"].get("stage_total"), "optimize_s": opt["time_s"].get("total"),
        "landmark_error_m": (o.get("landmark_error_m") or {}).get("mean"),
        "landmark_error_linked_m": (o.get("landmark_error_fitted_walks_m") or {}).get("mean"),
        "landmark_fixes_linked": (o.get("landmark_error_fitted_walks_m") or {}).get("n"),
        "knn_median_m": ev["maps"]["built"]["knn"]["median"], "knn_n": ev["maps"]["built"]["knn"]["n"],
        "linked_walks": opt.get("linked_walks"), "walks": opt.get("walks"),
        "new_walks_placed": inc.get("new_walks_placed"),
    }


def _ratio(a: float | None, b: float | None) -> float | None:
    return round(a / b, 3) if a is not None and b else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--floors", default="site1/F1,site2/B1")
    ap.add_argument("--share", type=float, default=0.2)
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-incremental"))
    ap.add_argument("--before", type=Path, default=None,
                    help="another checkout of rmbuild (e.g. `git worktree add` of an earlier commit) run beside "
                         "this one in the same run")
    ap.add_argument("--repeat", type=int, default=2, help="timings per command (the fastest is kept)")
    ap.add_argument("--bytecode", action="store_true",
                    help="byte-compile each checkout's rmbuild first (as an installed package is): every command "
                         "then loads cached byte code")
    args = ap.parse_args()
    root = ilc_data_root()
    if not root.is_dir():
        print(f"skipped: {root} absent")
        return
    if args.bytecode:
        for tree in (Path(__file__).resolve().parent.parent, *([args.before.resolve()] if args.before else [])):
            subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "rmbuild")], check=True)
    result: dict = {"share_new": args.share, "speedup_target": SPEEDUP_TARGET,
                    "accuracy_tolerance": ACCURACY_TOLERANCE, "before": _describe(args.before),
                    "bytecode": _bytecode_state(args.bytecode), "floors": {}}
    for floor in args.floors.split(","):
        src = root / floor / "path_data_files"
        try:
            result["floors"][floor] = run_floor(src, args.scratch.resolve() / floor.replace("/", "-"), args.share,
                                                args.before.resolve() if args.before else None, args.repeat)
        except RuntimeError as e:
            result["floors"][floor] = {"error": str(e)}
    write_result("incremental", result)
    (RESULTS / "incremental.md").write_text(markdown(result))
    print(markdown(result))


def _bytecode_state(compiled: bool) -> str:
    """How the timed commands get rmbuild's byte code (the module docstring)."""
    if compiled:
        return "compiled beforehand"
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        return "PYTHONDONTWRITEBYTECODE set: compiled by each command unless the checkout has __pycache__"
    return "written by the set-up commands"


def _describe(tree: Path | None) -> str | None:
    """The commit of the ``--before`` checkout (its path when it is not a git checkout)."""
    if tree is None:
        return None
    r = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else str(tree)


def _f(v: float | None, fmt: str = ".2f") -> str:
    return "" if v is None else format(v, fmt)


def markdown(result: dict) -> str:
    lines = ["# `optimize --incremental` vs a full re-run (`python -m bench.bench_incremental`)", "",
             f"The last {result['share_new']:.0%} of a floor's traces appended (`ingest --append`) to a workspace "
             "optimised on the rest; the same workspace then optimised incrementally and in full, each command "
             "timed in turn (the fastest of the repeats kept). Wall: the command's wall time; CPU: its user + "
             "system time (less moved by other processes on a shared machine than the wall time); core: the "
             "optimisation itself (the report's time_s.total). Landmark error: optimize's report against the waypoints "
             "(mean, m; all walks / linked walks only); kNN: `evaluate --localizer knn`, median error (m) on "
             "the built map. Targets: "
             f"≥ {result['speedup_target']:g}× faster, accuracy within {result['accuracy_tolerance']:.0%}."
             + (f" `before`: the code at {result['before']}, run in the same run." if result.get("before") else "")
             + (f" rmbuild's byte code: {result['bytecode']}." if result.get("bytecode") else ""),
             "", "| floor | code | walks old + new | wall s full / incr (ratio) | CPU s full / incr (ratio) | "
             "core s full / incr (ratio) | landmark m full / incr | linked-walk landmark m full / incr | "
             "kNN median m full / incr | linked walks full / incr (new placed) |", "|---" * 10 + "|"]
    for floor, r in result["floors"].items():
        if "error" in r:
            lines.append(f"| {floor} | {r['error']} | | | | | | | | |")
            continue
        for v in ("before_", ""):
            if f"{v}ratios" not in r:
                continue
            f, i, q = r["runs"][f"{v}full"], r["runs"][f"{v}incremental"], r[f"{v}ratios"]
            lines.append(
                f"| {floor} | {v.rstrip('_') or 'this'} | {r['walks_old']} + {r['walks_new']} | "
                f"{f['wall_s']:.1f} / {i['wall_s']:.1f} ({q['speedup_wall']:.1f}×) | "
                f"{f['cpu_s']:.1f} / {i['cpu_s']:.1f} ({q['speedup_cpu']:.1f}×) | "
                f"{_f(f['optimize_s'], '.1f')} / {_f(i['optimize_s'], '.1f')} ({q['speedup_optimize']:.1f}×) | "
                f"{_f(f['landmark_error_m'])} / {_f(i['landmark_error_m'])} | "
                f"{_f(f['landmark_error_linked_m'])} / {_f(i['landmark_error_linked_m'])} | "
                f"{_f(f['knn_median_m'])} / {_f(i['knn_median_m'])} | {f['linked_walks']} / {i['linked_walks']} "
                f"({i['new_walks_placed']} of {r['walks_new']}) |")
    loads = [x for r in result["floors"].values() for run in r.get("runs", {}).values()
             for x in run.get("load_average_before", [])]
    if loads:
        lines += ["", f"Load average (1 min, {os.cpu_count()} CPUs) before the timed "
                  f"commands: {min(loads):.1f}-{max(loads):.1f}."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
