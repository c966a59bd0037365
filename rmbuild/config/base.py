"""Strict loading and writing of typed, frozen, per-stage config dataclasses.

Every stage's config is a frozen dataclass whose fields carry their unit in a comment. A TOML file holds
one table per stage (``[optimize]``, ``[optimize.wifi]`` for a nested dataclass, ...). Unknown keys,
wrong types and out-of-range values are errors, never silently dropped. The resolved config is written
next to the stage's outputs with :func:`to_toml`.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin, get_type_hints

from rmbuild.errors import ConfigError
from rmbuild.io.compressed import read_at_most
from rmbuild.limits import MAX_CONFIG_BYTES

T = TypeVar("T")


def _check_value(tp: Any, value: Any, key: str, where: str) -> Any:
    origin = get_origin(tp)
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed:
            raise ConfigError(f"must be one of {list(allowed)}, got {_short(value)}", where, key)
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
                return _check_value(a, value, key, where)
            except ConfigError as e:
                errors.append(e.problem)
        raise ConfigError(" / ".join(errors), where, key)
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"expected a list, got {type(value).__name__}", where, key)
        if len(args) == 2 and args[1] is Ellipsis:
            if len(value) > MAX_LIST:
                raise ConfigError(f"a list of {len(value)} values: at most {MAX_LIST}", where, key)
            return tuple(_check_value(args[0], v, key, where) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"expected a list of {len(args)} values, got {len(value)}", where, key)
        return tuple(_check_value(a, v, key, where) for a, v in zip(args, value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"expected a table, got {type(value).__name__}", where, key)
        return from_dict(tp, value, where, prefix=f"{key}.")  # type: ignore[arg-type]
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"expected true/false, got {_short(value)}", where, key)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {_short(value)}", where, key)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number, got {_short(value)}", where, key)
        try:
            v = float(value)
        except OverflowError:
            v = math.inf
        if not math.isfinite(v):
            raise ConfigError(f"expected a finite number, got {_short(value)}", where, key)
        return v
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {_short(value)}", where, key)
        return value
    raise ConfigError(f"unsupported config type {tp!r}", where, key)  # pragma: no cover - programming error


#: longest list a list-valued field takes (e.g. localizer names)
MAX_LIST = 64


def _short(value: Any) -> str:
    """repr of a bad value, cut to a readable length (a config value may be a huge string or number)."""
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


@dataclasses.dataclass(frozen=True)
class Range:
    """The documented range of a numeric config field (both ends included); for a tuple field, of each
    element. Declared with :func:`bounded`, printed by ``rmbuild config``, checked by :func:`from_dict`."""

    lo: float
    hi: float

    def __contains__(self, v: object) -> bool:
        return isinstance(v, (int, float)) and self.lo <= v <= self.hi

    def __str__(self) -> str:
        return f"[{_num(self.lo)}, {_num(self.hi)}]"


def _num(v: float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def bounded(default: Any, lo: float, hi: float) -> Any:
    """A numeric config field with its documented range ``[lo, hi]``: ``x: float = bounded(2.0, 0.25, 100)``."""
    if not lo <= hi:
        raise ValueError(f"bounded: lo {lo} > hi {hi}")  # programming error
    return dataclasses.field(default=default, metadata={"range": Range(lo, hi)})


def field_range(f: dataclasses.Field) -> Range | None:
    r = f.metadata.get("range")
    return r if isinstance(r, Range) else None


def _is_numeric(tp: Any) -> bool:
    """int, float, tuples of them, or Optional of these."""
    if tp in (int, float):
        return True
    origin = get_origin(tp)
    if origin in (typing.Union, types.UnionType, tuple):
        return any(_is_numeric(a) for a in get_args(tp) if a is not Ellipsis and a is not type(None))
    return False


def unbounded_fields(cls: type, prefix: str = "") -> list[str]:
    """Numeric fields of a config dataclass (nested ones included) that declare no range: each should."""
    out: list[str] = []
    hints = get_type_hints(cls)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            out += unbounded_fields(tp, f"{prefix}{f.name}.")  # type: ignore[arg-type]
        elif _is_numeric(tp) and field_range(f) is None:
            out.append(f"{prefix}{f.name}")
    return out


def _check_range(f: dataclasses.Field, value: Any, key: str, where: str) -> None:
    r = field_range(f)
    if r is None or value is None:
        return
    values = value if isinstance(value, tuple) else (value,)
    for i, v in enumerate(values):
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v not in r:
            which = f" (element {i + 1})" if isinstance(value, tuple) else ""
            raise ConfigError(f"{_short(v)}{which} is outside its range {r}", where, key)


def check_ranges(cfg: Any, prefix: str = "") -> None:
    """ValueError when a field of ``cfg`` (nested configs included) is outside its range: for ``validate()``
    methods, so that configs built in Python are held to the ranges a file is."""
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            check_ranges(v, f"{prefix}{f.name}.")
            continue
        try:
            _check_range(f, v, f"{prefix}{f.name}", "")
        except ConfigError as e:
            raise ValueError(str(e)) from None


def from_dict(cls: type[T], data: dict[str, Any], where: str = "config", prefix: str = "") -> T:
    """Build a config dataclass from a plain dict, rejecting unknown keys, wrong types and values outside
    their documented ranges; then the dataclass' own ``validate()`` (if any) checks rules between fields.

    ``prefix``: the dotted key of this table (``map.fill``), for error messages.
    """
    hints = get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        name = str(unknown[0])[:80]
        raise ConfigError(f"unknown key {name!r} (known: {', '.join(sorted(fields))})", where,
                          key=f"{prefix}{name}", label=prefix.rstrip(".") or None)
    kwargs = {}
    for k, v in data.items():
        key = f"{prefix}{k}"
        kwargs[k] = _check_value(hints[k], v, key, where)
        _check_range(fields[k], kwargs[k], key, where)
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except ValueError as e:
            raise ConfigError(str(e), where, key=prefix.rstrip(".") or None) from None
    return obj


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file into a dict; every problem is a one-line :class:`ConfigError` naming file and line."""
    return parse_toml(read_toml_text(path), str(path))


