"""Bare Wi-Fi scans in rmbuild's schema (a ``wifi*`` table, optional ``fixes*``, no poses): read into memory.

`rmbuild localize` accepts scans without any motion data; the ``ingest`` readers need poses or IMU, so
this reader covers the one case they refuse. Rows are checked like ingest checks them (columns, types,
the RSSI range of the ``[ingest]`` config); errors name the file and line.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig
from rmbuild.errors import InputError
from rmbuild.io.formats.rmbuild_schema import SCHEMAS, check_columns, coerce, read_located
from rmbuild.types import FIX_COLUMNS, POSE_COLUMNS, WIFI_COLUMNS, Dataset

#: file-name prefixes of motion data: inputs holding one of them are walks, read by the ingest readers
MOTION_PREFIXES = ("poses", "imu")


def _table(p: Path) -> str | None:
    name = p.name.lower()
    if p.parent.name.lower() == "truth":
        return None
    for t in ("wifi", "fixes", *MOTION_PREFIXES):
        if name.startswith(t) and name.endswith((".csv", ".csv.gz", ".parquet")):
            return t
    return None


def are_bare_scans(files: list[Path]) -> bool:
    """True when ``files`` hold a wifi table and no poses or IMU table (rmbuild's schema)."""
    tables = {_table(f) for f in files}
    return "wifi" in tables and not tables & set(MOTION_PREFIXES)


def _read(files: list[Path], table: str, cfg: IngestConfig) -> pd.DataFrame | None:
    req, opt = SCHEMAS[table]
    parts = []
    for f in files:
        if _table(f) != table:
            continue
        loc = read_located(f, req, opt)
        check_columns(loc, req, opt)
        coerce(loc, {**req, **opt})
        if table == "wifi":
            _check_rssi(loc.df, loc.where, cfg)
        parts.append(loc.df)
    return pd.concat(parts, ignore_index=True) if parts else None


def _check_rssi(df: pd.DataFrame, where: Callable[[int], str], cfg: IngestConfig) -> None:
    rssi = df["rssi_dbm"].to_numpy(dtype=np.float64)
    bad = (rssi < cfg.rssi_min_dbm) | (rssi > cfg.rssi_max_dbm)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"rssi_dbm {rssi[i]!r} outside [{cfg.rssi_min_dbm:g}, {cfg.rssi_max_dbm:g}] dBm", where(i))


def read_bare_scans(files: list[Path], cfg: IngestConfig | None = None) -> Dataset:
    """A :class:`Dataset` with no poses: the scans' readings (``node`` -1) and the fixes, when given (the
    scans' ground truth, interpolated in time along each walk). ``cfg``: the valid RSSI range."""
    cfg = cfg or IngestConfig()
    wifi = _read(files, "wifi", cfg)
    if wifi is None:
        raise InputError("no wifi file among the inputs (expected a file named wifi*.csv or .parquet)",
                         str(files[0].parent))
    for c, default in (("freq_mhz", np.nan), ("ssid", "")):
        if c not in wifi:
            wifi[c] = default
    wifi["node"] = -1
    wifi = wifi.sort_values(["walk_id", "t_s"], kind="stable").reset_index(drop=True)[list(WIFI_COLUMNS)]
    fixes = _read(files, "fixes", cfg)
    if fixes is None:
        fixes = pd.DataFrame({c: pd.Series(dtype=object if c in ("walk_id", "label") else float)
                              for c in FIX_COLUMNS})
    elif "label" not in fixes:
        fixes["label"] = ""
    ids = pd.unique(wifi["walk_id"])
    walks = pd.DataFrame({"walk_id": ids, "device_id": "", "user_id": "", "role": "", "source": "scans"})
    poses = pd.DataFrame({c: pd.Series(dtype=object if c == "walk_id" else float) for c in POSE_COLUMNS})
    return Dataset(walks=walks, poses=poses, wifi=wifi, fixes=fixes[list(FIX_COLUMNS)])
