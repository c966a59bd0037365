"""Fault injection: kill -9 at random points of each stage and right around its commit, SIGINT, two
concurrent runs. After each, the workspace holds the old or the new version of the stage with valid
checksums, and the next run works."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rmbuild.io.lock import lock_path
from rmbuild.io.workspace import STAGE_DIRS, Workspace

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
#: each stage's command (ingest is given its input and the workspace by the helper)
COMMANDS = {"ingest": "ingest", "optimize": "optimize", "map": "export-map", "evaluate": "evaluate"}

#: runs the CLI with os.replace patched to SIGKILL the process at a chosen point of a stage's commit:
#: "seal" (all files written, record not yet), "between" (old directory moved aside, new one not yet in
#: place) or "after" (the new directory in place, the old one not yet deleted)
KILLER = """
import os, signal, sys
import rmbuild.io.workspace as ws
point = sys.argv[1]
real_replace, real_seal = os.replace, ws._seal
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


def _argv(stage: str, root: Path) -> list[str]:
    if stage == "ingest":
        return ["ingest", str(root.parent / "in"), "-w", str(root), "--force", "-q"]
    return [COMMANDS[stage], "-w", str(root), "--force", "-q"]


@pytest.fixture(scope="module")
def full_ws(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("faults")
    subprocess.run([sys.executable, "-m", "rmbuild", "simulate", str(root / "in"), "--preset", "tiny", "-q"],
                   check=True, cwd=REPO, env=ENV)
    for stage in ("ingest", "optimize", "map", "evaluate"):
        args = _argv(stage, root / "ws")
        subprocess.run([sys.executable, "-m", "rmbuild", *args], check=True, cwd=REPO, env=ENV)
    return root / "ws"


def _fresh(full_ws: Path, tmp_path: Path) -> Path:
    shutil.copytree(full_ws.parent / "in", tmp_path / "in")
    shutil.copytree(full_ws, tmp_path / "ws")
    return tmp_path / "ws"


def _records(root: Path) -> dict[str, str | None]:
    return {s: (root / d / "stage.json").read_text() if (root / d / "stage.json").is_file() else None
            for s, d in STAGE_DIRS.items()}


def _assert_old_or_new(root: Path, stage: str, before: dict[str, str | None]) -> str:
    """Every stage verifies against its record; ``stage`` is the old version or a new one; the others are
    untouched (ingest replaces the whole workspace: then they are the old ones or gone). Returns "old"/"new"."""
    ws = Workspace.open(root)  # recovers an interrupted swap (nobody holds the lock)
    leftovers = [p.name for d in (root.parent, root) for p in d.glob(".*") if ".new-" in p.name or ".old-" in p.name]
    assert leftovers == [], leftovers
    after = _records(root)
    for s in STAGE_DIRS:
        if after[s] is not None:
            assert ws.verify(s) == [], (s, ws.verify(s))
    assert after[stage] is not None
    for s in STAGE_DIRS:
        if s != stage and stage != "ingest":
            assert after[s] == before[s], s
    return "old" if after[stage] == before[stage] else "new"


@pytest.mark.parametrize("stage, point", [("optimize", "seal"), ("optimize", "between"), ("optimize", "after"),
                                          ("ingest", "between"), ("ingest", "after"), ("map", "after")])
def test_kill_around_the_commit(stage: str, point: str, full_ws: Path, tmp_path: Path) -> None:
    root = _fresh(full_ws, tmp_path)
    before = _records(root)
    p = subprocess.run([sys.executable, "-c", KILLER, point, *_argv(stage, root)], cwd=REPO, env=ENV,
                       capture_output=True, text=True)
    assert p.returncode == -signal.SIGKILL, p.stderr
    state = _assert_old_or_new(root, stage, before)
    assert state == ("new" if point == "after" else "old")
    # the next run works and leaves a consistent workspace
    p = subprocess.run([sys.executable, "-m", "rmbuild", *_argv(stage, root)], cwd=REPO, env=ENV,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert _assert_old_or_new(root, stage, _records(root)) == "old"
    assert not lock_path(root).exists()


def _run_and_signal(argv: list[str], delay_s: float, sig: int) -> subprocess.CompletedProcess:
    proc = subprocess.Popen([sys.executable, "-m", "rmbuild", *argv], cwd=REPO, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(delay_s)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


@pytest.mark.parametrize("stage", ["optimize", "evaluate"])
def test_kill_at_random_times(stage: str, full_ws: Path, tmp_path: Path) -> None:
    """kill -9 anywhere in a run (startup, reading, solving, writing, committing); `make fuzz` runs more."""
    rng = np.random.default_rng(24 + len(stage))
    root = _fresh(full_ws, tmp_path)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rmbuild", *_argv(stage, root)], check=True, cwd=REPO, env=ENV)
    full = time.perf_counter() - t0
    states = []
    for delay in np.sort(rng.uniform(0.3, full, 2)):
        before = _records(root)
        r = _run_and_signal(_argv(stage, root), float(delay), signal.SIGKILL)
        assert r.returncode in (0, -signal.SIGKILL), r.stderr
        states.append(_assert_old_or_new(root, stage, before))
    assert set(states) <= {"old", "new"}
    assert subprocess.run([sys.executable, "-m", "rmbuild", *_argv(stage, root)], cwd=REPO, env=ENV).returncode == 0


def test_sigint_keeps_the_old_stage_and_releases_the_lock(full_ws: Path, tmp_path: Path) -> None:
    root = _fresh(full_ws, tmp_path)
    before = _records(root)
    r = _run_and_signal(_argv("optimize", root), 1.6, signal.SIGINT)
    assert r.returncode in (0, 130), r.stderr
    if r.returncode == 130:
        assert r.stderr.strip().splitlines()[-1] == "interrupted; no partial outputs were kept"
        assert _assert_old_or_new(root, "optimize", before) == "old"
    assert not lock_path(root).exists()


def test_two_concurrent_runs(full_ws: Path, tmp_path: Path) -> None:
    """Two optimize runs at once: one runs, the other is told the workspace is busy; nothing is mixed."""
    root = _fresh(full_ws, tmp_path)
    before = _records(root)
    procs = [subprocess.Popen([sys.executable, "-m", "rmbuild", *_argv("optimize", root)], cwd=REPO, env=ENV,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in results)
    assert codes in ([0, 0], [0, 75]), results
    if codes == [0, 75]:
        busy = next(e for c, e in results if c == 75)
        assert "is busy" in busy and "rmbuild optimize" in busy
    assert _assert_old_or_new(root, "optimize", before) == "new"
    # two ingests creating one new workspace
    fresh = tmp_path / "ws2"
    procs = [subprocess.Popen([sys.executable, "-m", "rmbuild", "ingest", str(tmp_path / "in"), "-w", str(fresh),
                               "-q"], cwd=REPO, env=ENV, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    codes = sorted(p.wait(timeout=120) for p in procs)
    assert codes in ([0, 2], [0, 75]), codes  # 2: the second found the workspace made (no --force)
    assert Workspace.open(fresh).verify("ingest") == []
