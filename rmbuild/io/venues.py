"""The venues file of `rmbuild build --venues` (docs/scale-out.md): one ``[[venue]]`` table per venue.

```toml
[[venue]]
name = "mall-17"                     # the workspace's directory name under OUT_DIR
inputs = ["mall-17/walks"]           # files or folders, relative to this file's folder
format = "msft-ilc"                  # optional: recognised from the files otherwise
config = "mall-17.toml"              # optional: this venue's config (else the --config file)
floorplan = "mall-17/plan.geojson"   # optional: as `rmbuild ingest --floorplan`
```

Unknown keys, missing or wrong-typed values, duplicate names and missing input paths are errors naming
the file, the venue's line and the key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from rmbuild.config.base import parse_toml, read_toml_text
from rmbuild.errors import ConfigError
from rmbuild.limits import MAX_VENUES

#: a venue's name becomes a directory name: letters, digits, ``.``, ``_``, ``-``, not starting with ``.``
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,99}$")
_HEADER = re.compile(r"^\s*\[\[\s*venue\s*\]\]\s*(#.*)?$")
_KEYS = ("name", "inputs", "format", "config", "floorplan")


@dataclass(frozen=True)
class Venue:
    name: str
    inputs: tuple[Path, ...]
    format: str | None = None
    config: Path | None = None
    floorplan: Path | None = None


def read_venues(path: str | Path, formats: list[str]) -> list[Venue]:
    """The venues of ``path``; ``formats``: the input format names a venue may give."""
    p = Path(path)
    text = read_toml_text(p)  # read once: the lines named are those parsed
    doc = parse_toml(text, str(p))
    lines = _venue_lines(text)
    extra = sorted(set(doc) - {"venue"})
    if extra:
        raise ConfigError(f"unknown key {extra[0]!r}: a venues file holds [[venue]] tables only", str(p))
    items = doc.get("venue")
    if not isinstance(items, list) or not items:
        raise ConfigError("no [[venue]] table", str(p))
    if len(items) > MAX_VENUES:
        raise ConfigError(f"{len(items):,} venues: at most {MAX_VENUES:,} in one file", str(p))
    out: list[Venue] = []
    for i, v in enumerate(items):
        where = f"{p}:{lines[i]}" if i < len(lines) else str(p)
        out.append(_venue(v, i, where, p.parent, formats))
    names = [v.name for v in out]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup is not None:
        raise ConfigError(f"venue name {dup!r} given twice (each venue gets its own workspace)", str(p))
    return out


def _venue(v: object, i: int, where: str, base: Path, formats: list[str]) -> Venue:
    label = f"venue {i + 1}"
    if not isinstance(v, dict):
        raise ConfigError(f"{label}: expected a table", where)
    unknown = sorted(set(v) - set(_KEYS))
    if unknown:
        raise ConfigError(f"{label}: unknown key {unknown[0]!r} (known: {', '.join(_KEYS)})", where)
    name = v.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        raise ConfigError(f"{label}: name must be a directory name (letters, digits, . _ -), got {name!r}", where)
    inputs = v.get("inputs")
    if isinstance(inputs, str):
        inputs = [inputs]
    if not isinstance(inputs, list) or not inputs or not all(isinstance(x, str) for x in inputs):
        raise ConfigError(f"venue {name!r}: inputs must be a path or a list of paths", where)
    paths = tuple(_existing(base, x, name, "inputs", where) for x in inputs)
    fmt = v.get("format")
    if fmt is not None and fmt not in formats:
        raise ConfigError(f"venue {name!r}: format must be one of {', '.join(formats)}, got {fmt!r}", where)
    opt = {k: _existing(base, v[k], name, k, where) if k in v else None for k in ("config", "floorplan")}
    return Venue(name, paths, fmt, opt["config"], opt["floorplan"])


def _existing(base: Path, value: object, name: str, key: str, where: str) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"venue {name!r}: {key} must be a path, got {value!r}", where)
    p = Path(value) if Path(value).is_absolute() else base / value
    if not p.exists():
        raise ConfigError(f"venue {name!r}: {key}: {p} does not exist", where)
    if not (p.is_file() or (key == "inputs" and p.is_dir())):
        what = "a regular file or directory" if key == "inputs" else "a regular file"
        raise ConfigError(f"venue {name!r}: {key}: {p} is not {what}", where)
    return p


def _venue_lines(text: str) -> list[int]:
    """The line (from 1) of each ``[[venue]]`` header, in order."""
    return [n for n, line in enumerate(text.splitlines(), 1) if _HEADER.match(line)]
