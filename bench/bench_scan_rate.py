"""The real floors with fewer Wi-Fi scans: how the pipeline holds when phones scan less often.

The MS ILC 2.0 traces were recorded by Android 8 phones scanning every ~2.3 s; Android 9 and later limit a
foreground app to four scans in two minutes unless "Wi-Fi scan throttling" is switched off in the developer
options, and apps often pace their scans. Each policy below thins every trace's scans (a scan: the readings
sharing one timestamp; the other lines untouched) and runs `make bench-real`'s whole pipeline and scoring
on the thinned copies:

- ``every_5s`` / ``every_10s``: a scan is kept when it comes at least 5 / 10 s after the last kept one;
- ``android9``: a scan is kept when fewer than four were kept in the 120 s before it (each trace on its
  own: a device recording walks back to back would fare worse).

Writes ``bench/results/scan_rate.{json,md}``; the thinned copies and workspaces go to ``--scratch``.
"""

from __future__ import annotations

import argparse
import gzip
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from bench import bench_real as br
from bench.common import write_result

POLICIES = ("native", "every_5s", "every_10s", "android9")
ANDROID9_SCANS, ANDROID9_WINDOW_S = 4, 120.0


def keeper(policy: str) -> Callable[[float], bool]:
    """A function of a scan's time (s, in order) that says whether the policy keeps it (module docstring)."""
    kept: list[float] = []
    if policy.startswith("every_"):
        gap = float(policy[len("every_"):-1])

        def paced(t: float) -> bool:
            if kept and t - kept[-1] < gap:
                return False
            kept.append(t)
            return True
        return paced
    if policy == "android9":
        def throttled(t: float) -> bool:
            if sum(1 for x in kept if t - x < ANDROID9_WINDOW_S) >= ANDROID9_SCANS:
                return False
            kept.append(t)
            return True
        return throttled
    raise ValueError(f"unknown policy {policy!r}")


def scan_key(line: str, fmt: str) -> tuple[str, float] | None:
    """(scan id, time s) of a Wi-Fi reading line of an MS ILC trace or an IPIN logfile, else None."""
    if fmt == "msft-ilc":
        parts = line.split("\t", 2)
        if len(parts) > 1 and parts[1] == "TYPE_WIFI":
            return parts[0], int(parts[0]) / 1000.0
        return None
    if line.startswith("WIFI;"):
        t = line.split(";", 2)[1]
        return t, float(t)
    return None


def thin_lines(lines: list[str], policy: str, fmt: str) -> tuple[list[str], int, int]:
    """(the lines with the dropped scans' readings removed, scans kept, scans)."""
    keep, decided, out = keeper(policy), {}, []
    for line in lines:
        key = scan_key(line, fmt)
        if key is not None:
            if key[0] not in decided:
                decided[key[0]] = keep(key[1])
            if not decided[key[0]]:
                continue
        out.append(line)
    return out, sum(decided.values()), len(decided)


def thin_floor(src: Path, dst: Path, policy: str, fmt: str) -> tuple[int, int]:
    """Copy a floor's folder with every trace thinned (other files linked); returns (scans kept, scans)."""
    kept = total = 0
    for p in sorted(src.rglob("*")):
        if p.is_dir():
            continue
        q = dst / p.relative_to(src)
        q.parent.mkdir(parents=True, exist_ok=True)
        trace = p.name.endswith((".txt", ".txt.gz"))
        if not trace:
            if not q.exists():
                os.symlink(p.resolve(), q)
            continue
        opener = gzip.open if p.name.endswith(".gz") else open
        with opener(p, "rt", errors="surrogateescape", newline="") as f:
            lines, k, n = thin_lines(f.readlines(), policy, fmt)
        with opener(q, "wt", errors="surrogateescape", newline="") as f:
            f.writelines(lines)
        kept, total = kept + k, total + n
    return kept, total


def run_policy(policy: str, floors: list[str], root: Path, scratch: Path) -> list[dict]:
    rows = []
    for name in floors:
        rel, fmt = br.FLOORS[name]
        if not (root / rel).exists():
            rows.append({"policy": policy, "floor": name, "skipped": f"{root / rel} not found"})
            continue
        data = root
        kept = total = None
        if policy != "native":
            data = scratch / "data" / policy
            kept, total = thin_floor(root / rel, data / rel, policy, fmt)
        r = br.measure_floor(name, data, scratch / policy)
        r.pop("per_walk", None)  # the per-walk table stays in the workspace: 24 runs of it would swamp the file
        rows.append({"policy": policy, "scans_kept": kept, "scans": total, **r})
    return rows


def md_row(r: dict) -> str:
    if "skipped" in r or "error" in r:
        return f"| {r['policy']} | {r['floor']} | {r.get('skipped') or r.get('error')} |" + " |" * 5
    vic = (r.get("optimize_report") or {}).get("vicinity") or {}
    kept = "all" if r["scans_kept"] is None else f"{r['scans_kept']} / {r['scans']}"
    lm, k = r["landmark_m"], r["knn"]
    return "| " + " | ".join([
        r["policy"], r["floor"], kept, br._f(vic.get("scan_spacing_m")), br._f(vic.get("scans_per_walk"), "{:.0f}"),
        f"{r['linked']} / {r['walks']}", br._f((lm.get("linked_walks") or {}).get("mean")),
        f"{br._f(k['built_median_m'])} / {br._f(k['surveyed_median_m'])} ({br._f(k['ratio'], '{:.2f}×')})",
    ]) + " |"


def markdown(result: dict) -> str:
    head = ("| policy | floor | scans kept | scan spacing m | scans per walk | linked | linked walks mean m "
            "| kNN median built / surveyed m |\n|---|---|---|---|---|---|---|---|")
    body = "\n".join(md_row(r) for r in result["rows"])
    return (f"# Real floors with fewer Wi-Fi scans (`python -m bench.bench_scan_rate`)\n\nCode: "
            f"{result['code'].get('commit', '?')}; written on {result['date']}. Policies and columns: the "
            f"script's docstring and `bench/results/real.md`.\n\n{head}\n{body}\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--floors", help="comma-separated subset of bench_real's floors")
    ap.add_argument("--policies", default=",".join(POLICIES), help=f"comma-separated subset of {POLICIES}")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/rmbuild-bench-scan-rate"))
    ap.add_argument("--out", default="scan_rate")
    a = ap.parse_args(argv)
    root = Path(os.environ.get("RMBUILD_DATASETS", br.DEFAULT_DATASETS)).resolve()
    if not root.is_dir():
        print(f"bench-scan-rate: no datasets at {root} (set RMBUILD_DATASETS); skipped")
        return 0
    floors = br.select_floors(a.floors)
    rows = [r for p in a.policies.split(",") for r in run_policy(p.strip(), floors, root, a.scratch.resolve())]
    result = {"code": br.code_identity(), "date": time.strftime("%Y-%m-%d"), "rows": rows}
    p = write_result(a.out, result)
    p.with_suffix(".md").write_text(markdown(result))
    print(p.with_suffix(".md").read_text())
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
