"""The workspace cannot be corrupted by a kill, a second run or a careless --force; checksums are checked;
file names made from walk ids are safe; outputs a user gave are not overwritten without --force."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild.errors import WorkspaceBusyError, WorkspaceError
from rmbuild.io.lock import lock_path, workspace_lock
from rmbuild.io.workspace import Workspace, walk_file_names

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def optimized(tmp_path_factory) -> Path:
    """A small ingested and optimised workspace (copied by the tests that change it)."""
    root = tmp_path_factory.mktemp("opt")
    inp = write_tables(make_input_tables(n_walks=3, n_steps=40), root / "in")
    from rmbuild.cli import main

    for args in (["ingest", inp, "-w", root / "ws", "-q"], ["optimize", "-w", root / "ws", "-q"]):
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        assert e.value.code == 0
    return root / "ws"


def _copy(ws: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "ws"
    shutil.copytree(ws, dst)
    return dst


# ------------------------------------------------------------------------------------- point 4: commit
def test_a_stage_commits_its_report_and_checksums_with_its_data(optimized: Path, tmp_path: Path) -> None:
    ws = Workspace.open(_copy(optimized, tmp_path))
    rec = ws.record("optimize")
    assert rec is not None and "optimize/report.json" in rec["files"] and "optimize/poses.parquet" in rec["files"]
    assert ws.verify("optimize") == [] and ws.verify("ingest") == []
    assert ws.read_report("optimize")["stage"] == "optimize"
    # nothing about a stage lives outside its directory: replacing the directory replaces all of it
    assert not (ws.root / "reports").exists()
    assert set(json.loads((ws.root / "manifest.json").read_text())) == {"format", "schema_version",
                                                                        "rmbuild_version", "created_utc"}


def test_a_changed_file_is_a_clear_error_naming_it(optimized: Path, tmp_path: Path, capsys) -> None:
    root = _copy(optimized, tmp_path)
    poses = root / "optimize" / "poses.parquet"
    df = pd.read_parquet(poses)
    df.loc[0, "x_m"] += 1.0
    df.to_parquet(poses, index=False)
    assert Workspace.open(root).verify("optimize") == ["optimize/poses.parquet: checksum mismatch"]
    r = run_cli(capsys, "export-map", "-w", root)
    assert r.code == 2 and f"{poses}: checksum mismatch" in r.err and "rmbuild optimize --force" in r.err
    assert not (root / "map").exists()


def test_outputs_of_an_earlier_ingest_are_stale(optimized: Path, tmp_path: Path, capsys) -> None:
    """A stage records the records of what it read: data changed under it is noticed, not used."""
    root = _copy(optimized, tmp_path)
    rec = json.loads((root / "data" / "stage.json").read_text())
    rec["completed_utc"] = "2000-01-01T00:00:00Z"  # as if ingest had been re-run into this directory
    (root / "data" / "stage.json").write_text(json.dumps(rec))
    assert Workspace.open(root).stale_inputs("optimize") == ["ingest"]
    r = run_cli(capsys, "export-map", "-w", root)
    assert r.code == 2 and "optimize ran on an earlier ingest" in r.err


# ------------------------------------------------------------------------------------- point 5: marker
def test_ingest_never_replaces_a_directory_that_is_not_a_workspace(small_input: Path, tmp_path: Path,
                                                                   capsys) -> None:
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text("<h1>mine</h1>")
    (site / "manifest.json").write_text('{"name": "my web app", "start_url": "/"}')
    for extra in ([], ["--force"]):
        r = run_cli(capsys, "ingest", small_input, "-w", site, *extra)
        assert r.code == 2 and "is not an rmbuild workspace" in r.err, r.err
    assert (site / "index.html").read_text() == "<h1>mine</h1>"


def test_inputs_inside_the_workspace_are_refused(small_input: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", small_input, "-w", ws).code == 0
    shutil.copytree(small_input, ws / "sub")
    before = sorted(p.name for p in ws.iterdir())
    r = run_cli(capsys, "ingest", ws / "sub", "-w", ws, "--force")
    assert r.code == 2 and "inside the workspace" in r.err and str(ws / "sub") in r.err
    assert sorted(p.name for p in ws.iterdir()) == before


# ------------------------------------------------------------------------------------- point 6: lock
def test_a_busy_workspace_is_said_so(optimized: Path, tmp_path: Path, capsys) -> None:
    root = _copy(optimized, tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from rmbuild.io.lock import workspace_lock\n"
         "with workspace_lock(sys.argv[1], 'optimize'):\n    print('held', flush=True); time.sleep(60)", str(root)],
        stdout=subprocess.PIPE, text=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert holder.stdout.readline().strip() == "held"
        for args in (["optimize", "-w", root, "--force"], ["export-map", "-w", root], ["view", "-w", root,
                                                                                      "--save", tmp_path / "v.rrd"]):
            r = run_cli(capsys, *args)
            assert r.code == 75, (args, r.err)
            assert f"workspace {root.resolve()} is busy" in r.err and f"pid {holder.pid}" in r.err
            assert "rmbuild optimize" in r.err and len(r.err.strip().splitlines()) == 1
        r = run_cli(capsys, "ingest", tmp_path / "nothing", "-w", root, "--force")
        assert r.code == 2  # bad input is said first; the lock is not even taken
    finally:
        holder.kill()
        holder.wait()
    assert not (root / "map").exists()
    # the kernel released the dead holder's lock: its file is stale and the next command takes it
    assert lock_path(root).exists()
    assert run_cli(capsys, "export-map", "-w", root, "-q").code == 0
    assert not lock_path(root).exists()


def test_lock_is_reentrant_and_exclusive_within_a_process(tmp_path: Path) -> None:
    root = tmp_path / "ws"
    root.mkdir()
    with workspace_lock(root, "optimize"):
        with workspace_lock(root, "optimize"):
            assert lock_path(root).exists()
        assert json.loads(lock_path(root).read_text())["command"] == "optimize"
    assert not lock_path(root).exists()
    with workspace_lock(root, "view", exclusive=False), pytest.raises(RuntimeError):
        with workspace_lock(root, "optimize"):
            pass
    assert issubclass(WorkspaceBusyError, WorkspaceError)


def test_a_second_command_keeps_the_first_ones_temporary_directory(optimized: Path, tmp_path: Path) -> None:
    """Recovery (which deletes temporary directories) happens only under the exclusive lock."""
    root = _copy(optimized, tmp_path)
    tmp = root / ".map.new-inflight"
    with workspace_lock(root, "export-map"):
        tmp.mkdir()
        child = subprocess.run([sys.executable, "-m", "rmbuild", "view", "-w", str(root), "--save",
                                str(tmp_path / "v.rrd")], capture_output=True, text=True, cwd=REPO,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
        assert child.returncode == 75 and tmp.is_dir()
        from rmbuild.io.workspace import Workspace as W

        W.open(root)  # an in-process open under the lock recovers: the stale directory goes
        assert not tmp.exists()


# ------------------------------------------------------------------------------------- point 8: ids
def test_file_names_from_walk_ids_are_unique_bounded_and_safe() -> None:
    ids = ["a/b", "a_b", "A_B", "x" * 300, ".hidden", "..", "NA", "00001", "con", "w1", "Ünï", ""]
    names = walk_file_names(ids)
    assert len(set(n.casefold() for n in names.values())) == len(ids)
    for wid, n in names.items():
        assert 1 <= len(n) <= 64 and not n.startswith(".") and all(c.isascii() for c in n), (wid, n)
        assert all(c.isalnum() or c in "-_." for c in n), n
    assert names["w1"] == "w1" and names["NA"] == "NA" and names["00001"] == "00001"  # plain ids keep their name
    assert names["a_b"] != names["a/b"] and names["con"] != "con"
    assert walk_file_names(ids) == names  # deterministic


def test_walk_ids_stay_strings_and_each_gets_its_own_file(tmp_path: Path, capsys) -> None:
    tables = make_input_tables(n_walks=4, n_steps=30)
    rename = {"walk0": "a/b", "walk1": "a_b", "walk2": "00001", "walk3": "NA"}
    for df in tables.values():
        df["walk_id"] = df["walk_id"].map(rename)
    inp = write_tables(tables, tmp_path / "in")
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", inp, "-w", ws, "-q").code == 0
    w = Workspace.open(ws)
    assert sorted(w.read_dataset().walks["walk_id"]) == sorted(rename.values())
    assert run_cli(capsys, "optimize", "-w", ws, "-q").code == 0
    index = pd.read_csv(ws / "optimize" / "tum" / "walks.csv", dtype=str, keep_default_na=False)
    assert sorted(index["walk_id"]) == sorted(rename.values())
    files = sorted(p.name for p in (ws / "optimize" / "tum").glob("*.txt"))
    assert len(files) == 4 and sorted(index["file"]) == files
    n_poses = {wid: int((w.read_dataset().poses["walk_id"] == wid).sum()) for wid in rename.values()}
    for wid, f in zip(index["walk_id"], index["file"]):
        assert len((ws / "optimize" / "tum" / f).read_text().splitlines()) == n_poses[wid]


# ------------------------------------------------------------------------------------- point 11: --force
def test_report_and_recordings_are_not_overwritten_without_force(optimized: Path, tmp_path: Path,
                                                                 capsys) -> None:
    root = _copy(optimized, tmp_path)
    mine = tmp_path / "mine.html"
    mine.write_text("my notes")
    r = run_cli(capsys, "report", "-w", root, "--out", mine)
    assert r.code == 2 and "--force" in r.err and mine.read_text() == "my notes"
    assert run_cli(capsys, "report", "-w", root, "--out", mine, "--force", "-q").code == 0
    assert mine.read_text().startswith("<!DOCTYPE html>") and (tmp_path / "mine_figures" / "walks.png").is_file()
    assert run_cli(capsys, "report", "-w", root, "-q").code == 0  # --out wrote nothing into the workspace
    r = run_cli(capsys, "report", "-w", root)
    assert r.code == 2 and "report.html already exists" in r.err
    (root / "report.html").unlink()
    r = run_cli(capsys, "report", "-w", root)  # the figures of the last report are in WORKSPACE/report/
    assert r.code == 2 and "already holds report figures" in r.err
    assert run_cli(capsys, "report", "-w", root, "-q", "--force").code == 0
    rrd = tmp_path / "mine.rrd"
    rrd.write_bytes(b"precious")
    r = run_cli(capsys, "view", "-w", root, "--save", rrd)
    assert r.code == 2 and rrd.read_bytes() == b"precious"
    r = run_cli(capsys, "export-map", "-w", root, "--rerun", rrd)
    assert r.code == 2 and rrd.read_bytes() == b"precious" and not (root / "map").exists()
    assert run_cli(capsys, "view", "-w", root, "--save", rrd, "--force", "-q").code == 0
    assert rrd.read_bytes() != b"precious"


def test_every_file_gets_the_mode_of_a_new_file(optimized: Path) -> None:
    """Atomic writes go through mkstemp (0600); the files they leave follow the umask like any new file."""
    import os
    import stat

    mask = os.umask(0)
    os.umask(mask)
    modes = {p.relative_to(optimized).as_posix(): stat.S_IMODE(p.stat().st_mode)
             for p in optimized.rglob("*") if p.is_file()}
    assert "manifest.json" in modes and any(k.endswith("report.json") for k in modes)
    assert {k: oct(m) for k, m in modes.items() if m != 0o666 & ~mask} == {}


def test_workspace_file_names_live_in_one_module() -> None:
    """Paths into a workspace are built only by rmbuild/io/workspace.py (simulate writes input files)."""
    import re

    from rmbuild.io.workspace import ARTEFACTS, STAGE_DIRS

    names = {Path(rel).name for rel in ARTEFACTS.values()} | set(STAGE_DIRS.values()) | {
        "stage.json", "manifest.json", "reports", "config.toml", "report.json"}
    pattern = re.compile(r'/\s*f?"(' + "|".join(map(re.escape, sorted(names))) + r')"')
    pkg = REPO / "rmbuild"
    skip = {pkg / "io" / "workspace.py", pkg / "stages" / "simulate.py"}
    offenders = [f"{p.relative_to(REPO)}:{i}: {line.strip()}" for p in sorted(pkg.rglob("*.py")) if p not in skip
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert offenders == [], offenders
