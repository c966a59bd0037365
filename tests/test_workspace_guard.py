"""The workspace's guards of issue 40: one lock covers a building and its floors; a planted symbolic link is
never written through; no output lands inside a workspace's own directories; `build` never replaces what
was made by hand without --force; a config file is checked whole."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from cli_util import run_cli

REPO = Path(__file__).resolve().parents[1]
HOLD = ("import sys, time; from rmbuild.io.lock import workspace_lock\n"
        "with workspace_lock(sys.argv[1], sys.argv[2], sys.argv[3] == 'x'):\n"
        "    print('held', flush=True); time.sleep(60)")


@pytest.fixture(scope="module")
def two_floors(tmp_path_factory) -> Path:
    """The input of a simulated building of two tiny floors."""
    from rmbuild.config.simulate import preset_config
    from rmbuild.stages import simulate

    base = tmp_path_factory.mktemp("bldg")
    cfg = preset_config("tiny", 5)
    cfg = replace(cfg, building=replace(cfg.building, floors=2, floor_change_walks=0))
    simulate.run(base / "in", cfg)
    return base / "in"


@pytest.fixture
def building(two_floors: Path, tmp_path: Path, capsys) -> Path:
    ws = tmp_path / "B"
    assert run_cli(capsys, "ingest", two_floors, "-w", ws, "-q").code == 0
    assert (ws / "floors" / "F1" / "manifest.json").is_file()
    return ws


class Holder:
    """Another process holding a workspace's lock (``exclusive``) until stopped."""

    def __init__(self, root: Path, command: str, exclusive: bool = True) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", HOLD, str(root), command, "x" if exclusive else "s"],
                                     stdout=subprocess.PIPE, text=True, cwd=REPO,
                                     env={**os.environ, "PYTHONPATH": str(REPO)})
        assert self.proc.stdout is not None and self.proc.stdout.readline().strip() == "held"

    def __enter__(self) -> Holder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.proc.kill()
        self.proc.wait()


# ------------------------------------------------------------------------------ one lock per building
def test_a_floor_at_work_blocks_rewriting_its_building(building: Path, two_floors: Path, capsys) -> None:
    """`ingest --force` of a building succeeded while a floor's lock was held (issue 40)."""
    with Holder(building / "floors" / "F1", "optimize"):
        r = run_cli(capsys, "ingest", two_floors, "-w", building, "--force", "-q")
        assert r.code == 75 and f"workspace {building.resolve()} is busy" in r.err, r.err
        assert len(r.err.strip().splitlines()) == 1
        r = run_cli(capsys, "optimize", "-w", building, "-q")  # every floor: the building exclusively
        assert r.code == 75, r.err
        # another floor is free: commands on different floors run side by side
        r = run_cli(capsys, "optimize", "-w", building / "floors" / "F2", "-q")
        assert r.code == 0, r.err
        r = run_cli(capsys, "optimize", "-w", building / "floors" / "F1", "-q")
        assert r.code == 75 and "holds it" in r.err, r.err
    assert run_cli(capsys, "ingest", two_floors, "-w", building, "--force", "-q").code == 0
    assert not list(building.parent.glob(".*.lock")) and not list((building / "floors").glob(".*.lock"))


def test_a_building_at_work_blocks_its_floors(building: Path, two_floors: Path, capsys) -> None:
    """A floor's `optimize` and `ingest --append` succeeded while the building was locked (issue 40)."""
    floor = building / "floors" / "F1"
    with Holder(building, "ingest"):
        for args in (["optimize", "-w", floor, "-q"], ["ingest", two_floors, "-w", floor, "--append", "-q"],
                     ["view", "-w", floor, "--save", building.parent / "v.rrd", "-q"]):
            r = run_cli(capsys, *args)
            assert r.code == 75, (args, r.err)
            assert f"workspace {building.resolve()} is busy" in r.err and "rmbuild ingest" in r.err, r.err
    assert not (floor / "optimize").exists()
    assert run_cli(capsys, "optimize", "-w", floor, "-q").code == 0


# ------------------------------------------------------------------------------ planted symbolic links
@pytest.fixture
def single(tmp_path: Path, capsys) -> Path:
    from conftest import make_input_tables, write_tables

    folder = write_tables(make_input_tables(n_walks=3, n_steps=40), tmp_path / "in")
    ws = tmp_path / "ws"
    assert run_cli(capsys, "ingest", folder, "-w", ws, "-q").code == 0
    assert run_cli(capsys, "optimize", "-w", ws, "-q").code == 0
    return ws


