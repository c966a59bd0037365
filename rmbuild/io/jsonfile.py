"""JSON files a user gives (floor plans, MS ILC's floor_info.json, a venue.json): bounded size and nesting,
finite numbers only; every problem is one :class:`InputError` naming the file (and the line when the JSON
itself is malformed)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from rmbuild.errors import InputError
from rmbuild.io.compressed import read_at_most
from rmbuild.limits import MAX_JSON_DEPTH


class _NotFinite(ValueError):
    pass


def _finite(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise _NotFinite(f"number {text[:40]} is beyond the float range")
    return v


def _constant(text: str) -> float:
    raise _NotFinite(f"{text} is not a number JSON allows")


def parse_json(data: bytes | str, where: str) -> Any:
    """The JSON document ``data``: InputError naming ``where`` when it is malformed (with its line), holds a
    NaN, an infinity or a number beyond the float range, or nests deeper than :data:`MAX_JSON_DEPTH`."""
    try:
        doc = json.loads(data, parse_float=_finite, parse_constant=_constant)
    except _NotFinite as e:
        raise InputError(f"invalid JSON: {e}", where) from None
    except RecursionError:
        raise InputError(f"invalid JSON: nested deeper than {MAX_JSON_DEPTH} levels", where) from None
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg} (column {e.colno})", f"{where}:{e.lineno}") from None
    except (UnicodeDecodeError, ValueError) as e:
        raise InputError(f"invalid JSON: {str(e)[:200]}", where) from None
    if _depth_over(doc, MAX_JSON_DEPTH):
        raise InputError(f"invalid JSON: nested deeper than {MAX_JSON_DEPTH} levels", where)
    return doc


def read_json_file(path: str | Path, max_bytes: int, what: str) -> Any:
    """The JSON document in the file ``path`` (``what`` it is, for messages), at most ``max_bytes`` long."""
    p = Path(path)
    try:
        data = read_at_most(p, max_bytes)
        if len(data) > max_bytes:
            raise InputError(f"{what} larger than {max_bytes / 2**20:g} MB", str(p))
    except OSError as e:
        raise InputError(f"cannot read {what}: {e.strerror or e}", str(p)) from None
    return parse_json(data, str(p))


def _depth_over(doc: Any, limit: int) -> bool:
    """Whether ``doc`` nests lists and objects deeper than ``limit`` (walked without recursion)."""
    stack = [(doc, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        if isinstance(v, list):
            if d > limit:
                return True
            stack.extend((x, d + 1) for x in v if isinstance(x, (list, dict)))
    return False
