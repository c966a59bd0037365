"""The fuzz parent: makes the bases, feeds cases to worker processes, restarts a worker that dies, and
summarises (``python -m bench.fuzz``)."""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from bench.fuzz.cases import kind_of, make_bases

REPO = Path(__file__).resolve().parents[2]
#: MB the worker may allocate beyond its state after imports (RLIMIT_AS): a blow-up fails the case
MEM_CAP_MB = 1536
#: s; a case taking longer fails
TIMEOUT_S = 60.0
#: cases a worker runs before it is replaced (a long-lived process keeps memory it has freed; the peak
#: of a case is measured from a worker of about its start-up size)
CASES_PER_WORKER = 100


@dataclass
class _Worker:
    proc: subprocess.Popen
    case: tuple[str, int] | None = None
    started: float = 0.0
    done: int = 0


def _spawn(base: Path, work: Path) -> subprocess.Popen:
    env = dict(os.environ, MPLBACKEND="Agg", MALLOC_ARENA_MAX="2", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, "-m", "bench.fuzz.worker", str(base), str(work), str(MEM_CAP_MB),
                             str(TIMEOUT_S)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, bufsize=1, cwd=REPO, env=env)


def run_cases(cases: list[tuple[str, int]], jobs: int = 1, work: Path | None = None,
              progress: bool = False, light: bool = False) -> list[dict]:
    """Run ``cases`` ((kind, seed) pairs) in ``jobs`` workers; one result dict per case, in order.
    ``light``: config cases only load the file (see :func:`bench.fuzz.cases.make_case`)."""
    with tempfile.TemporaryDirectory(prefix="rmbuild-fuzz-", dir=work) as tmp:
        base = make_bases(Path(tmp) / "base")
        results: dict[tuple[str, int], dict] = {}
        todo = list(cases)
        sel = selectors.DefaultSelector()
        workers = [_Worker(_spawn(base, Path(tmp))) for _ in range(max(1, jobs))]
        for w in workers:
            sel.register(w.proc.stdout, selectors.EVENT_READ, w)  # type: ignore[arg-type]
        t_start = time.perf_counter()
        shown = 0
        while len(results) < len(cases):
            for w in workers:
                if w.case is None and todo:
                    w.case, w.started = todo.pop(0), time.perf_counter()
                    req = {"kind": w.case[0], "seed": w.case[1], "light": light}
                    w.proc.stdin.write(json.dumps(req) + "\n")  # type: ignore[union-attr]
            for key, _ in sel.select(timeout=1.0):
                w = key.data
                line = w.proc.stdout.readline()
                if line:
                    r = json.loads(line)
                    results[(r["kind"], r["seed"])] = r
                    w.case = None
                    w.done += 1
                    if w.done >= CASES_PER_WORKER and todo:
                        w.proc.stdin.close()  # type: ignore[union-attr]
                        _replace(w, sel, base, Path(tmp), results, "")
                else:  # the worker died (killed by the kernel, a crash in native code)
                    _replace(w, sel, base, Path(tmp), results, "worker died")
            for w in workers:
                if w.case is not None and time.perf_counter() - w.started > TIMEOUT_S + 30:
                    w.proc.kill()
                    _replace(w, sel, base, Path(tmp), results, "hung")
            if progress and len(results) >= shown + 100:
                shown = len(results)
                bad = sum(bool(r["problems"]) for r in results.values())
                print(f"{shown}/{len(cases)} cases, {bad} failures, {time.perf_counter() - t_start:.0f} s",
                      file=sys.stderr, flush=True)
        for w in workers:
            w.proc.stdin.close()  # type: ignore[union-attr]
            w.proc.wait(timeout=30)
        return [results[c] for c in cases]


def _replace(w: _Worker, sel: selectors.BaseSelector, base: Path, work: Path, results: dict, why: str) -> None:
    sel.unregister(w.proc.stdout)  # type: ignore[arg-type]
    w.proc.wait()
    w.done = 0
    if w.case is not None:
        results[w.case] = {"kind": w.case[0], "seed": w.case[1], "code": why, "problems": [why],
                           "stderr": "", "time_s": None, "peak_rss_mb": None}
        w.case = None
    w.proc = _spawn(base, work)
    sel.register(w.proc.stdout, selectors.EVENT_READ, w)  # type: ignore[arg-type]


def plan(n: int, seed: int = 0) -> list[tuple[str, int]]:
    """``n`` cases of a run: case i has the kind drawn for it and seed ``seed * 1_000_000 + i``."""
    return [(kind_of(i, seed), seed * 1_000_000 + i) for i in range(n)]


def summarise(results: list[dict]) -> dict:
    """Counts per kind: cases, exit 0 / 2, failures by problem, peak memory and time."""
    out: dict = {"cases": len(results), "failures": sum(bool(r["problems"]) for r in results), "kinds": {}}
    for kind in sorted({r["kind"] for r in results}):
        rs = [r for r in results if r["kind"] == kind]
        rss = [r["peak_rss_mb"] for r in rs if r.get("peak_rss_mb") is not None]
        ts = [r["time_s"] for r in rs if r.get("time_s") is not None]
        out["kinds"][kind] = {
            "cases": len(rs), "exit_0": sum(r["code"] == 0 for r in rs), "exit_2": sum(r["code"] == 2 for r in rs),
            "failures": sum(bool(r["problems"]) for r in rs),
            "problems": dict(Counter(p.split(" [")[0] for r in rs for p in r["problems"])),
            "peak_rss_mb_max": max(rss, default=None), "time_s_max": max(ts, default=None),
            "time_s_mean": round(sum(ts) / len(ts), 3) if ts else None,
        }
    rss_all = [r["peak_rss_mb"] for r in results if r.get("peak_rss_mb") is not None]
    out["peak_rss_mb_max"] = max(rss_all, default=None)
    out["failed_cases"] = [{k: r.get(k) for k in ("kind", "seed", "code", "problems", "mutations", "argv")}
                           | {"stderr_last_line": (r.get("stderr") or "").strip().splitlines()[-1:]}
                           for r in results if r["problems"]]
    return out