def _dot_files(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.startswith("."))


def test_a_lock_file_planted_as_a_link_is_never_written_through(single: Path, tmp_path: Path, capsys) -> None:
    """`ln -s victim ws/.ws.lock; rmbuild optimize -w ws --force` overwrote the victim (issue 40)."""
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / ".ws.lock").symlink_to(victim)
    for args in (["optimize", "-w", single, "--force", "-q"], ["report", "-w", single, "-q"]):
        r = run_cli(capsys, *args)
        assert r.code == 2 and ".ws.lock: the workspace lock is a symbolic link" in r.err, r.err
        assert len(r.err.strip().splitlines()) == 1
    assert victim.read_text() == "precious"


def test_a_stage_directory_planted_as_a_link_is_refused_and_leaves_nothing(single: Path, tmp_path: Path,
                                                                            capsys) -> None:
    """A symlinked stage directory left `.map.old-PID` behind (issue 40)."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "mine.txt").write_text("mine")
    (single / "map").symlink_to(elsewhere, target_is_directory=True)
    r = run_cli(capsys, "export-map", "-w", single, "--force", "-q")
    assert r.code == 2 and f"{single / 'map'} is a symbolic link: rmbuild never writes through one" in r.err, r.err
    assert sorted(p.name for p in elsewhere.iterdir()) == ["mine.txt"]
    assert _dot_files(single) == [] and _dot_files(tmp_path) == []
    # planted "backups" are not put in place either
    (single / "map").unlink()
    (single / ".map.old-1").symlink_to(elsewhere, target_is_directory=True)
    assert run_cli(capsys, "export-map", "-w", single, "-q").code == 0
    assert not (single / "map").is_symlink() and (single / "map" / "stage.json").is_file()
    assert _dot_files(single) == [] and (elsewhere / "mine.txt").is_file()


def test_a_workspace_reached_through_a_link_is_replaced_where_it_lives(single: Path, tmp_path: Path,
                                                                        capsys) -> None:
    """`ingest --force -w LINK` left `.LINK.old-PID` behind and replaced the link by a new directory."""
    link = tmp_path / "linkws"
    link.symlink_to(single, target_is_directory=True)
    r = run_cli(capsys, "ingest", tmp_path / "in", "-w", link, "--force", "-q")
    assert r.code == 0, r.err
    assert link.is_symlink() and (single / "data" / "stage.json").is_file() and not (single / "optimize").exists()
    assert _dot_files(tmp_path) == []


def test_outputs_never_land_among_a_workspace_s_files(single: Path, tmp_path: Path, capsys) -> None:
    """`localize -o ws/map/radiomap.parquet --force` and `report --out ws/optimize/report.json --force`
    overwrote the workspace's own files (issue 40)."""
    from conftest import make_input_tables, write_tables

    assert run_cli(capsys, "export-map", "-w", single, "-q").code == 0
    q = write_tables({"wifi": make_input_tables()["wifi"]}, tmp_path / "q")
    before = {p: p.read_bytes() for p in single.rglob("*") if p.is_file()}
    for args in (["localize", q, "-w", single, "-o", single / "map" / "radiomap.parquet", "--force"],
                 ["localize", q, "-w", single, "-o", single / "data" / "new.csv"],
                 ["report", "-w", single, "--out", single / "optimize" / "report.json", "--force"],
                 ["view", "-w", single, "--save", single / "evaluate.rrd" / ".." / "manifest.json", "--force"],
                 ["localize", q, "-w", single, "-o", tmp_path / ".ws.lock.csv", "--force"]):
        r = run_cli(capsys, *args, "-q")
        if args[-1] == "--force" and str(args[-2]).endswith(".lock.csv"):
            assert r.code == 0, r.err  # not a lock file: a name like any other
            continue
        assert r.code == 2 and f"lies among the files of workspace {single}" in r.err, (args, r.err)
    # a report's figures go beside its page: never through a link planted there
    (tmp_path / "r_figures").symlink_to(single / "map", target_is_directory=True)
    r = run_cli(capsys, "report", "-w", single, "--out", tmp_path / "r.html", "-q")
    assert r.code == 2 and "r_figures is a symbolic link" in r.err, r.err
    assert {p: p.read_bytes() for p in single.rglob("*") if p.is_file()} == before
    # the report page, its figures and recordings are where they belong
    assert run_cli(capsys, "report", "-w", single, "-q").code == 0
    assert run_cli(capsys, "localize", q, "-w", single, "-o", tmp_path / "out.csv", "-q").code == 0
    (tmp_path / "link.csv").symlink_to(single / "map" / "radiomap.parquet")
    r = run_cli(capsys, "localize", q, "-w", single, "-o", tmp_path / "link.csv", "--force", "-q")
    assert r.code == 2 and "is a symbolic link" in r.err


