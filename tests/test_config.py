"""Strict typed config: unknown keys, wrong types, ranges, nested tables, round trip through TOML."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from rmbuild.config import SECTIONS, IngestConfig, load_stage_config, to_toml
from rmbuild.config.base import from_dict, to_dict
from rmbuild.errors import ConfigError


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_defaults_round_trip_through_toml(section: str) -> None:
    cfg = SECTIONS[section]()
    text = to_toml(cfg, section)
    back = from_dict(SECTIONS[section], tomllib.loads(text)[section], section)
    assert back == cfg
    assert to_dict(back) == to_dict(cfg)


def test_type_and_range_errors() -> None:
    with pytest.raises(ConfigError, match="expected a number"):
        from_dict(IngestConfig, {"max_attach_gap_s": "soon"})
    with pytest.raises(ConfigError, match=r"max_attach_gap_s: -1.0 is outside its range \[0, 3600\]"):
        from_dict(IngestConfig, {"max_attach_gap_s": -1})
    with pytest.raises(ConfigError, match="unknown key 'gap'"):
        from_dict(IngestConfig, {"gap": 1})
    assert from_dict(IngestConfig, {"max_attach_gap_s": 3}).max_attach_gap_s == 3.0
    with pytest.raises(ConfigError, match=r"odometry.scale_min: 1.2 is outside its range \[0.1, 1\]"):
        from_dict(SECTIONS["optimize"], {"odometry": {"scale_min": 1.2}}, "optimize")
    with pytest.raises(ConfigError, match=r"continuity.max_gap_s: -1.0 is outside its range \[0, 86400\]"):
        from_dict(SECTIONS["optimize"], {"continuity": {"max_gap_s": -1.0}}, "optimize")
    with pytest.raises(ConfigError, match="need d_min < d_max"):  # a rule between fields stays in validate()
        from_dict(SECTIONS["optimize"], {"wifi": {"d_min": 8.0}}, "optimize")
    with pytest.raises(ConfigError, match="unknown key 'gnc_factors'"):
        from_dict(SECTIONS["optimize"], {"solve": {"gnc_factors": [2.0]}}, "optimize")


def test_optimize_config_stays_small() -> None:
    """[optimize] holds what a user may reasonably change: at most 40 settings."""
    import dataclasses

    def count(cls) -> int:
        return sum(count(f.type if not isinstance(f.type, str) else type(getattr(cls(), f.name)))
                   if dataclasses.is_dataclass(getattr(cls(), f.name)) else 1 for f in dataclasses.fields(cls))

    assert count(SECTIONS["optimize"]) <= 40


def test_file_layers(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_text("[ingest]\nattach = 'nearest'\n[optimize]\n")
    cfg = load_stage_config("ingest", p)
    assert cfg.attach == "nearest" and cfg.max_attach_gap_s == 2.0
    p.write_text("[ingest\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_stage_config("ingest", p)


def _settings(doc: dict) -> int:
    return sum(_settings(v) if isinstance(v, dict) else 1 for v in doc.values())


def test_config_command_prints_a_file_that_loads_back(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    r = run_cli(capsys, "config", "--all")
    assert r.code == 0
    doc = tomllib.loads(r.out)
    assert set(doc) == set(SECTIONS)
    assert "# m; grid cell edge" in r.out  # the field comments (units) come along
    (tmp_path / "all.toml").write_text(r.out)
    for name in SECTIONS:
        assert load_stage_config(name, tmp_path / "all.toml") == SECTIONS[name]()
    r = run_cli(capsys, "config", "--stage", "nope")
    assert r.code == 2 and "'nope' is not one of" in r.err and len(r.err.strip().splitlines()) == 1
    r = run_cli(capsys, "config", "--stage", "ingest,map", "--stage", "pdr,ingest")  # comma and repeat
    assert r.code == 0 and [k for k in tomllib.loads(r.out)] == ["ingest", "map", "pdr"]


def test_config_command_shows_the_user_settings_by_default(tmp_path: Path, capsys) -> None:
    """`rmbuild config` prints at most 60 settings (none of the simulator's or the baselines'), a file that
    loads back to the defaults; `--all` prints every one of the 200-odd."""
    from cli_util import run_cli

    r = run_cli(capsys, "config")
    assert r.code == 0
    doc = tomllib.loads(r.out)
    assert 30 <= _settings(doc) <= 60
    assert "simulate" not in doc and "baselines" not in doc["evaluate"] and "--all" in r.out
    assert doc["optimize"]["odometry"]["mu"] == SECTIONS["optimize"]().odometry.mu
    (tmp_path / "user.toml").write_text(r.out)
    for name in doc:
        assert load_stage_config(name, tmp_path / "user.toml") == SECTIONS[name]()
    everything = tomllib.loads(run_cli(capsys, "config", "--all").out)
    assert _settings(everything) > 200 and "slac" in everything["evaluate"]["baselines"]
    only = tomllib.loads(run_cli(capsys, "config", "--stage", "simulate").out)
    assert list(only) == ["simulate"] and _settings(only) > 60


def test_user_settings_name_real_settings() -> None:
    """Each key the default view lists exists (a renamed setting must be renamed there too)."""
    import dataclasses

    from rmbuild.config.user import USER_SETTINGS

    for section, keys in USER_SETTINGS.items():
        for key in keys:
            obj = SECTIONS[section]()
            for part in key.split("."):
                assert part in {f.name for f in dataclasses.fields(obj)}, f"{section}.{key}"
                obj = getattr(obj, part)
            assert not dataclasses.is_dataclass(obj), f"{section}.{key} is a table, not a setting"


@pytest.mark.parametrize(("text", "old", "new"), [
    ("[pdr]\nstep_length_m = 0.7\n[pdr.ipin]\nuse_imui = false\n", "pdr.ipin", "ingest.ipin"),
    ("[pdr.msft_ilc]\nmax_wifi_age_s = 5.0\n", "pdr.msft_ilc", "ingest.msft_ilc"),
    ("[evaluate]\nsplit_every = 4\n\n[evaluate.slac]\nseed = 3\n", "evaluate.slac", "evaluate.baselines.slac"),
])
def test_a_moved_table_is_a_one_line_error_naming_its_new_place(text: str, old: str, new: str, tmp_path: Path,
                                                                capsys) -> None:
    from cli_util import run_cli

    p = tmp_path / "old.toml"
    p.write_text(text)
    r = run_cli(capsys, "config", "--config", p)
    assert r.code == 2 and len(r.err.strip().splitlines()) == 1
    assert f"[{old}] is now [{new}]" in r.err and f"{p}:{text.splitlines().index(f'[{old}]') + 1}" in r.err


def test_a_workspace_config_written_before_the_move_still_reads() -> None:
    """data/config.toml of a workspace ingested by an earlier rmbuild keeps its IPIN origin."""
    from rmbuild.config import load_stage_config_text

    old = "[ingest]\nattach = 'nearest'\n\n[pdr]\nstep_length_m = 0.7\n\n[pdr.ipin]\norigin_lat_deg = 49.5\n" \
          "origin_lon_deg = 11.1\n"
    ing = load_stage_config_text("ingest", old, "data/config.toml")
    assert ing.attach == "nearest" and (ing.ipin.origin_lat_deg, ing.ipin.origin_lon_deg) == (49.5, 11.1)
    assert load_stage_config_text("pdr", old, "data/config.toml").step_length_m == 0.7


def test_simulate_prints_its_own_settings(capsys) -> None:
    from cli_util import run_cli

    tiny = tomllib.loads(run_cli(capsys, "simulate", "--print-config", "--preset", "tiny", "--seed", "3").out)
    default = tomllib.loads(run_cli(capsys, "simulate", "--print-config").out)
    assert tiny["simulate"]["seed"] == 3 and default["simulate"]["seed"] == 7
    assert tiny["simulate"]["venue"] != default["simulate"]["venue"]
    r = run_cli(capsys, "simulate")
    assert r.code == 2 and "OUT_DIR" in r.err


# ------------------------------------------------------------------------------- ranges and file errors
@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_every_numeric_field_has_a_documented_range(section: str) -> None:
    from rmbuild.config.base import unbounded_fields

    assert unbounded_fields(SECTIONS[section]) == []
    text = to_toml(SECTIONS[section](), section, comments=True)
    assert "# range: [" in text


def test_configs_built_in_python_are_held_to_the_ranges() -> None:
    """validate() applies the ranges to a config built in Python too (stages call it), nested tables included."""
    import dataclasses

    from rmbuild.config.optimize import paper_config

    paper_config().validate()  # the published model's values are all inside the documented ranges
    for cls in SECTIONS.values():
        cls().validate()
    opt = SECTIONS["optimize"]()
    bad = dataclasses.replace(opt, solve=dataclasses.replace(opt.solve, outer_iterations=0))
    with pytest.raises(ValueError, match=r"solve.outer_iterations: 0 is outside its range \[1, 100\]"):
        bad.validate()
    ev = SECTIONS["evaluate"]()
    pfl = dataclasses.replace(ev.baselines.pfl, n_particles=10**9)
    bad = dataclasses.replace(ev, baselines=dataclasses.replace(ev.baselines, pfl=pfl))
    with pytest.raises(ValueError, match="pfl.n_particles"):
        bad.validate()


@pytest.mark.parametrize("text, line, message", [
    ("[map]\ncell_size_m = 1e-300\n", 2, r"map.cell_size_m: 1e-300 is outside its range \[0.25, 100\]"),
    ("[map]\n\n[map.fill]\n# note\nidw_power = 0.0\n", 5, r"map.fill.idw_power: 0.0 is outside its range"),
    ("[ingest]\nrssi_max_dbm = 1e308\n", 2, r"ingest.rssi_max_dbm: 1e\+308 is outside its range"),
    ("[evaluate.knn]\nk = -4611686018427387904\n", 2, r"evaluate.knn.k: -4611686018427387904 is outside"),
    ("[map]\nfill = { idw_power = -1 }\n", 2, r"map.fill.idw_power: -1.0 is outside"),
    ("[map]\ncell_size_m = 1" + "0" * 400 + "\n", 2, r"map.cell_size_m: expected a finite number, got 1000"),
    ("[ingest]\nattach = \"nearby\"\n", 2, r"ingest.attach: must be one of \['interval', 'nearest'\]"),
    ("[ingest]\ngap = 1\n", 2, r"ingest: unknown key 'gap'"),
    ("[ingset]\n", 1, r"unknown section \[ingset\]"),
    ("[ingest\n", 1, r"invalid TOML: Expected '\]'"),
])
def test_config_errors_name_file_line_and_key(text: str, line: int, message: str, tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    p = tmp_path / "bad.toml"
    p.write_text(text)
    section = text.strip("[").split("]")[0].split(".")[0]
    section = section if section in SECTIONS else "ingest"
    with pytest.raises(ConfigError) as e:
        load_stage_config(section, p)
    assert str(e.value).startswith(f"{p}:{line}: "), str(e.value)
    import re

    assert re.search(message, str(e.value)), str(e.value)
    r = run_cli(capsys, "config", "--config", p)
    assert r.code == 2 and r.err.strip().splitlines() == [f"error: {e.value}"]


def test_hostile_config_files_are_clean_errors(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    cases = {
        "latin1.toml": ("[ingest]\n# caf\xe9\n".encode("latin-1"), f"{tmp_path / 'latin1.toml'}:2: not UTF-8"),
        "deep.toml": (b"[ingest]\nx = " + b"[" * 100_000 + b"]" * 100_000 + b"\n", "nested too deeply"),
        "huge.toml": (b"#" * (2 << 20), "too large for a config file"),
        "bin.toml": (bytes(range(256)), "not UTF-8"),
    }
    for name, (data, message) in cases.items():
        (tmp_path / name).write_bytes(data)
        r = run_cli(capsys, "config", "--config", tmp_path / name)
        assert r.code == 2 and len(r.err.strip().splitlines()) == 1 and message in r.err, (name, r.err)
    r = run_cli(capsys, "config", "--config", tmp_path)
    assert r.code == 2


def test_an_absurd_simulation_is_refused_before_it_starts(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    p = tmp_path / "c.toml"
    p.write_text("[simulate.walkers]\nn_long_walks = 1000\nlong_walk_steps = [100.0, 90000.0]\n")
    r = run_cli(capsys, "simulate", tmp_path / "out", "--config", p)
    assert r.code == 2 and "at most 2,500,000" in r.err and not (tmp_path / "out").exists()


def test_a_range_applies_to_configs_built_in_python() -> None:
    from rmbuild.config import MapConfig

    with pytest.raises(ValueError, match="cell_size_m"):
        MapConfig(cell_size_m=0.001).validate()


def test_command_line_values_are_checked_like_the_file(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    r = run_cli(capsys, "export-map", "-w", tmp_path / "nope", "--cell-size", "1e-300")
    assert r.code == 2 and "command-line option: map.cell_size_m: 1e-300 is outside its range" in r.err
