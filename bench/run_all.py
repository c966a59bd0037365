"""`make bench`: run every benchmark, write bench/results/*.json and bench/results/SUMMARY.md."""

from __future__ import annotations

import importlib
import json
import sys
import traceback

from bench.common import RESULTS

BENCHES = ["bench_ingest", "bench_optimize", "bench_map", "bench_pdr", "bench_localizers", "bench_viz"]


def main() -> int:
    failed = []
    for name in BENCHES:
        try:
            mod = importlib.import_module(f"bench.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"bench.{name}":
                continue
            raise
        print(f"== {name}", flush=True)
        try:
            mod.main()
        except Exception:
            traceback.print_exc()
            failed.append(name)
    lines = ["# Benchmark results", "", "Written by `make bench`; one JSON per benchmark beside this file.", ""]
    for p in sorted(RESULTS.glob("*.json")):
        data = json.loads(p.read_text())
        data.pop("machine", None)
        lines += [f"## {p.stem}", "", "```json", json.dumps(data, indent=1)[:3000], "```", ""]
    (RESULTS / "SUMMARY.md").write_text("\n".join(lines))
    print(f"results in {RESULTS}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