# ------------------------------------------------------------------------------ build and outputs made by hand
def test_build_never_replaces_what_was_made_by_hand(tmp_path: Path, capsys) -> None:
    """After `export-map --cell-size 5` (or `optimize --anchors`) a plain `build` rebuilt the defaults saying
    only "inputs unchanged" (issue 40); it now refuses, saying what differs, and --force rebuilds."""
    import json

    from conftest import make_input_tables, write_tables

    t = make_input_tables(n_walks=3, n_steps=40)
    folder = write_tables(t, tmp_path / "in")
    t["fixes"][["walk_id", "t_s", "x_m", "y_m"]].to_csv(tmp_path / "anchors.csv", index=False)
    ws = tmp_path / "ws"
    assert run_cli(capsys, "build", folder, "-w", ws, "-q").code == 0
    assert run_cli(capsys, "build", folder, "-w", ws, "-q").code == 0  # up to date: nothing to do, no refusal

    def cell() -> float:
        return json.loads((ws / "map" / "report.json").read_text())["cell_size_m"]

    assert run_cli(capsys, "export-map", "-w", ws, "--cell-size", "5", "--force", "-q").code == 0
    r = run_cli(capsys, "build", folder, "-w", ws, "-q")
    assert r.code == 2 and len(r.err.strip().splitlines()) == 1, r.err
    assert "map (map.cell_size_m = 5.0 (build: 2.0)) made by hand since the last build" in r.err
    assert "pass --force" in r.err and cell() == 5.0
    assert run_cli(capsys, "optimize", "-w", ws, "--anchors", tmp_path / "anchors.csv", "--force", "-q").code == 0
    r = run_cli(capsys, "build", folder, "-w", ws, "-q")
    assert r.code == 2 and "optimize (same config: other options or inputs)" in r.err, r.err
    assert run_cli(capsys, "build", folder, "-w", ws, "--force", "-q").code == 0
    assert cell() == 2.0
    assert run_cli(capsys, "build", folder, "-w", ws, "-q").code == 0


# ------------------------------------------------------------------------------ config files checked whole
@pytest.mark.parametrize("table", ["[optimize]\nbogus = 1\n", "[map]\ncell_size_m = 0.01\n",
                                   "[ingest.msft_ilc]\nbogus = 1\n", "[evaluate]\nknn = 3\n"])
def test_a_config_file_is_checked_whole_by_every_stage(table: str, single: Path, tmp_path: Path, capsys) -> None:
    """`[optimize] bogus = 1` passed ingest, export-map and evaluate: only the running stage's table was
    checked (issue 40)."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[ingest]\n" + table)
    q = tmp_path / "q"
    q.mkdir()
    (q / "wifi.csv").write_text("walk_id,t_s,bssid,rssi_dbm\nq,1.0,00:11:22:33:44:01,-60\n")
    for args in (["ingest", tmp_path / "in", "-w", tmp_path / "ws2"], ["optimize", "-w", single, "--force"],
                 ["export-map", "-w", single, "--force"], ["evaluate", "-w", single, "--force"],
                 ["localize", q, "-w", single, "-o", tmp_path / "o.csv"],
                 ["simulate", tmp_path / "sim", "--preset", "tiny"], ["build", tmp_path / "in", "-w", tmp_path / "b"]):
        r = run_cli(capsys, *args, "--config", cfg, "-q")
        assert r.code == 2 and r.err.startswith(f"error: {cfg}:3: "), (args, r.err)
        assert len(r.err.strip().splitlines()) == 1
    assert not (tmp_path / "ws2").exists() and not (tmp_path / "sim").exists() and not (tmp_path / "b").exists()
