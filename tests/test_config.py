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
    with pytest.raises(ConfigError, match="scale_min_span_m and solve.scale_pair_gate_m must be >= 0"):
        from_dict(SECTIONS["optimize"], {"solve": {"scale_min_span_m": -5.0}}, "optimize")
    with pytest.raises(ConfigError, match="scale_max_iterations must be >= scale_iterations"):
        from_dict(SECTIONS["optimize"], {"solve": {"scale_iterations": 4, "scale_max_iterations": 3}}, "optimize")


def test_file_layers(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_text("[ingest]\nattach = 'nearest'\n[optimize]\n")
    cfg = load_stage_config("ingest", p)
    assert cfg.attach == "nearest" and cfg.max_attach_gap_s == 2.0
    p.write_text("[ingest\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_stage_config("ingest", p)


def test_config_command_prints_a_file_that_loads_back(tmp_path: Path, capsys) -> None:
    from cli_util import run_cli

    r = run_cli(capsys, "config")
    assert r.code == 0
    doc = tomllib.loads(r.out)
    assert set(doc) == set(SECTIONS)
    assert "# m; grid cell edge" in r.out  # the field comments (units) come along
    (tmp_path / "all.toml").write_text(r.out)
    for name in SECTIONS:
        assert load_stage_config(name, tmp_path / "all.toml") == SECTIONS[name]()
    r = run_cli(capsys, "config", "--stage", "nope")
    assert r.code == 2 and "unknown section 'nope'" in r.err
