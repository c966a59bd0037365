"""Leave one floor out: choose a default among candidates by the other floors, score it on the held-out one.

usage: python -m bench.lofo NAME=RESULTS.json NAME=RESULTS.json ... [--out NAME]

Each RESULTS.json is a ``bench.bench_real`` result (``--config`` gives a candidate's optimize config) over the
same floors. For every floor, the candidate whose built / surveyed kNN median ratio has the smallest geometric
mean over the *other* floors is chosen, and its ratio on the held-out floor is what a floor nobody tuned on
would get. Printed (and written to bench/results/NAME.md with ``--out``): per floor each candidate's linked
walks, linked-walk mean error and kNN ratio; the choice per held-out floor; the geometric means.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from bench.common import RESULTS


def load(specs: list[str]) -> dict[str, dict[str, dict]]:
    """candidate name -> floor -> bench_real row (rows with an error or skipped left out)."""
    out: dict[str, dict[str, dict]] = {}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep:
            raise SystemExit(f"{spec!r}: expected NAME=RESULTS.json")
        rows = json.loads(Path(path).read_text())["floors"]
        out[name] = {r["floor"]: r for r in rows if "error" not in r and "skipped" not in r}
    return out


def ratio(row: dict) -> float:
    return float(row["knn"]["ratio"])


def geomean(values: list[float]) -> float:
    return math.exp(sum(math.log(v) for v in values) / len(values)) if values else math.nan


def choose(results: dict[str, dict[str, dict]], floors: list[str], held_out: str) -> str:
    """The candidate with the smallest geometric-mean kNN ratio over ``floors`` other than ``held_out``."""
    others = [f for f in floors if f != held_out]
    return min(results, key=lambda c: geomean([ratio(results[c][f]) for f in others]))


def table(results: dict[str, dict[str, dict]]) -> str:
    names = list(results)
    floors = [f for f in results[names[0]] if all(f in r for r in results.values())]
    head = ("| floor | " + " | ".join(f"{n}: linked, mean m, kNN ×" for n in names)
            + " | chosen on the others | its kNN × |")
    lines = [head, "|" + "---|" * (len(names) + 3)]
    held = []
    for f in floors:
        c = choose(results, floors, f)
        held.append(ratio(results[c][f]))
        cells = []
        for n in names:
            r = results[n][f]
            mean = (r["landmark_m"].get("linked_walks") or {}).get("mean")
            cells.append(f"{r['linked']}/{r['walks']}, {mean:.1f}, {ratio(r):.2f}" if mean is not None
                         else f"{r['linked']}/{r['walks']}, –, {ratio(r):.2f}")
        lines.append(f"| {f} | " + " | ".join(cells) + f" | {c} | {held[-1]:.2f} |")
    means = [f"{geomean([ratio(results[n][f]) for f in floors]):.2f}" for n in names]
    lines.append("| geometric mean | " + " | ".join(means) + f" | leave one floor out | {geomean(held):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", nargs="+", help="NAME=RESULTS.json (bench.bench_real output), one per candidate")
    ap.add_argument("--out", help="also write bench/results/OUT.md")
    a = ap.parse_args(argv)
    md = table(load(a.results))
    print(md)
    if a.out:
        intro = (__doc__ or "").split("\n\n")[1]
        (RESULTS / f"{a.out}.md").write_text(f"# Leave one floor out (`python -m bench.lofo`)\n\n{intro}\n\n{md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
