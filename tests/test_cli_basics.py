"""The CLI shell: help texts, simulate determinism and safety, simulate -> ingest needs no options."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest
from cli_util import run_cli

from rmbuild.cli import COMMANDS
from rmbuild.io.workspace import Workspace


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_help_lists_commands(capsys) -> None:
    r = run_cli(capsys, "--help")
    assert r.code == 0
    for name in ("simulate", "ingest", "optimize"):
        assert name in r.out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_command_has_help(name: str, capsys) -> None:
    r = run_cli(capsys, name, "--help")
    assert r.code == 0 and "Usage:" in r.out, r.err


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_offers_rerun_only_where_the_command_takes_it(name: str, capsys) -> None:
    from rmbuild.cli import load_command

    takes = any("--rerun" in getattr(p, "opts", ()) for p in load_command(name).params)
    r = run_cli(capsys, name, "--help")
    assert ("--rerun" in r.out) == takes, name
    if name == "build":
        assert not takes


def test_a_mistyped_command_gets_a_suggestion(capsys) -> None:
    r = run_cli(capsys, "optimise", "-w", "x")
    assert r.code == 2 and "No such command 'optimise'. Did you mean 'optimize'?" in r.err
    assert len(r.err.strip().splitlines()) == 1
    r = run_cli(capsys, "expor-map")
    assert r.code == 2 and "Did you mean 'export-map'?" in r.err
    r = run_cli(capsys, "frobnicate")
    assert r.code == 2 and "No such command 'frobnicate'." in r.err and "Did you mean" not in r.err


def test_optimize_summary_counts_linked_walks_first(capsys) -> None:
    """With unlinked walks the first optimised error is the linked walks' (an unlinked walk's frame is
    arbitrary), and the linked count says why it is below the progress bar's."""
    from rmbuild.cli.optimize import _summary

    lm = {"mean": 107.58, "max": 272.36, "n": 513}
    r = {"walks": 102, "poses": 5709, "factors": {"odometry": 5607, "vicinity": 1915, "prior": 6},
         "time_s": {"stage_total": 10.7}, "gauge": "floorplan", "linked_walks": 54,
         "refuted_walks": ["a", "b", "c", "d"], "anchored_only_walks": 0,
         "metrics_alignment": {"fitted_on": "linked walks", "walks": 54},
         "raw": {"ate_m": None, "landmark_error_m": {"mean": 53.69, "max": 104.8, "n": 513}},
         "optimized": {"ate_m": None, "landmark_error_m": lm,
                       "landmark_error_fitted_walks_m": {"mean": 8.9, "max": 30.08, "n": 258},
                       "landmark_error_unlinked_at_raw_m": {"mean": 35.58, "max": 100.65, "n": 513}}}
    capsys.readouterr()
    _summary(r)
    out = capsys.readouterr().out
    first = next(line for line in out.splitlines() if "optimized" in line and "error" in line)
    assert "8.90 m" in first and "54 linked walks" in first and "107.58" not in out
    assert "linked into the map: 54 of 102 walks; the RF check then refuted 4" in out
    assert out.index("optimized landmark") < out.index("unlinked at their raw placement")


def test_a_broken_command_module_is_an_error(capsys, monkeypatch) -> None:
    """A command whose module fails to import is listed and fails loudly, never silently disappears."""
    from rmbuild import cli as cli_mod

    monkeypatch.setitem(cli_mod.COMMANDS, "view", "rmbuild.cli.no_such_module:view")
    r = run_cli(capsys, "--help")
    assert r.code == 0 and "view" in r.out
    r = run_cli(capsys, "view", "--help")
    assert r.code == 1 and r.err.strip().splitlines() == [r.err.strip()]
    assert "command 'view' is broken" in r.err and "no_such_module" in r.err


def test_format_choices_come_from_the_reader_registry(capsys) -> None:
    from rmbuild.io.formats import REGISTRY, reader_names

    r = run_cli(capsys, "ingest", "--help")
    for name in reader_names():
        assert name in r.out and REGISTRY[name].description.split()[0] in r.out
    r = run_cli(capsys, "ingest", "x", "-w", "y", "--format", "nope")
    assert r.code == 2 and "nope" in r.err


def test_simulate_is_deterministic_and_safe(tmp_path: Path, capsys) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_cli(capsys, "simulate", a, "--preset", "tiny", "--seed", "11").code == 0
    assert run_cli(capsys, "simulate", b, "--preset", "tiny", "--seed", "11").code == 0
    da, db = _digest(a), _digest(b)
    assert da == db and "poses.csv" in da and "truth/poses.csv" in da
    r = run_cli(capsys, "simulate", a, "--preset", "tiny", "--seed", "12")
    assert r.code == 2 and "--force" in r.err
    assert _digest(a) == da
    assert run_cli(capsys, "simulate", a, "--preset", "tiny", "--seed", "12", "--force").code == 0
    assert _digest(a) != da
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    r = run_cli(capsys, "simulate", mine, "--preset", "tiny", "--force")
    assert r.code == 2 and "refusing" in r.err and (mine / "notes.txt").read_text() == "keep"


def test_simulate_then_ingest_picks_up_truth(tmp_path: Path, capsys) -> None:
    assert run_cli(capsys, "simulate", tmp_path / "in", "--preset", "tiny", "--format", "parquet").code == 0
    r = run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws")
    assert r.code == 0, r.err
    ds = Workspace.open(tmp_path / "ws").read_dataset()
    assert ds.truth_poses is not None and len(ds.truth_poses) == len(ds.poses)
    assert (ds.truth_poses["walk_id"] == ds.poses["walk_id"]).all()
    assert ds.venue is not None and len(ds.fixes) > 0
    assert set(ds.extra["truth"]) >= {"walks", "devices"}


def test_bad_test_device_option(tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "simulate", tmp_path / "x", "--preset", "tiny", "--test-device", "1.2")
    assert r.code == 2 and "--test-device" in r.err


def test_stage_on_missing_workspace(tmp_path: Path, capsys) -> None:
    r = run_cli(capsys, "optimize", "-w", tmp_path / "nothing")
    assert r.code == 2 and "not an rmbuild workspace" in r.err


def test_progress_counts_and_log_lines(caplog) -> None:
    """The bar's count column says done/total unit; -v leaves one line per finished phase with the count,
    the time and the rate; without a terminal and -v nothing is drawn."""
    import io
    import logging

    from rich.console import Console
    from rich.progress import Progress

    from rmbuild.cli.progress import LogProgress, progress_display
    from rmbuild.cli.progress_bars import CountRateColumn, RichProgress

    bar = Progress(CountRateColumn(), console=Console(file=io.StringIO(), force_terminal=True, width=100))
    rp = RichProgress(bar, verbose=True)
    with caplog.at_level(logging.INFO, logger="rmbuild"):
        rp.phase("reading", 5, "files")
        rp.advance(3)
        assert CountRateColumn().render(bar.tasks[-1]).plain.startswith("3/5 files")
        rp.message("3 walks")
        rp.close()
    assert re.match(r"reading: done in [0-9.]+ s; 3/5 files \([0-9.,]+ files/s\); 3 walks", caplog.messages[-1])
    lp = LogProgress()
    with caplog.at_level(logging.INFO, logger="rmbuild"):
        lp.phase("solving", None, "iterations")
        lp.advance(4)
        lp.close()
    assert caplog.messages[-1].startswith("solving: done in") and "4 iterations" in caplog.messages[-1]
    with progress_display(quiet=False, verbose=0) as p:  # pytest's stderr is no terminal
        assert p is None
