"""`make bench`: run every benchmark, write bench/results/*.json and bench/results/SUMMARY.md."""

from __future__ import annotations

import importlib
import json
import sys
import traceback

from bench.common import RESULTS

BENCHES = ["bench_ingest", "bench_optimize", "bench_map", "bench_pdr", "bench_localizers", "bench_uiloc", "bench_viz"]


def write_summary() -> None:
    """SUMMARY.md: every result JSON in bench/results, as it stands."""
    lines = ["# Benchmark results", "", "Written by `make bench` (`python -m bench.run_all`); one JSON per "
             "benchmark beside this file. Timings are wall-clock on the 2-core project machine; compare ratios "
             "measured in one run.", ""]
    for p in sorted(RESULTS.glob("*.json")):
        data = json.loads(p.read_text())
        machine = data.pop("machine", None)
        text = json.dumps(data, indent=1)
        if len(text) > 6000:
            text = text[:6000] + "\n... (truncated; see the JSON file)"
        lines += [f"## {p.stem}", "", f"machine: {machine}" if machine else "", "", "```json", text, "```", ""]
    (RESULTS / "SUMMARY.md").write_text("\n".join(lines))


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
