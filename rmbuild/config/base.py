"""Strict loading and writing of typed, frozen, per-stage config dataclasses.

Every stage's config is a frozen dataclass whose fields carry their unit in a comment. A TOML file holds
one table per stage (``[optimize]``, ``[optimize.wifi]`` for a nested dataclass, ...). Unknown keys,
wrong types and out-of-range values are errors, never silently dropped. The resolved config is written
next to the stage's outputs with :func:`to_toml`.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin, get_type_hints

from rmbuild.errors import ConfigError

T = TypeVar("T")


def _check_value(tp: Any, value: Any, where: str) -> Any:
    origin = get_origin(tp)
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed:
            raise ConfigError(f"must be one of {list(allowed)}, got {value!r}", where)
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_value(a, value, where)
            except ConfigError as e:
                errors.append(e.problem)
        raise ConfigError(" / ".join(errors), where)
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"expected a list, got {type(value).__name__}", where)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_value(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"expected a list of {len(args)} values, got {len(value)}", where)
        return tuple(_check_value(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"expected a table, got {type(value).__name__}", where)
        return from_dict(tp, value, where)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"expected true/false, got {value!r}", where)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {value!r}", where)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number, got {value!r}", where)
        if not math.isfinite(float(value)):
            raise ConfigError(f"expected a finite number, got {value!r}", where)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {value!r}", where)
        return value
    raise ConfigError(f"unsupported config type {tp!r}", where)  # pragma: no cover - programming error


def from_dict(cls: type[T], data: dict[str, Any], where: str = "config") -> T:
    """Build a config dataclass from a plain dict, rejecting unknown keys and wrong types.

    After construction the dataclass' own ``validate()`` (if it defines one) checks ranges.
    """
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"unknown key {unknown[0]!r} (known: {', '.join(sorted(names))})", f"{where}"
        )
    kwargs = {k: _check_value(hints[k], v, f"{where}.{k}") for k, v in data.items()}
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except ValueError as e:
            raise ConfigError(str(e), where) from None
    return obj


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file into a dict; a syntax error becomes a one-line :class:`ConfigError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError("config file not found", str(p)) from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"invalid TOML: {e}", str(p)) from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def field_comments(cls: type) -> dict[str, list[str]]:
    """The ``#`` comment lines written just above each field of a config dataclass (its unit and meaning)."""
    import inspect

    try:
        src = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):
        return {}
    out: dict[str, list[str]] = {}
    pending: list[str] = []
    for line in src:
        t = line.strip()
        if t.startswith("#"):
            pending.append(t.lstrip("#").strip())
            continue
        head = t.split(":", 1)[0].strip()
        if pending and head.isidentifier() and ":" in t and not t.startswith(("def ", "class ", "@")):
            out[head] = pending
        pending = []
    return out


def to_toml(cfg: Any, section: str, comments: bool = False) -> str:
    """Serialise a config dataclass (nested dataclasses become sub-tables) as TOML text.

    ``comments``: put each field's source comment (unit, meaning, the paper's value) above it.
    """
    lines: list[str] = []
    nested: list[tuple[str, Any]] = []
    notes = field_comments(type(cfg)) if comments else {}
    lines.append(f"[{section}]")
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            nested.append((f"{section}.{f.name}", v))
            continue
        lines.extend(f"# {c}" for c in notes.get(f.name, []))
        if v is None:
            lines.append(f"# {f.name} = (unset)")
        else:
            lines.append(f"{f.name} = {_toml_value(v)}")
    text = "\n".join(lines) + "\n"
    for sub, v in nested:
        text += "\n" + to_toml(v, sub, comments)
    return text


def section_of(data: dict[str, Any], section: str, where: str) -> dict[str, Any]:
    """The table ``[section]`` of a parsed TOML file ({} when absent)."""
    sub = data.get(section, {})
    if not isinstance(sub, dict):
        raise ConfigError(f"[{section}] must be a table", where)
    return sub


def to_dict(cfg: Any) -> dict[str, Any]:
    """A config dataclass as plain dicts/lists (None fields omitted): the inverse of :func:`from_dict`."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            values = {f.name: getattr(v, f.name) for f in dataclasses.fields(v)}
            return {k: conv(x) for k, x in values.items() if x is not None}
        if isinstance(v, tuple):
            return [conv(x) for x in v]
        return v

    return conv(cfg)


def with_overrides(cfg: T, where: str = "option", **overrides: Any) -> T:
    """A copy of ``cfg`` with top-level fields replaced, type-checked and validated like a file."""
    data = to_dict(cfg)
    data.update({k: v for k, v in overrides.items()})
    return from_dict(type(cfg), data, where)
