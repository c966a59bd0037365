"""Anchors: known building-frame positions of walks at given times (walk_id, t_s, x_m, y_m).

:func:`read_anchors` checks the file on its own (columns, numbers, positions within
:data:`MAX_ANCHOR_COORD_M`); :func:`check_anchors` checks it against the ingested walks (known walk, time
within the walk, anchors of one walk that the walk could not have joined). Every error names the file
and its line (CSV) or row (Parquet, counted from 1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.errors import InputError
from rmbuild.io.formats.rmbuild_schema import check_columns, coerce, read_located
from rmbuild.limits import MAX_ANCHORS, MAX_COORD_M
from rmbuild.types import Dataset

ANCHOR_SCHEMA = {"walk_id": "str", "t_s": "num", "x_m": "num", "y_m": "num"}
#: m; |x| or |y| beyond this is no building-frame position (the limit of every position)
MAX_ANCHOR_COORD_M = MAX_COORD_M
#: m; allowance for the anchors' own position error when two anchors of one walk are compared
ANCHOR_SLACK_M = 5.0
#: 1; allowance on the walked distance between two anchors (PDR step lengths err by well under 50 %)
WALKED_SLACK = 1.5


@dataclass
class Anchors:
    """An anchors file: ``table`` (walk_id, t_s, x_m, y_m) and ``where(i)``, "file:line" of row i."""

    table: pd.DataFrame
    where: Callable[[int], str]

    def __len__(self) -> int:
        return len(self.table)


def read_anchors(path: str | Path) -> Anchors:
    """The anchors of a CSV/Parquet file; InputError naming file and line on bad input."""
    p = Path(path)
    if not p.is_file():
        raise InputError("anchors file not found", str(p))
    loc = read_located(p, ANCHOR_SCHEMA, {"label": "str"})
    check_columns(loc, ANCHOR_SCHEMA, {"label": "str"})
    if len(loc.df) > MAX_ANCHORS:
        raise InputError(f"{len(loc.df):,} anchors: at most {MAX_ANCHORS:,} in one file (known positions are "
                         "landmarks, not a track)", loc.where(MAX_ANCHORS))
    coerce(loc, {**ANCHOR_SCHEMA, "label": "str"})
    df = loc.df[list(ANCHOR_SCHEMA)].reset_index(drop=True)
    xy = df[["x_m", "y_m"]].to_numpy(float)
    far = np.abs(xy).max(axis=1) > MAX_ANCHOR_COORD_M
    if far.any():
        i = int(np.argmax(far))
        raise InputError(f"anchor position ({xy[i, 0]:.6g}, {xy[i, 1]:.6g}) m is more than "
                         f"{MAX_ANCHOR_COORD_M:g} m from the origin: not a building-frame position", loc.where(i))
    return Anchors(df, loc.where)


def check_anchors(anchors: Anchors, ds: Dataset, max_gap_s: float = 0.0) -> None:
    """Check anchors against the ingested walks: a known walk, a time at most ``max_gap_s`` outside the
    walk's poses, and no two anchors of one walk further apart than the walk went between them."""
    df = anchors.table
    poses = ds.poses
    pw = poses["walk_id"].astype(str).to_numpy()
    walks = pd.Index(pd.unique(pw))
    t_all = poses["t_s"].to_numpy(float)
    xy_all = poses[["x_m", "y_m"]].to_numpy(float)
    for wid, rows in df.groupby(df["walk_id"].astype(str), sort=False).indices.items():
        if wid not in walks:
            raise InputError(f"anchor of unknown walk {wid!r}", anchors.where(int(rows[0])))
        sel = pw == wid
        t, xy = t_all[sel], xy_all[sel]
        ta = df["t_s"].to_numpy(float)[rows]
        out = (ta < t[0] - max_gap_s) | (ta > t[-1] + max_gap_s)
        if out.any():
            i = int(rows[np.argmax(out)])
            raise InputError(f"anchor time t_s={df['t_s'].iloc[i]:.6g} is outside walk {wid!r}'s poses "
                             f"[{t[0]:.6g}, {t[-1]:.6g}] s (by more than {max_gap_s:g} s)", anchors.where(i))
        _check_consistent(anchors, rows, t, xy, wid)


def _check_consistent(anchors: Anchors, rows: np.ndarray, t: np.ndarray, xy: np.ndarray, wid: str) -> None:
    """Consecutive anchors of one walk must be reachable: their distance at most the distance walked
    between their times (times :data:`WALKED_SLACK`) plus :data:`ANCHOR_SLACK_M`."""
    if len(rows) < 2:
        return
    df = anchors.table
    order = rows[np.argsort(df["t_s"].to_numpy(float)[rows], kind="stable")]
    walked = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    s = np.interp(df["t_s"].to_numpy(float)[order], t, walked)
    a = df[["x_m", "y_m"]].to_numpy(float)[order]
    gap = np.hypot(*np.diff(a, axis=0).T)
    allowed = WALKED_SLACK * np.diff(s) + ANCHOR_SLACK_M
    bad = gap > allowed
    if bad.any():
        k = int(np.argmax(bad))
        i, j = int(order[k]), int(order[k + 1])
        raise InputError(
            f"anchors of walk {wid!r} contradict each other: this one is {gap[k]:.1f} m from the one at "
            f"{anchors.where(i)} but the walk goes only {np.diff(s)[k]:.1f} m between their times",
            anchors.where(j))
