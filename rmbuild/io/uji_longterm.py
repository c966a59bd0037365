"""The UJI long-term Wi-Fi fingerprinting data set, read into memory.

G. M. Mendoza-Silva, P. Richter, J. Torres-Sospedra, E. S. Lohan, J. Huerta, "Long-Term WiFi
Fingerprinting Dataset for Research on Robust Indoor Positioning", Data 3(1):3, 2018. A university
library surveyed monthly for 25 months (floors 3 and 5) with one phone; the layout is
``db/MM/{trn|tst}NN{rss|crd|tms|ids}.csv.gz``, and row i of the four files is one fingerprint:

* ``rss``: one column per AP (620), dBm, **100 = not detected**;
* ``crd``: x, y (metres, the survey's frame), floor;
* ``tms``: the time as the digits YYYYMMDDhhmmssmmm;
* ``ids``: the sample id.

AP columns carry no BSSID; they are named ``WAP001`` .. ``WAP620`` here (the column order is the same in
every file of the data set).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.errors import InputError

#: the value the data set writes for "AP not detected"
NOT_DETECTED = 100
#: set names: trn01, tst10, ...
SET_NAME = re.compile(r"^(trn|tst)(\d{2})rss\.csv(\.gz)?$")


@dataclass
class UjiSet:
    """One set of fingerprints. ``rss_dbm`` float32 (n, n_ap), NaN = not detected; ``xy`` float64 (n, 2) m;
    ``floor`` int64 (n,); ``t_s`` float64 (n,) Unix time (s, UTC as written); ``ids`` int64 (n,);
    ``bssids`` (n_ap,) column names; ``month`` and ``name`` say which set it is."""

    month: int
    name: str
    rss_dbm: np.ndarray
    xy: np.ndarray
    floor: np.ndarray
    t_s: np.ndarray
    ids: np.ndarray
    bssids: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)

    def rows(self, mask: np.ndarray) -> UjiSet:
        return UjiSet(self.month, self.name, self.rss_dbm[mask], self.xy[mask], self.floor[mask], self.t_s[mask],
                      self.ids[mask], self.bssids)


def month_dir(db: str | Path, month: int) -> Path:
    return Path(db) / f"{month:02d}"


def set_names(db: str | Path, month: int, kind: str | None = None) -> list[str]:
    """The sets of a month (``trn01``, ``tst01``, ...), sorted; ``kind`` "trn" or "tst" keeps one kind."""
    d = month_dir(db, month)
    if not d.is_dir():
        raise InputError("no such month folder", str(d))
    names = sorted(m[1] + m[2] for f in d.iterdir() if (m := SET_NAME.match(f.name)))
    return [n for n in names if kind is None or n.startswith(kind)]


def _file(d: Path, name: str, part: str) -> Path:
    for suffix in (".csv.gz", ".csv"):
        p = d / f"{name}{part}{suffix}"
        if p.is_file():
            return p
    raise InputError(f"missing the {part} file of set {name}", str(d / f"{name}{part}.csv.gz"))


def _numbers(path: Path, ncols: int | None = None) -> np.ndarray:
    """The file's comma-separated numbers as float64 (rows, cols); a ragged or non-numeric row is an error."""
    try:
        df = pd.read_csv(path, header=None)
    except (pd.errors.ParserError, UnicodeDecodeError, EOFError, OSError) as e:
        raise InputError(f"unreadable ({type(e).__name__}: {str(e)[:120]})", str(path)) from None
    if ncols is not None and df.shape[1] != ncols:
        raise InputError(f"expected {ncols} columns, found {df.shape[1]}", f"{path}:1")
    numeric = all(pd.api.types.is_numeric_dtype(t) for t in df.dtypes)
    vals = (df if numeric else df.apply(pd.to_numeric, errors="coerce")).to_numpy(dtype=np.float64)
    bad = ~np.isfinite(vals)
    if bad.any():
        i = int(np.argmax(bad.any(axis=1)))
        raise InputError(f"not a number: {df.iloc[i, int(np.argmax(bad[i]))]!r}", f"{path}:{i + 1}")
    return vals


def read_set(db: str | Path, month: int, name: str) -> UjiSet:
    """Read set ``name`` (e.g. "trn01") of ``month`` (1..25) from the data set's ``db`` folder."""
    d = month_dir(db, month)
    rss = _numbers(_file(d, name, "rss"))
    crd = _numbers(_file(d, name, "crd"), 3)
    tms = _numbers(_file(d, name, "tms"), 1)[:, 0]
    ids = _numbers(_file(d, name, "ids"), 1)[:, 0]
    n = len(rss)
    for part, a in (("crd", crd), ("tms", tms), ("ids", ids)):
        if len(a) != n:
            raise InputError(f"{len(a)} rows, but the rss file has {n}", str(_file(d, name, part)))
    bad = (rss != NOT_DETECTED) & ((rss > 0) | (rss < -120))
    if bad.any():
        i = int(np.argmax(bad.any(axis=1)))
        raise InputError(f"RSSI {rss[i, int(np.argmax(bad[i]))]:g} dBm is neither a reading nor {NOT_DETECTED}",
                         f"{_file(d, name, 'rss')}:{i + 1}")
    rss32 = np.where(rss == NOT_DETECTED, np.nan, rss).astype(np.float32)
    stamp = pd.to_datetime(tms.astype(np.int64).astype(str), format="%Y%m%d%H%M%S%f", errors="coerce")
    if stamp.isna().any():
        i = int(np.argmax(stamp.isna()))
        raise InputError(f"not a YYYYMMDDhhmmssmmm time: {int(tms[i])}", f"{_file(d, name, 'tms')}:{i + 1}")
    t_s = (stamp - pd.Timestamp("1970-01-01")).total_seconds().to_numpy(dtype=np.float64)
    bssids = np.array([f"WAP{j + 1:03d}" for j in range(rss.shape[1])], dtype=object)
    return UjiSet(month, name, rss32, crd[:, :2].copy(), crd[:, 2].astype(np.int64), t_s, ids.astype(np.int64),
                  bssids)

