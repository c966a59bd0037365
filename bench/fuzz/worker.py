"""The fuzz worker: runs cases in-process under a memory cap and reports one JSON line per case.

Protocol: the parent writes ``{"kind", "seed", "light"}`` lines on stdin; the worker answers each with a result
line on its original stdout (the CLI's own output is captured). Start:
``python -m bench.fuzz.worker BASE_DIR WORK_DIR MEM_CAP_MB TIMEOUT_S``.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import resource
import shutil
import signal
import sys
import time
from pathlib import Path

#: MB; the most a case may take (resident set, the worker's imports included)
PEAK_LIMIT_MB = 1024


class CaseTimeout(BaseException):
    """Raised by the alarm; a BaseException so that the CLI's catch-all does not turn it into exit 1."""


def _alarm(signum: int, frame: object) -> None:
    raise CaseTimeout()


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def _reset_peak() -> None:
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")


def _digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        h.update(str(p.relative_to(root)).encode())
        if p.is_file() and not p.is_symlink():
            h.update(p.read_bytes())
    return h.hexdigest()


def _leftovers(root: Path) -> list[str]:
    """Temporary directories, backups or lock files a command left behind."""
    return sorted(str(p.relative_to(root)) for p in root.rglob(".*")
                  if any(m in p.name for m in (".new-", ".old-", ".lock", ".part")))


def run_one(kind: str, seed: int, base: Path, work: Path, timeout_s: float, light: bool = False) -> dict:
    from bench.fuzz.cases import make_case
    from rmbuild.cli import main

    root = work / f"{kind}-{seed}"
    shutil.rmtree(root, ignore_errors=True)
    case = make_case(kind, seed, base, root, light)
    before = _digest(case.unchanged) if case.unchanged is not None else None
    victims = {v: _file_digest(v) for v in case.victims}
    out, err = io.StringIO(), io.StringIO()
    rss_before = _status_kb("VmRSS") / 1024
    _reset_peak()
    t0 = time.perf_counter()
    code: int | str = 0
    first_code: int | str | None = None
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        for argv in [case.argv, *case.then]:  # a chain goes on while its commands succeed
            code = _run_cli(main, argv, out, err)
            first_code = code if first_code is None else first_code
            if code != 0:
                break
    except CaseTimeout:
        code = "timeout"
    except MemoryError:
        code = "memory"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    elapsed = time.perf_counter() - t0
    result = {"kind": kind, "seed": seed, "argv": case.argv, "mutations": case.description, "code": code,
              "first_code": first_code, "stderr": err.getvalue(), "time_s": round(elapsed, 3),
              "peak_rss_mb": round(_status_kb("VmHWM") / 1024, 1), "rss_before_mb": round(rss_before, 1)}
    result["problems"] = problems(case, result, before)
    changed = [str(v) for v, d in victims.items() if _file_digest(v) != d]
    if changed:
        result["problems"].append(f"wrote through a link: {changed[:2]}")
    result["stderr"] = result["stderr"][-3000:]
    shutil.rmtree(root, ignore_errors=True)
    return result


def _run_cli(main, argv: list[str], out: io.StringIO, err: io.StringIO) -> int:
    """One command of a case: its exit code (the CLI's SystemExit)."""
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main(argv)
        return 0
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else 1


def _file_digest(p: Path) -> str | None:
    try:
        return hashlib.sha256(p.read_bytes()).hexdigest()
    except OSError:
        return None


def problems(case: object, r: dict, before: str | None) -> list[str]:
    """What is wrong with a case's outcome (empty: a clean outcome)."""
    out: list[str] = []
    code, err = r["code"], r["stderr"]
    if code not in (0, 2):
        out.append(f"exit {code}")
    if "Traceback" in err:
        out.append("traceback")
    if "internal error" in err:
        out.append("internal error")
    if code == 2:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.startswith("error: ")]
        if len(errors) != 1 or errors[0] != lines[-1]:
            out.append("not one error line")
        elif str(case.root) not in errors[0] and "command-line option" not in errors[0]:  # type: ignore[attr-defined]
            out.append("error names no file of the case")
    if code != 0:
        # a chain's later command may fail after its first one created the workspace
        if case.creates is not None and case.creates.exists() and r.get("first_code", code) != 0:  # type: ignore[attr-defined]
            out.append("failed but wrote its output")
        if before is not None and _digest(case.unchanged) != before:  # type: ignore[attr-defined]
            out.append("failed but changed the workspace")
    if r["peak_rss_mb"] is not None and r["peak_rss_mb"] > PEAK_LIMIT_MB:
        out.append(f"peak memory {r['peak_rss_mb']:.0f} MB")
    planted = {str(p.relative_to(case.root)) for p in case.planted}  # type: ignore[attr-defined]
    left = [p for p in _leftovers(case.root) if p not in planted]  # type: ignore[attr-defined]
    if left:
        out.append(f"left {left[:3]}")
    return out


def main() -> None:
    base, work = Path(sys.argv[1]), Path(sys.argv[2])
    cap_mb, timeout_s = float(sys.argv[3]), float(sys.argv[4])
    import bench.fuzz.cases  # noqa: F401  (imports before the cap: they are not the case's memory)
    import rmbuild.cli.ingest  # noqa: F401
    import rmbuild.stages.optimize  # noqa: F401

    signal.signal(signal.SIGALRM, _alarm)
    proto = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1)
    for line in sys.stdin:
        req = json.loads(line)
        # the cap counts from the worker's size now: what earlier cases left mapped is not this case's
        cap = int(_status_kb("VmSize") * 1024 + cap_mb * 2**20)
        resource.setrlimit(resource.RLIMIT_AS, (cap, resource.RLIM_INFINITY))
        try:
            res = run_one(req["kind"], int(req["seed"]), base, work, timeout_s, bool(req.get("light")))
        except MemoryError:
            res = {"kind": req["kind"], "seed": req["seed"], "code": "memory", "problems": ["memory cap"],
                   "stderr": "", "time_s": None, "peak_rss_mb": None}
        except Exception as e:  # a defect of the case generator, not of rmbuild: reported as such
            res = {"kind": req["kind"], "seed": req["seed"], "code": "generator", "stderr": repr(e)[:500],
                   "problems": [f"case generator: {type(e).__name__}"], "time_s": None, "peak_rss_mb": None}
        proto.write(json.dumps(res) + "\n")


if __name__ == "__main__":
    main()
