"""`make bench`: run every benchmark, write bench/results/*.json and bench/results/SUMMARY.md."""

from __future__ import annotations

import importlib
import os
import sys
import traceback

from bench.common import RESULTS
from bench.summary import write_summary

BENCHES = ["bench_ingest", "bench_optimize", "bench_map", "bench_pdr", "bench_localizers", "bench_uiloc", "bench_viz",
           "bench_scale", "bench_incremental"]
# the venue-month scaling run (bench_month) takes ~45 min: only with RMBUILD_BENCH_MONTH=1
if os.environ.get("RMBUILD_BENCH_MONTH") == "1":
    BENCHES.append("bench_month")


def main() -> int:
    failed = []
    for name in BENCHES:
        print(f"== {name}", flush=True)
        try:
            importlib.import_module(f"bench.{name}").main()
        except Exception:
            traceback.print_exc()
            failed.append(name)
    write_summary()
    print(f"results in {RESULTS}" + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
