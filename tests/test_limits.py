"""Extreme but well-formed input (issue 40): values far beyond any real data are refused where they enter,
with one error line naming the file, the line and the limit (rmbuild/limits.py), before anything of their
size is allocated; what stays accepted fits in bounded memory."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from capped import run_capped
from cli_util import run_cli
from conftest import make_input_tables, write_tables

from rmbuild import limits

ILC_FIXTURE = Path(__file__).resolve().parent / "fixtures" / "msft_ilc" / "tiny_trace.txt"


def one_error(r, pattern: str) -> str:
    """The single error line of a failed run (exit 2), matched against ``pattern``."""
    assert r.code == 2, (r.code, r.err)
    lines = [ln for ln in r.err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.err
    assert re.search(pattern, lines[0]), lines[0]
    return lines[0]


# ------------------------------------------------------------------------------ positions and walks
@pytest.mark.parametrize("value", ["1e308", "-2e5", "100000.5"])
def test_a_pose_far_beyond_any_building_is_refused_at_ingest(value: str, tmp_path: Path, capsys) -> None:
    """A pose x of 1e308 passed ingest and crashed optimize (`arange: cannot compute length`)."""
    t = make_input_tables()
    t["poses"]["x_m"] = t["poses"]["x_m"].astype(object)
    t["poses"].loc[7, "x_m"] = value
    folder = write_tables(t, tmp_path / "in")
    r = run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws")
    one_error(r, rf"{re.escape(str(folder / 'poses.csv'))}:9: poses: x_m .* more than 100000 m from the origin")
    assert not (tmp_path / "ws").exists()


def test_a_fix_far_away_is_refused(tmp_path: Path, capsys) -> None:
    t = make_input_tables()
    t["fixes"].loc[1, "y_m"] = -3e9
    folder = write_tables(t, tmp_path / "in")
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"fixes.csv:3: fixes: y_m -3e\+09 is more than 100000 m")


def test_an_ilc_waypoint_of_1e30_names_its_line(tmp_path: Path, capsys) -> None:
    """An MS ILC waypoint x of 1e30 ended in `IndexError: index -9223372036854775808` (issue 40)."""
    lines = ILC_FIXTURE.read_text().split("\n")
    i = next(k for k, ln in enumerate(lines) if "\tTYPE_WAYPOINT\t" in ln)
    lines[i] = lines[i].replace("50.0000", "1e30", 1)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "trace.txt").write_text("\n".join(lines))
    one_error(run_cli(capsys, "ingest", tmp_path / "in", "-w", tmp_path / "ws"),
              rf"trace.txt:{i + 1}: fixes: x_m 1e\+30 is more than")


def test_a_walk_longer_than_the_limits_is_refused(tmp_path: Path, capsys, monkeypatch) -> None:
    import rmbuild.ingest_core as core

    folder = write_tables(make_input_tables(n_steps=30), tmp_path / "in")
    monkeypatch.setattr(core, "MAX_WALK_POSES", 25)
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"poses.csv:27: walk 'walk0' has 30 poses: at most 25 in one walk")
    monkeypatch.setattr(core, "MAX_WALK_POSES", 1000)
    monkeypatch.setattr(core, "MAX_WALK_PATH_M", 10.0)  # 0.7 m steps: the 16th pose is 10.5 m on
    one_error(run_cli(capsys, "ingest", folder, "-w", tmp_path / "ws"),
              r"poses.csv:17: walk 'walk0': its steps add up to more than 10 m by this pose")


def test_a_million_distinct_bssids_is_a_clean_error_in_bounded_memory(tmp_path: Path) -> None:
    """1e6 readings of 1e6 distinct BSSIDs (~30 MB of CSV) asked for a dense 615,000,000-cell table
    (MemoryError at 2.1 GB); now one line naming the file and the limit, well under 1 GB."""
    t = make_input_tables(n_walks=2, n_steps=400)
    n = 1_000_000
    rng = np.random.default_rng(0)
    poses = t["poses"]
    k = rng.integers(0, len(poses), n)
    wifi = pd.DataFrame({"walk_id": poses["walk_id"].to_numpy()[k], "t_s": poses["t_s"].to_numpy()[k] + 0.1,
                         "bssid": np.char.mod("%012x", np.arange(n)), "rssi_dbm": -60.0})
    t["wifi"] = wifi.sort_values(["walk_id", "t_s"], kind="stable")
    folder = write_tables(t, tmp_path / "in")
    r = run_capped("ingest", folder, "-w", tmp_path / "ws", "-q")
    one_error(r, rf"{re.escape(str(folder / 'wifi.csv'))}: 800 poses with Wi-Fi readings of 1,000,000 distinct "
                 rf"BSSIDs: a fingerprint table of 800,000,000 cells, at most {limits.MAX_FINGERPRINT_CELLS:,}")
    assert r.peak_rss_mb < 1024, r.peak_rss_mb
