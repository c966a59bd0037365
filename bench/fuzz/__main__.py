"""``python -m bench.fuzz [--cases N] [--seed S] [--jobs J] [--out FILE]``: run the fuzz campaign."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from bench.fuzz.run import MEM_CAP_MB, TIMEOUT_S, plan, run_cases, summarise


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.fuzz", description=__doc__)
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--kind", default=None, help="only cases of this kind (schema, ilc, config, ...)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/fuzz.json"))
    args = ap.parse_args()
    cases = plan(args.cases, args.seed)
    if args.kind:
        cases = [(args.kind, s) for _, s in cases]
    t0 = time.perf_counter()
    results = run_cases(cases, jobs=args.jobs, progress=True)
    summary = summarise(results)
    summary.update({"seed": args.seed, "jobs": args.jobs, "wall_s": round(time.perf_counter() - t0, 1),
                    "memory_cap_mb": MEM_CAP_MB, "timeout_s": TIMEOUT_S, "python": platform.python_version()})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"{summary['cases']} cases, {summary['failures']} failures, peak RSS {summary['peak_rss_mb_max']} MB, "
          f"{summary['wall_s']} s -> {args.out}")
    for kind, k in summary["kinds"].items():
        print(f"  {kind:15s} {k['cases']:6d} cases  exit0 {k['exit_0']:5d}  exit2 {k['exit_2']:5d}  "
              f"failures {k['failures']:4d}  {k['problems']}  max {k['peak_rss_mb_max']} MB {k['time_s_max']} s")
    sys.exit(1 if summary["failures"] else 0)


if __name__ == "__main__":
    main()
