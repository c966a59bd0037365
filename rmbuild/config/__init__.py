"""Typed per-stage configuration.

One frozen dataclass per stage, each in its own module; a TOML file holds one table per stage. The
registry below names every section a config file may contain; anything else is an error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rmbuild.config.base import from_dict, load_toml, section_of, to_dict, to_toml
from rmbuild.config.evaluate import EvaluateConfig
from rmbuild.config.ingest import IngestConfig
from rmbuild.config.optimize import OptimizeConfig
from rmbuild.config.pdr import PdrConfig
from rmbuild.config.radiomap import MapConfig
from rmbuild.config.simulate import SimulateConfig
from rmbuild.errors import ConfigError

#: TOML section name -> config dataclass
SECTIONS: dict[str, type] = {
    "simulate": SimulateConfig,
    "ingest": IngestConfig,
    "pdr": PdrConfig,
    "optimize": OptimizeConfig,
    "map": MapConfig,
    "evaluate": EvaluateConfig,
}


def load_stage_config(
    section: str, path: str | Path | None = None, overrides: dict[str, Any] | None = None, base: Any = None
):
    """The config of one stage: ``base`` (or the defaults), then the file's ``[section]`` table (nested
    tables merge key by key), then ``overrides``.

    Raises :class:`ConfigError` for an unknown section in the file, an unknown key or a bad value.
    """
    cls = SECTIONS[section]
    data: dict[str, Any] = to_dict(base) if base is not None else {}
    where = "config"
    if path is not None:
        where = str(path)
        doc = load_toml(path)
        unknown = sorted(set(doc) - set(SECTIONS))
        if unknown:
            raise ConfigError(
                f"unknown section [{unknown[0]}] (known: {', '.join(SECTIONS)})", where
            )
        data = _merge(data, dict(section_of(doc, section, where)))
    for k, v in (overrides or {}).items():
        if v is not None:
            data[k] = v
    return from_dict(cls, data, f"{where}:[{section}]" if path else section)


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


__all__ = [
    "SECTIONS",
    "EvaluateConfig",
    "IngestConfig",
    "MapConfig",
    "OptimizeConfig",
    "PdrConfig",
    "SimulateConfig",
    "load_stage_config",
    "to_toml",
]
