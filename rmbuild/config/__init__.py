"""Typed per-stage configuration.

One frozen dataclass per stage, each in its own module; a TOML file holds one table per stage. The
registry below names every section a config file may contain; anything else is an error.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rmbuild.config.base import from_dict, parse_toml, read_toml_text, section_of, to_dict, to_toml, toml_key_line
from rmbuild.errors import ConfigError

if TYPE_CHECKING:
    from rmbuild.config.build import BuildConfig
    from rmbuild.config.evaluate import EvaluateConfig
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.config.optimize import OptimizeConfig
    from rmbuild.config.pdr import PdrConfig
    from rmbuild.config.radiomap import MapConfig
    from rmbuild.config.simulate import SimulateConfig

#: TOML section name -> "module:class" of its config dataclass
_SECTION_CLASSES = {
    "simulate": "rmbuild.config.simulate:SimulateConfig",
    "ingest": "rmbuild.config.ingest:IngestConfig",
    "pdr": "rmbuild.config.pdr:PdrConfig",
    "optimize": "rmbuild.config.optimize:OptimizeConfig",
    "map": "rmbuild.config.radiomap:MapConfig",
    "evaluate": "rmbuild.config.evaluate:EvaluateConfig",
    "build": "rmbuild.config.build:BuildConfig",
}


class _Sections(Mapping[str, type]):
    """TOML section name -> config dataclass; a section's module is imported when its class is first used
    (a command loads only its own stage's config)."""

    def __getitem__(self, name: str) -> type:
        mod, cls = _SECTION_CLASSES[name].split(":")
        return getattr(importlib.import_module(mod), cls)

    def __iter__(self) -> Iterator[str]:
        return iter(_SECTION_CLASSES)

    def __len__(self) -> int:
        return len(_SECTION_CLASSES)


#: TOML section name -> config dataclass: every section a config file may contain
SECTIONS: Mapping[str, type] = _Sections()


def __getattr__(name: str) -> Any:
    """The config dataclasses (``from rmbuild.config import OptimizeConfig``), imported when first asked for."""
    for where in _SECTION_CLASSES.values():
        mod, cls = where.split(":")
        if cls == name:
            return getattr(importlib.import_module(mod), cls)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def load_stage_config(
    section: str, path: str | Path | None = None, overrides: dict[str, Any] | None = None, base: Any = None
):
    """The config of one stage: ``base`` (or the defaults), then the file's ``[section]`` table (nested
    tables merge key by key), then ``overrides`` (command-line options; None values are ignored).

    Raises :class:`ConfigError` naming the file, the line (when the value is set on a line of its own) and
    the key for an unknown section in the file, an unknown key or a bad value — in any of the file's tables,
    not only ``[section]``: a file is checked whole, whichever stage reads it.
    """
    text = None
    if path is not None:
        p = Path(path)
        text = read_toml_text(p)  # size and encoding errors; read once: the lines named are those parsed
        doc = parse_toml(text, str(p))  # syntax errors, with their line
        for other in doc:
            if other != section and other in SECTIONS:  # an unknown section: the error of _resolve below
                _resolve(other, text, str(path), None, None)
    return _resolve(section, text, str(path) if path is not None else None, overrides, base)


def load_stage_config_text(section: str, text: str, where: str) -> Any:
    """The config of one stage from TOML ``text`` (e.g. the config.toml a stage wrote) over the defaults.
    Tables an earlier rmbuild wrote under their old names (:data:`MOVED_TABLES`) are read at their new place."""
    return _resolve(section, text, where, None, None, migrate=True)


#: tables that moved, old dotted name -> new: a config file naming the old one is an error naming the new;
#: a config an earlier rmbuild wrote into a workspace is read with the table moved
MOVED_TABLES: dict[tuple[str, ...], tuple[str, ...]] = {
    ("pdr", "msft_ilc"): ("ingest", "msft_ilc"),
    ("pdr", "ipin"): ("ingest", "ipin"),
    **{("evaluate", name): ("evaluate", "baselines", name)
       for name in ("slac", "nb", "ssd", "pfl", "smoothing", "ssr", "mll", "smartloc", "hist", "offline_cal")},
}


def _moved(doc: dict[str, Any], text: str, where: str, migrate: bool) -> dict[str, Any]:
    """``doc`` with the tables of :data:`MOVED_TABLES` at their new place (``migrate``); else a
    ConfigError at the first old table found."""
    for old, new in MOVED_TABLES.items():
        parent: Any = doc
        for part in old[:-1]:
            parent = parent.get(part) if isinstance(parent, dict) else None
        if not isinstance(parent, dict) or old[-1] not in parent:
            continue
        if not migrate:
            line = toml_key_line(text, old)
            raise ConfigError(f"[{'.'.join(old)}] is now [{'.'.join(new)}]: rename the table",
                              f"{where}:{line}" if line else where)
        table = parent.pop(old[-1])
        target = doc
        for part in new[:-1]:
            target = target.setdefault(part, {})
        target.setdefault(new[-1], table)
    return doc


def _resolve(section: str, text: str | None, where: str | None, overrides: dict[str, Any] | None,
             base: Any, migrate: bool = False) -> Any:
    cls = SECTIONS[section]
    data: dict[str, Any] = to_dict(base) if base is not None else {}
    if text is not None and where is not None:
        doc = _moved(parse_toml(text, where), text, where, migrate)
        unknown = sorted(set(doc) - set(SECTIONS))
        if unknown:
            line = toml_key_line(text, (unknown[0],))
            raise ConfigError(f"unknown section [{unknown[0][:80]}] (known: {', '.join(SECTIONS)})",
                              f"{where}:{line}" if line else where)
        data = _merge(data, dict(section_of(doc, section, where)))
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    data.update(given)
    try:
        return from_dict(cls, data, where or "config", prefix=f"{section}.")
    except ConfigError as e:
        field = (e.key or "").removeprefix(f"{section}.").split(".")[0]
        if field in given:
            raise ConfigError(e.problem, "command-line option", e.key, e.label) from None
        line = toml_key_line(text, tuple(e.key.split("."))) if text is not None and e.key else None
        if line is None:
            raise
        raise ConfigError(e.problem, f"{where}:{line}", e.key, e.label) from None


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


__all__ = [
    "MOVED_TABLES",
    "SECTIONS",
    "BuildConfig",
    "EvaluateConfig",
    "IngestConfig",
    "MapConfig",
    "OptimizeConfig",
    "PdrConfig",
    "SimulateConfig",
    "load_stage_config",
    "load_stage_config_text",
    "to_toml",
]
