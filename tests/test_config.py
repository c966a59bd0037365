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
    with pytest.raises(ConfigError, match="max_attach_gap_s must be >= 0"):
        from_dict(IngestConfig, {"max_attach_gap_s": -1})
    with pytest.raises(ConfigError, match="unknown key 'gap'"):
        from_dict(IngestConfig, {"gap": 1})
    assert from_dict(IngestConfig, {"max_attach_gap_s": 3}).max_attach_gap_s == 3.0
    with pytest.raises(ConfigError, match="need 0 < scale_min <= 1 <= scale_max"):
        from_dict(SECTIONS["optimize"], {"odometry": {"scale_min": 1.2}}, "optimize")
    with pytest.raises(ConfigError, match="need max_gap_s >= 0"):
        from_dict(SECTIONS["optimize"], {"continuity": {"max_gap_s": -1.0}}, "optimize")
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
