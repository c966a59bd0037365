"""Fault injection: kill -9 (or SIGINT) a stage at a random time or at a point of its commit, then check
that the workspace holds the old or the new version of the stage with valid checksums and that the next
run works. ``python -m bench.fuzz.faults --kills 40`` writes bench/results/faults.json; tests/test_faults.py
runs a few of the same."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import psutil

from rmbuild.io.lock import lock_path
from rmbuild.io.workspace import STAGE_DIRS, Workspace

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
COMMANDS = {"ingest": "ingest", "optimize": "optimize", "map": "export-map", "evaluate": "evaluate"}

#: runs the CLI with the commit patched to SIGKILL the process at a chosen point: "seal" (all files
#: written, record not yet), "between" (old directory moved aside, new one not yet in place) or "after"
#: (the new directory in place, the old one not yet deleted)
KILLER = """
import os, signal, sys
import rmbuild.io.workspace as ws
point = sys.argv[1]
real_replace = os.replace
def die():
    os.kill(os.getpid(), signal.SIGKILL)
def replace(src, dst, *a, **k):
    if point == "between" and ".old-" in os.path.basename(str(dst)):
        real_replace(src, dst, *a, **k); die()
    real_replace(src, dst, *a, **k)
    if point == "after" and ".new-" in os.path.basename(str(src)):
        die()
def seal(*a, **k):
    die()
os.replace = replace
if point == "seal":
    ws._seal = seal
