"""Reading an anchors file (walk_id, t_s, x_m, y_m: known building-frame positions of walks)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from rmbuild.errors import InputError
from rmbuild.io.formats.rmbuild_schema import _check_columns, _coerce, _Located, _read_file

ANCHOR_SCHEMA = {"walk_id": "str", "t_s": "num", "x_m": "num", "y_m": "num"}


def read_anchors(path: str | Path) -> pd.DataFrame:
    """Anchors as a DataFrame (walk_id, t_s, x_m, y_m); InputError naming file and row on bad input."""
    p = Path(path)
    if not p.is_file():
        raise InputError("anchors file not found", str(p))
    loc = _Located(p, _read_file(p))
    _check_columns(loc, ANCHOR_SCHEMA, {"label": "str"})
    _coerce(loc, {**ANCHOR_SCHEMA, "label": "str"})
    return loc.df[list(ANCHOR_SCHEMA)].reset_index(drop=True)