def read_toml_text(path: str | Path) -> str:
    """The text of a TOML file, at most :data:`MAX_CONFIG_BYTES` (counted as it is read: a device has no size);
    size, reading and encoding problems are a :class:`ConfigError` naming the file."""
    p = Path(path)
    try:
        data = read_at_most(p, MAX_CONFIG_BYTES)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(f"more than {MAX_CONFIG_BYTES:,} bytes: too large for a config file", str(p))
    except FileNotFoundError:
        raise ConfigError("config file not found", str(p)) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, not a config file", str(p)) from None
    except OSError as e:
        raise ConfigError(f"unreadable ({e.strerror})", str(p)) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise ConfigError(f"not UTF-8 text ({e.reason})", f"{p}:{line}") from None
    return text


def parse_toml(text: str, where: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(e))
        raise ConfigError(f"invalid TOML: {msg}", f"{where}:{m.group(1)}" if m else where) from None
    except RecursionError:
        raise ConfigError("invalid TOML: arrays or tables nested too deeply", where) from None


_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")
_KEY = re.compile(r"^\s*([A-Za-z0-9_\-\.\"' ]+?)\s*=")


def _dotted(s: str) -> tuple[str, ...]:
    return tuple(part.strip().strip("\"'") for part in s.split("."))


def toml_key_line(text: str, key: tuple[str, ...]) -> int | None:
    """The line (from 1) where the dotted ``key`` is set in TOML ``text``, when it is set by a plain
    ``key = value`` line under its table header (or as a dotted key); None otherwise."""
    table: tuple[str, ...] = ()
    for n, line in enumerate(text.splitlines(), 1):
        if m := _HEADER.match(line):
            table = _dotted(m.group(1))
            if table == key:
                return n
        elif m := _KEY.match(line):
            full = table + _dotted(m.group(1))
            if full == key or key[: len(full)] == full and len(full) > len(table):
                return n
    return None


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


def to_toml(cfg: Any, section: str, comments: bool = False, keys: frozenset[str] | None = None) -> str:
    """Serialise a config dataclass (nested dataclasses become sub-tables) as TOML text.

    ``comments``: put each field's source comment (unit, meaning, the paper's value) and its range above it.
    ``keys``: only these settings (dotted names below ``section``, ``"odometry.mu"``), and only the tables
    that hold one of them; None: every setting.
    """
    lines: list[str] = []
    nested: list[tuple[str, Any, frozenset[str] | None]] = []
    notes = field_comments(type(cfg)) if comments else {}
    lines.append(f"[{section}]")
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            sub = None if keys is None else frozenset(k.split(".", 1)[1] for k in keys
                                                      if k.startswith(f"{f.name}."))
            if sub is None or sub:
                nested.append((f"{section}.{f.name}", v, sub))
            continue
        if keys is not None and f.name not in keys:
            continue
        lines.extend(f"# {c}" for c in notes.get(f.name, []))
        if comments and (r := field_range(f)) is not None:
            lines.append(f"# range: {r}")
        if v is None:
            lines.append(f"# {f.name} = (unset)")
        else:
            lines.append(f"{f.name} = {_toml_value(v)}")
    text = "\n".join(lines) + "\n"
    for name, v, sub in nested:
        text += "\n" + to_toml(v, name, comments, sub)
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