from rmbuild.cli import main
main(sys.argv[2:])
"""


def argv(stage: str, root: Path) -> list[str]:
    """The command line that (re)runs ``stage`` on the workspace ``root`` (inputs in ``root``/../in)."""
    if stage == "ingest":
        return ["ingest", str(root.parent / "in"), "-w", str(root), "--force", "-q"]
    return [COMMANDS[stage], "-w", str(root), "--force", "-q"]


def rmbuild(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rmbuild", *args], cwd=REPO, env=ENV, capture_output=True,
                          text=True, **kw)


def make_workspace(root: Path) -> Path:
    """root/in (simulate tiny) and root/ws with every stage run."""
    subprocess.run([sys.executable, "-m", "rmbuild", "simulate", str(root / "in"), "--preset", "tiny", "-q"],
                   check=True, cwd=REPO, env=ENV)
    for stage in STAGE_DIRS:
        subprocess.run([sys.executable, "-m", "rmbuild", *argv(stage, root / "ws")], check=True, cwd=REPO, env=ENV)
    return root / "ws"


def copy_workspace(src: Path, dst_root: Path) -> Path:
    shutil.copytree(src.parent / "in", dst_root / "in")
    shutil.copytree(src, dst_root / "ws")
    return dst_root / "ws"


def records(root: Path) -> dict[str, str | None]:
    return {s: (root / d / "stage.json").read_text() if (root / d / "stage.json").is_file() else None
            for s, d in STAGE_DIRS.items()}


def old_or_new(root: Path, stage: str, before: dict[str, str | None]) -> str:
    """Check the workspace after a fault; returns "old" or "new" (the version of ``stage`` it holds).

    Opening it recovers an interrupted swap; then every stage verifies against its record, no temporary
    directory is left, ``stage`` has a record, and the other stages are untouched (ingest replaces the
    whole workspace: then they are the old ones or gone)."""
    ws = Workspace.open(root)
    left = [p.name for d in (root.parent, root) for p in d.glob(".*") if ".new-" in p.name or ".old-" in p.name]
    assert left == [], left
    after = records(root)
    for s in STAGE_DIRS:
        if after[s] is not None:
            assert ws.verify(s) == [], (s, ws.verify(s))
    assert after[stage] is not None
    if stage != "ingest":
        assert all(after[s] == before[s] for s in STAGE_DIRS if s != stage)
    return "old" if after[stage] == before[stage] else "new"


def kill_at_commit_point(root: Path, stage: str, point: str) -> int:
    p = subprocess.run([sys.executable, "-c", KILLER, point, *argv(stage, root)], cwd=REPO, env=ENV,
                       capture_output=True, text=True)
    return p.returncode


def _default_sigint() -> None:
    """In the child: Ctrl-C's default action (a shell's background job inherits SIGINT ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_and_signal(args: list[str], delay_s: float, sig: int, workspace: Path | None = None
                   ) -> subprocess.CompletedProcess:
    """Run rmbuild and send ``sig`` after ``delay_s``, counted from the moment the command holds the lock
    of ``workspace`` when given (its stage is running), else from the start."""
    proc = subprocess.Popen([sys.executable, "-m", "rmbuild", *args], cwd=REPO, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    if workspace is not None:
        t0 = time.perf_counter()
        while not lock_path(workspace).exists() and proc.poll() is None and time.perf_counter() - t0 < 120:
            time.sleep(0.01)
    time.sleep(delay_s)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


def random_kills(root: Path, stage: str, n: int, rng: np.random.Generator, sig: int = signal.SIGKILL) -> dict:
    """``n`` runs of ``stage`` killed at uniformly random times within a full run's duration; counts of the
    outcomes, and whether the next run works and the lock was released."""
    t0 = time.perf_counter()
    assert rmbuild(argv(stage, root)).returncode == 0
    full = time.perf_counter() - t0
    out: Counter = Counter()
    # SIGKILL: any time from the start; SIGINT: once the stage runs (Ctrl-C while Python still imports
    # rmbuild is Python's own KeyboardInterrupt, before rmbuild has done anything)
    lo, on_lock = (0.2, None) if sig == signal.SIGKILL else (0.0, root)
    for delay in rng.uniform(lo, full * (1.05 if sig == signal.SIGKILL else 0.5), n):
        before = records(root)
        r = run_and_signal(argv(stage, root), float(delay), sig, on_lock)
        # a Ctrl-C while Python finalises (after rmbuild's exit) ends the process by SIGINT: the shell reports
        # 130 for it as for rmbuild's own exit 130
        ok_codes = (0, -signal.SIGKILL) if sig == signal.SIGKILL else (0, 130, -signal.SIGINT)
        out[f"exit {r.returncode}"] += 1
        if r.returncode not in ok_codes:
            out["unexpected exit"] += 1
        try:
            out[old_or_new(root, stage, before)] += 1
        except AssertionError as e:
            out["inconsistent"] += 1
            out[f"inconsistent: {str(e)[:80]}"] += 1
        if lock_path(root).exists() and sig != signal.SIGKILL:
            out["lock left"] += 1
        if "Traceback" in r.stderr:
            out["traceback"] += 1
    out["next run ok"] = int(rmbuild(argv(stage, root)).returncode == 0)
    return {"kills": n, "full_run_s": round(full, 2), **dict(out)}


# ---------------------------------------------------------------------------------------------- build on Dask
#: s; a build must end this soon after one of its workers is killed (or complete)
BUILD_EXIT_BOUND_S = 60.0
#: s; after the command ends, its processes (Dask workers, the resource tracker) must be gone this soon
ORPHAN_GRACE_S = 3.0


def make_building_input(root: Path) -> Path:
    """A simulated building of two tiny floors (rmbuild's schema), for `build` on a local Dask cluster."""
    code = ("import sys; from dataclasses import replace; from pathlib import Path\n"
            "from rmbuild.config.simulate import preset_config\nfrom rmbuild.stages import simulate\n"
            "cfg = preset_config('tiny', 5)\n"
            "cfg = replace(cfg, building=replace(cfg.building, floors=2, floor_change_walks=0))\n"
            "simulate.run(Path(sys.argv[1]), cfg)")
    subprocess.run([sys.executable, "-c", code, str(root / "bin")], check=True, cwd=REPO, env=ENV)
    return root / "bin"


def build_argv(inp: Path, ws: Path, force: bool) -> list[str]:
    return ["build", str(inp), "-w", str(ws), "--scheduler", "local:2", "-q"] + (["--force"] if force else [])


def _workers(proc: psutil.Process) -> list[psutil.Process]:
    """The Dask worker processes under ``proc`` (spawned by its nannies)."""
    out = []
    for c in proc.children(recursive=True):
        try:
            if "spawn_main" in " ".join(c.cmdline()):
                out.append(c)
        except psutil.Error:
            pass
    return out


def build_consistent(ws: Path) -> list[str]:
    """Problems of a building workspace after a fault: a floor stage whose files do not match its record, a
    temporary or backup directory left (after a run that opened it: recovery happens under the lock)."""
    from rmbuild.io.workspace import building_floors

    out = []
    for name, p in (building_floors(ws) or {}).items():
        w = Workspace.open(p)
        for s in STAGE_DIRS:
            if w.record(s) is not None and w.verify(s):
                out.append(f"{name}/{s}: {w.verify(s)[:2]}")
        out += [f"{name}: left {q.name}" for q in p.glob(".*") if ".new-" in q.name or ".old-" in q.name]
    return out


def build_kill(inp: Path, ws: Path, delay_s: float, target: str) -> dict:
    """Run `build --scheduler local:2 --force`, and after ``delay_s`` kill -9 one of its Dask workers
    (``target`` "worker", a random one of those up) or the command itself ("client"). Returns what happened:
    exit code, s from the kill to the exit, the error lines, processes left ``ORPHAN_GRACE_S`` after the exit,
    whether the workspace is consistent, and whether the next `build` (without --force) completes."""
    proc = subprocess.Popen([sys.executable, "-m", "rmbuild", *build_argv(inp, ws, True)], cwd=REPO, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    me = psutil.Process(proc.pid)
    time.sleep(delay_s)
    try:
        family = me.children(recursive=True)
    except psutil.Error:
        family = []
    victim = None
    if proc.poll() is None:
        if target == "client":
            victim = proc.pid
        else:
            workers = _workers(me)
            victim = workers[int(time.monotonic_ns() % len(workers))].pid if workers else None
    t_kill = time.perf_counter()
    if victim is not None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(victim, signal.SIGKILL)
    try:
        out, err = proc.communicate(timeout=BUILD_EXIT_BOUND_S + 90)
        hung = False
    except subprocess.TimeoutExpired:
        hung = True
        for q in [me, *family]:
            with contextlib.suppress(psutil.Error):
                q.kill()
        out, err = proc.communicate()
    exit_s = time.perf_counter() - t_kill
    time.sleep(ORPHAN_GRACE_S)
    left = [q.pid for q in family if q.is_running() and q.status() != psutil.STATUS_ZOMBIE]
    errors = [ln for ln in err.splitlines() if ln.strip()]
    res = {"delay_s": round(delay_s, 2), "target": target if victim is not None else "none (already done)",
           "exit": proc.returncode, "exit_after_kill_s": round(exit_s, 2), "hung": hung, "orphans": len(left),
           "stderr_lines": len(errors), "error": errors[-1][:300] if errors else ""}
    problems = []
    late = victim is not None and exit_s > BUILD_EXIT_BOUND_S
    if hung or late or proc.returncode not in (0, 1, 2, -signal.SIGKILL):
        problems.append("hang or late exit")
    if left:
        problems.append(f"{len(left)} process(es) left")
    if target == "worker" and proc.returncode not in (0, -signal.SIGKILL) and (
            sum(ln.startswith("error: ") for ln in errors) != 1 or not errors[-1].startswith("error: ")):
        problems.append("not one error line")  # (warnings may come before it)
    if "Traceback" in err or "internal error" in err:
        problems.append("internal error")
    nxt = rmbuild(build_argv(inp, ws, not (ws / "build_state.json").is_file()))
    res["next_run_exit"] = nxt.returncode
    if nxt.returncode != 0:
        problems.append(f"next run exit {nxt.returncode}: {nxt.stderr.strip()[-200:]}")
    else:
        bad = build_consistent(ws)
        if bad:
            problems.append(f"inconsistent: {bad[:2]}")
    res["problems"] = problems
    return res


def build_kills(root: Path, n: int, rng: np.random.Generator, target: str = "worker") -> dict:
    """``n`` builds with a worker (or the client) killed at a uniformly random time within a full run."""
    inp = make_building_input(root)
    ws = root / "bws"
    t0 = time.perf_counter()
    full = rmbuild(build_argv(inp, ws, True))
    assert full.returncode == 0, full.stderr
    full_s = time.perf_counter() - t0
    runs = [build_kill(inp, ws, float(d), target) for d in rng.uniform(0.3, full_s, n)]
    exits = [r["exit_after_kill_s"] for r in runs if r["target"] == target]
    return {"kills": n, "full_run_s": round(full_s, 2), "failures": sum(bool(r["problems"]) for r in runs),
            "exit": dict(Counter(str(r["exit"]) for r in runs)),
            "max_exit_after_kill_s": max(exits, default=None), "orphans": sum(r["orphans"] for r in runs),
            "next_run_ok": sum(r["next_run_exit"] == 0 for r in runs), "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.fuzz.faults", description=__doc__)
    ap.add_argument("--kills", type=int, default=40, help="random kills per stage")
    ap.add_argument("--build-kills", type=int, default=20,
                    help="builds on a local Dask cluster with a worker killed at a random time (and as many with "
                         "the command itself killed)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/faults.json"))
    args = ap.parse_args()
    rng = np.random.default_rng(24)
    res: dict = {"random_sigkill": {}, "sigint": {}, "commit_points": {}}
    with tempfile.TemporaryDirectory(prefix="rmbuild-faults-") as tmp:
        base = make_workspace(Path(tmp) / "base")
        for i, stage in enumerate(STAGE_DIRS):
            root = copy_workspace(base, Path(tmp) / f"k{i}")
            res["random_sigkill"][stage] = random_kills(root, stage, args.kills, rng)
            root = copy_workspace(base, Path(tmp) / f"i{i}")
            res["sigint"][stage] = random_kills(root, stage, max(2, args.kills // 4), rng, signal.SIGINT)
            for point in ("seal", "between", "after"):
                root = copy_workspace(base, Path(tmp) / f"c{i}{point}")
                before = records(root)
                code = kill_at_commit_point(root, stage, point)
                try:
                    state = old_or_new(root, stage, before)
                except AssertionError as e:
                    state = f"inconsistent: {e}"
                nxt = rmbuild(argv(stage, root)).returncode
                res["commit_points"][f"{stage}/{point}"] = {"exit": code, "state": state, "next_run_exit": nxt}
            print(stage, res["random_sigkill"][stage], res["sigint"][stage], file=sys.stderr, flush=True)
        for target in ("worker", "client"):
            part = build_kills(Path(tmp) / f"build_{target}", args.build_kills, rng, target)
            res[f"build_{target}_kill"] = part
            print(f"build, {target} killed:", {k: v for k, v in part.items() if k != "runs"}, file=sys.stderr,
                  flush=True)
    bad = sum(v.get("inconsistent", 0) + v.get("unexpected exit", 0) + v.get("traceback", 0) + v.get("lock left", 0)
              + (1 - v["next run ok"])
              for part in ("random_sigkill", "sigint") for v in res[part].values())
    bad += sum(v["state"] not in ("old", "new") or v["next_run_exit"] != 0 for v in res["commit_points"].values())
    bad += sum(res[f"build_{t}_kill"]["failures"] for t in ("worker", "client"))
    res["failures"] = bad
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"faults: {bad} failures -> {args.out}")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
