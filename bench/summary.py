"""bench/results/SUMMARY.md: one table of every benchmark's headline figures, their targets and whether
they are met, read from the JSON files beside it (``python -m bench.summary``; also the end of
``python -m bench.run_all``). A figure whose JSON (or key) is missing shows as "not run"."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.common import RESULTS


@dataclass(frozen=True)
class Row:
    """One headline figure: which JSON, a label, how to read it, its unit, and its target (text and test)."""

    source: str
    label: str
    get: Callable[[dict], Any]
    unit: str = ""
    target: str = ""
    met: Callable[[Any], bool] | None = None


def _case(d: dict, preset: str, mode: str) -> dict:
    return next(c for c in d["cases"] if c["preset"] == preset and c["mode"] == mode)


def _loc(d: dict, case: str, name: str, key: str = "mean") -> Any:
    return d["cases"][case]["localizers"][name][key]


def _knn_rounds(d: dict) -> str:
    k = d["knn"]
    loads = k.get("load_per_round") or [d["machine"].get("load_1min", float("nan"))]
    return (f"(median of {k.get('rounds', '?')} interleaved rounds, "
            f"{'stable' if k.get('stable', False) else 'not stable'}; load {min(loads):.1f}-{max(loads):.1f})")


def _knn_faiss(d: dict) -> str:
    f, c = d["knn"].get("faiss"), d["knn"]["one_thread_cpu"]
    if not isinstance(f, dict):
        return str(f or "not run")
    return (f"{f['speedup_batch']:.2f}× / {f['speedup_one_at_a_time']:.2f}× {_knn_rounds(d)}; CPU "
            f"{c.get('vs_faiss_batch', float('nan')):.2f}× / {c.get('vs_faiss_one_at_a_time', float('nan')):.2f}×")


def _month_case(c: dict) -> str:
    load = f" at load {c['load_at_start']:.0f}" if "load_at_start" in c else ""
    if c["status"] != "ok":
        return f"{c['status']} ({c['reason']}) after {c['after_s']:.0f} s{load}"
    w = c["wall_s"]
    return (f"CLI {w['cli']:.0f} s (pair search {w.get('pair_search', 0):.0f} / placement {w.get('placement', 0):.0f} "
            f"/ solve {w.get('solve', 0):.0f} / RF {w.get('rf_check', 0):.0f} / metrics {w.get('metrics', 0):.0f}), "
            f"{max(c['peak_memory_mb'], c.get('peak_memory_mb_watched', 0)):,.0f} MB, linked walks' error "
            f"{(c['linked_error'] or {}).get('linked_mean_m', 0):.2f} m{load}")


def _month_at(d: dict, n: int, wall_s: float, gb: float) -> str:
    c = next((c for c in d["cases"] if abs(c["target_poses"] - n) < 0.2 * n), None)
    if c is None:
        return "not run"
    ok = c["status"] == "ok" and c["wall_s"]["cli"] <= wall_s and \
        max(c["peak_memory_mb"], c.get("peak_memory_mb_watched", 0)) <= gb * 1024
    return ("ok: " if ok else "") + _month_case(c)


def _month_scaling(d: dict) -> str:
    return "; ".join(f"{c['target_poses'] // 1000}k: {_month_case(c)}" for c in d["cases"])


def _month_exponents(d: dict) -> str:
    ex = (d.get("exponents") or {}).get("end_to_end") or {}
    return ", ".join(f"{k} {v}" for k, v in ex.items()) or "not run"


ROWS: list[Row] = [
    Row("ingest", "ingest `large` / bare `pandas.read_csv` of the same files", lambda d: d["ratio_ingest_to_read_csv"],
        "×", "≤ 3", lambda v: v <= 3.0),
    Row("ingest", "ingest `large` / bare `pandas.read_csv`, CPU time (read_csv parses on several threads)",
        lambda d: f"{d['ratio_cpu_ingest_to_read_csv']:.2f}× at load {d['machine'].get('load_1min', '?')}", ""),
    Row("ingest", "ingest `large` readings per second", lambda d: d["ingest_readings_per_s"], "/s"),
    Row("map", "kNN batch vs scikit-learn brute force (8,625 RPs × 186 APs, K = 15), CPU time, one thread each",
        lambda d: d["knn"]["one_thread_cpu"]["speedup_batch"], "×", "≥ 3", lambda v: v >= 3.0),
    Row("map", "kNN batch on its two worker threads (their CPU time together) vs scikit-learn on one thread",
        lambda d: d["knn"]["one_thread_cpu"].get("speedup_batch_two_workers", "not run"), "×"),
    Row("map", "kNN one query at a time vs scikit-learn brute force, CPU time, one thread each",
        lambda d: d["knn"]["one_thread_cpu"]["speedup_one_at_a_time"], "×", "≥ 10", lambda v: v >= 10.0),
    Row("map", "kNN batch / one at a time vs scikit-learn, wall clock (swings with the machine's load)",
        lambda d: f"{d['knn']['speedup_batch']:.2f}× / {d['knn']['speedup_one_at_a_time']:.1f}× "
                  f"{_knn_rounds(d)}", ""),
    Row("map", "kNN batch / one at a time vs faiss IndexFlatL2 (exact), wall clock; CPU time, one thread each",
        _knn_faiss, ""),
    Row("map", "kNN neighbour sets differing from float64 brute force other than at exact ties",
        lambda d: d["knn"]["differing_sets_not_ties"], "", "0", lambda v: v == 0),
    Row("map", "export-map `large` (tables, figures, writes)", lambda d: d["export_map"]["total_s"], "s"),
    Row("optimize", "optimize `large` (50,508 poses, 100 walks) total",
        lambda d: _case(d, "large", "robust")["time_s"]["optimize_total"], "s", "≤ 60", lambda v: v <= 60.0),
    Row("optimize", "optimize `large` peak memory", lambda d: _case(d, "large", "robust")["peak_memory_mb"], "MB",
        "≤ 8,000", lambda v: v <= 8000.0),
    Row("month", "`rmbuild optimize` ~500,000 poses (a venue-month of the `year` preset, ~1,000 walks)",
        lambda d: _month_at(d, 500_000, 120, 2), "", "≤ 120 s and ≤ 2 GB",
        lambda v: isinstance(v, str) and v.startswith("ok")),
    Row("month", "`rmbuild optimize` ~2,000,000 poses (the `year` preset: a venue-year, 4,000 walks)",
        lambda d: _month_at(d, 2_000_000, 600, 6), "", "≤ 600 s and ≤ 6 GB",
        lambda v: isinstance(v, str) and v.startswith("ok")),
    Row("month", "optimize scaling 50k / 150k / 500k / 2M poses", _month_scaling),
    Row("month", "growth exponent per phase, 50k -> 2M poses", _month_exponents, "", "≤ 1.15 each",
        lambda v: isinstance(v, str) and v != "not run" and all(float(x.split()[-1]) <= 1.15
                                                                  for x in v.split(", "))),
    Row("optimize", "optimize `large`: linked walks' mean error",
        lambda d: _case(d, "large", "robust")["optimized_linked_walks"]["linked_mean_m"], "m"),
    Row("localizers", "SLAC per scan (P = 60, M = 7, 3,310 RPs)",
        lambda d: d["latency"]["localizers"]["slac"]["ms_per_scan"], "ms", "≤ 20", lambda v: v <= 20.0),
    Row("localizers", "slowest localizer per scan (real-time budget 2 s)",
        lambda d: max(v["ms_per_scan"] for v in d["latency"]["localizers"].values()), "ms", "≤ 2,000",
        lambda v: v <= 2000.0),
    Row("localizers", "SLAC mean error, synthetic other device", lambda d: _loc(d, "synthetic / other device", "slac"),
        "m"),
    Row("localizers", "SLAC mean error, IPIN −2 (A5 map, S7 tests)",
        lambda d: _loc(d, "IPIN -2: A5 map, S7 tests", "slac"), "m"),
    Row("localizers", "kNN mean error, ILC site1/F1 (surveyed map)",
        lambda d: _loc(d, "ILC site1/F1 (surveyed)", "knn"), "m"),
    Row("viz", "rerun recording / optimize time (`large`)", lambda d: d["ratio_view_to_optimize"], "×", "≤ 0.25",
        lambda v: v <= 0.25),
    Row("real", "real floors: walks linked", lambda d: ", ".join(
        f"{f['floor']} {f['linked_pct']:.0f} %" for f in d["floors"])),
    Row("real", "real floors: walks placed right (≤ 8 m of their waypoints) / scored linked walks", lambda d: ", ".join(
        f"{f['floor']} {f['precision']['right']}/{f['precision']['scored']}" for f in d["floors"]
        if f.get("precision"))),
    Row("real", "real floors: kNN median, map built / surveyed", lambda d: ", ".join(
        f"{f['floor']} {f['knn']['ratio']:.2f}×" for f in d["floors"])),
    Row("scale", "`rmbuild build` serial / `local:2` wall time per MS ILC site (outputs equal)", lambda d: ", ".join(
        f"{k} ({len(v['runs']['serial']['floors'])} floors) "
        f"{v['runs']['serial']['wall_s'] / v['runs']['local:2']['wall_s']:.2f}×" for k, v in d["sites"].items()),
        "", "≥ 1.5 for a three-floor site", lambda v: all(float(x.split()[-1].rstrip("×")) >= 1.5
                                                           for x in v.split(", ") if "(3 floors)" in x)),
    Row("incremental", "`ingest --append` then `optimize --incremental` vs a full optimize: per split, linked-walk "
        "landmark m and kNN median m incremental / full, command speed-up (gave up: the full run ran)",
        lambda d: ", ".join(
            f"{k} {r['runs']['incremental']['landmark_linked_m']:.2f} / {r['runs']['full']['landmark_linked_m']:.2f}, "
            f"kNN {r['runs']['incremental']['knn_median_m']:.2f} / {r['runs']['full']['knn_median_m']:.2f}, "
            f"{r['speedup_wall']:.1f}×" + (" (gave up)" if r["runs"]["incremental"]["gave_up"] else "")
            for k, r in d["splits"].items() if "runs" in r),
        "", "within 10 % (0.3 m); ≥ 3× on ILC"),
    Row("bench_pdr", "phone PDR own-fit median error per ILC floor", lambda d: ", ".join(
        f"{k} {v['own_fit_median_m']:.2f}" for k, v in d["ilc"].items()), "m"),
    Row("fuzz", "fuzzed inputs ending otherwise than exit 0 / one-line exit 2", lambda d: d["failures"], "",
        "0", lambda v: v == 0),
]


def _fmt(v: Any, unit: str) -> str:
    if isinstance(v, float):
        v = f"{v:,.3g}" if abs(v) < 100 else f"{v:,.0f}"
    elif isinstance(v, int) and not isinstance(v, bool):
        v = f"{v:,}"
    return f"{v} {unit}".strip() if unit not in ("×",) else f"{v}×"


def summary_lines(results: Path = RESULTS) -> list[str]:
    """Markdown lines of the summary table (one row per :data:`ROWS` entry)."""
    cache: dict[str, dict | None] = {}
    lines = ["| benchmark | figure | value | target | met |", "|---|---|---|---|---|"]
    for r in ROWS:
        if r.source not in cache:
            p = results / f"{r.source}.json"
            cache[r.source] = json.loads(p.read_text()) if p.exists() else None
        data = cache[r.source]
        try:
            value = r.get(data) if data is not None else None
        except (KeyError, StopIteration, TypeError, ValueError):
            value = None
        if value is None:
            shown, met = "not run", ""
        else:
            shown = _fmt(value, r.unit)
            met = "" if r.met is None else ("yes" if r.met(value) else "**no**")
        lines.append(f"| {r.source} | {r.label} | {shown} | {r.target or '—'} | {met} |")
    return lines


def write_summary(results: Path = RESULTS) -> Path:
    """Write SUMMARY.md beside the JSON files; returns its path."""
    lines = ["# Benchmark results", "",
             "Headline figures of `make bench` (`python -m bench.run_all`), read from the JSON files beside this "
             "one, which hold every figure and the machine. Timings are wall-clock on a 2-core machine shared "
             "with other jobs: compare ratios measured in one run (each benchmark says how it repeats them).", ""]
    lines += summary_lines(results)
    lines += ["", "Localizer accuracy per test bed: `localizers.md`; real floors: `real.md` (the current "
              "code; `real_base.md` the baseline of the placement-precision work); the real floors with "
              "fewer Wi-Fi scans: `scan_rate.md`.", ""]
    p = results / "SUMMARY.md"
    p.write_text("\n".join(lines))
    return p


if __name__ == "__main__":
    print(write_summary().read_text())
