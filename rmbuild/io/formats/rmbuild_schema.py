"""rmbuild's own input schema: CSV (optionally gzip'd) or Parquet tables, documented in docs/data-format.md.

Files are recognised by name: ``walks*``, ``poses*``, ``wifi*``, ``ble*``, ``fixes*`` (``.csv``, ``.csv.gz``
or ``.parquet``), and inside a ``truth/`` folder ``poses*``, ``aps*``, ``walks*``, ``devices*``, ``users*``,
``landmarks*``, ``beacons*`` and ``venue.json``. Several files of one table are concatenated.
"""

from __future__ import annotations

import csv
import difflib
import gzip
import io
import math
import os
import re
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from rmbuild.config.ingest import IngestConfig
from rmbuild.errors import InputError, one_line
from rmbuild.io.compressed import ExpandsTooFar, open_binary
from rmbuild.io.formats.base import RawImu, RawInput, Reader, register
from rmbuild.io.jsonfile import read_json_file
from rmbuild.limits import MAX_PARQUET_CELLS, MAX_VENUE_BYTES
from rmbuild.pdr import ImuSignals

TABLES = ("walks", "poses", "wifi", "ble", "fixes", "imu")
TRUTH_TABLES = ("poses", "aps", "walks", "devices", "users", "landmarks", "floor_changes", "beacons")
SUFFIXES = (".csv", ".csv.gz", ".parquet")

# column -> kind ("str" | "num"); required and optional columns per table
POSE_ABS = {"walk_id": "str", "t_s": "num", "x_m": "num", "y_m": "num", "heading_rad": "num"}
POSE_INC = {"walk_id": "str", "t_s": "num", "step_length_m": "num", "dheading_rad": "num"}
POSE_OPT = {"yaw_abs_rad": "num", "yaw_abs_sigma_rad": "num", "step_freq_hz": "num", "floor": "str",
            "pressure_hpa": "num"}
SCHEMAS: dict[str, tuple[dict[str, str], dict[str, str]]] = {
    "walks": ({"walk_id": "str"}, {"device_id": "str", "user_id": "str", "role": "str", "floor": "str"}),
    "wifi": (
        {"walk_id": "str", "t_s": "num", "bssid": "str", "rssi_dbm": "num"},
        {"freq_mhz": "num", "ssid": "str"},
    ),
    # BLE beacon readings: the wifi columns, bssid = the beacon's id (MAC), ssid = its iBeacon uuid:major:minor
    "ble": (
        {"walk_id": "str", "t_s": "num", "bssid": "str", "rssi_dbm": "num"},
        {"freq_mhz": "num", "ssid": "str"},
    ),
    "fixes": ({"walk_id": "str", "t_s": "num", "x_m": "num", "y_m": "num"}, {"label": "str"}),
    "truth/poses": ({"walk_id": "str", "t_s": "num", "x_m": "num", "y_m": "num", "heading_rad": "num"}, {}),
}
#: raw phone IMU (one row per sample), turned into per-step poses by the PDR (rmbuild/pdr, [pdr] config)
IMU_REQ = {"walk_id": "str", "t_s": "num", "acc_x_mps2": "num", "acc_y_mps2": "num", "acc_z_mps2": "num"}
IMU_OPT = {"gyro_x_radps": "num", "gyro_y_radps": "num", "gyro_z_radps": "num", "yaw_abs_rad": "num",
           "yaw_accuracy": "num", "pressure_hpa": "num"}
#: the barometer's column (hPa) on poses and imu: read into RawInput.pressure (floor changes), not a pose field
PRESSURE = "pressure_hpa"
#: hPa; plausible air pressures (Dead Sea shore ~1,065; 9 km up ~300): outside, the unit is wrong (Pa, kPa)
PRESSURE_RANGE_HPA = (300.0, 1100.0)
#: optional numeric columns where an empty cell / NaN is allowed (means "not available")
NULLABLE = {"yaw_abs_rad", "yaw_abs_sigma_rad", "step_freq_hz", "freq_mhz", "gyro_x_radps", "gyro_y_radps",
            "gyro_z_radps", "yaw_accuracy", "pressure_hpa"}
ROLES = ("", "map", "test")


def _suffix(p: Path) -> str | None:
    name = p.name.lower()
    for s in SUFFIXES:
        if name.endswith(s):
            return s
    return None


def _table_of(p: Path) -> str | None:
    """'poses', 'truth/aps', 'truth/venue', ... or None when the file is not part of the schema."""
    in_truth = p.parent.name == "truth"
    if in_truth and p.name == "venue.json":
        return "truth/venue"
    if in_truth and p.suffix == ".toml":
        return "truth/provenance"  # e.g. the config simulate used: kept with the input, not ingested
    if _suffix(p) is None:
        return None
    stem = p.name.lower()
    for t in TRUTH_TABLES if in_truth else TABLES:
        if stem.startswith(t):
            return f"truth/{t}" if in_truth else t
    return None


#: columns; no table of the schema (nor a truth table) has more than a dozen
MAX_COLUMNS = 1000
#: cells of a numeric column that mean "no value" (NaN); string columns have none: "NA" is a walk id
_ARROW_STR = pd.ArrowDtype(pa.string())
#: bytes per chunk of the scan for fields starting with a space (bounded memory on any file size)
_SCAN_CHUNK = 1 << 20
NUMERIC_NA = ["", "nan", "NaN", "NAN", "-nan", "NA", "N/A", "n/a", "null", "NULL", "None", "<NA>"]


def _common_dir(files: list[Path]) -> str:
    """The directory holding all ``files`` (for errors about the set of inputs)."""
    try:
        return os.path.commonpath([str(f.parent) for f in files]) if files else "(no input files)"
    except ValueError:  # relative and absolute paths mixed
        return str(files[0].parent)


class _Located:
    """A table read from one file with a way to name its rows: 'file:line' (CSV) or 'file:row N'."""

    def __init__(self, path: Path, df: pd.DataFrame) -> None:
        self.path = path
        self.df = df
        self.csv = _suffix(path) != ".parquet"
        self._lines: list[int] | None = None

    def where(self, i: int) -> str:
        if not self.csv:
            return f"{self.path}:row {i + 1}"
        if self._lines is None:  # only when an error is reported: find the line each record starts on
            self._lines = _record_lines(self.path)
        return f"{self.path}:{self._lines[i]}" if 0 <= i < len(self._lines) else f"{self.path}:record {i + 1}"


def _open_text(path: Path) -> io.TextIOBase:
    return io.TextIOWrapper(open_binary(path), encoding="utf-8", errors="replace", newline="")


def _record_lines(path: Path) -> list[int]:
    """The physical line on which each data record of a CSV file starts (blank lines skipped like pandas;
    quoted fields may span lines)."""
    out: list[int] = []
    csv.field_size_limit(max(csv.field_size_limit(), 1 << 31))  # a cell may be as long as the file
    with _open_text(path) as fh:
        reader = csv.reader(fh, skipinitialspace=True)
        line = 1
        header = True
        for row in reader:
            if row and not header:
                out.append(line)
            header = header and not row
            line = reader.line_num + 1
    return out


def _bad_utf8_line(path: Path) -> str:
    """'line N' of the first line that is not UTF-8 ('' when it cannot be told)."""
    try:
        with open_binary(path) as raw:
            for n, line in enumerate(raw, 1):
                try:
                    line.decode("utf-8")
                except UnicodeDecodeError as e:
                    return f"{n}: byte {e.start + 1} of the line"
    except (OSError, EOFError, zlib.error, ExpandsTooFar):
        pass
    return ""


def _check_width(path: Path) -> None:
    """The header has at most :data:`MAX_COLUMNS` columns and the first data row no more fields than the
    header (pandas would parse every field of a longer first row into a column before complaining)."""
    csv.field_size_limit(max(csv.field_size_limit(), 1 << 31))
    with _open_text(path) as fh:
        reader = csv.reader(fh, skipinitialspace=True)
        header = next((row for row in reader if row), None)
        if header is None:
            return
        if len(header) > MAX_COLUMNS:
            raise InputError(f"{len(header):,} columns: at most {MAX_COLUMNS}", f"{path}:{reader.line_num}")
        line = reader.line_num + 1
        for row in reader:
            if row:
                if len(row) > len(header):
                    raise InputError(f"{len(row)} fields, the header has {len(header)}", f"{path}:{line}")
                return
            line = reader.line_num + 1


def _long_record(path: Path) -> tuple[str, str]:
    """(problem, where) of the first record with more fields than the header."""
    try:
        return _first_long_record(path)
    except ExpandsTooFar as e:
        return e.input_error().problem, str(path)


def _first_long_record(path: Path) -> tuple[str, str]:
    csv.field_size_limit(max(csv.field_size_limit(), 1 << 31))
    with _open_text(path) as fh:
        reader = csv.reader(fh, skipinitialspace=True)
        width, line = None, 1
        for row in reader:
            if row and width is None:
                width = len(row)
            elif row and width is not None and len(row) > width:
                return f"{len(row)} fields, the header has {width}", f"{path}:{line}"
            line = reader.line_num + 1
    return "more fields than the header", str(path)


def _has_initial_space(path: Path) -> bool:
    """Whether a field of the file may start with a space or a tab (a comma or a line break followed by one),
    which pandas' ``skipinitialspace`` then skips; without any, the option changes nothing and costs a third
    of the parse (bench/bench_ingest.py), so it is left off. A compressed file is taken to have some."""
    if str(path).lower().endswith(".gz"):
        return True
    prev = b"\n"  # the first field starts a line
    with path.open("rb") as fh:
        while chunk := fh.read(_SCAN_CHUNK):
            buf, prev = prev + chunk, chunk[-1:]
            if buf.find(b" ") < 0 and buf.find(b"\t") < 0:  # memchr: the usual case costs ~nothing
                continue
            a = np.frombuffer(buf, dtype=np.uint8)
            ws = np.flatnonzero((a[1:] == 32) | (a[1:] == 9))  # a[ws]: the byte before each space or tab
            if np.isin(a[ws], (44, 10, 13)).any():
                return True
    return False


def read_located(path: Path, required: dict[str, str] | None = None,
                 optional: dict[str, str] | None = None) -> _Located:
    """Read one table file; string columns of the schema stay text ("00001", "NA"), numeric ones are numbers."""
    return _Located(path, _read_file(path, {**(required or {}), **(optional or {})}))


def _read_file(path: Path, schema: dict[str, str] | None = None) -> pd.DataFrame:
    try:
        if _suffix(path) == ".parquet":
            _check_parquet_size(path)
            return pd.read_parquet(path)
        _check_width(path)
        with warnings.catch_warnings(), open_binary(path) as source:  # .gz: gunzipped, at most MAX_GUNZIP_BYTES
            # a first data row longer than the header: pandas would make an index of it, or drop cells
            warnings.simplefilter("error", pd.errors.ParserWarning)
            if schema is None:
                return pd.read_csv(source, skipinitialspace=True, keep_default_na=True, na_values=[""],
                                   index_col=False, compression=None)
            strs = [c for c, k in schema.items() if k == "str"]
            # read as Arrow strings (as fast as no dtype; dtype=str was 2x slower), then the usual str dtype
            df = pd.read_csv(source, skipinitialspace=_has_initial_space(path), dtype={c: _ARROW_STR for c in strs},
                             compression=None,
                             keep_default_na=False, na_values={c: NUMERIC_NA for c, k in schema.items() if k != "str"},
                             index_col=False)
            for c in strs:
                if c in df.columns:
                    df[c] = df[c].astype(str)
            return df
    except InputError:
        raise
    except ExpandsTooFar as e:
        raise e.input_error() from None
    except pd.errors.ParserWarning:
        raise InputError(*_long_record(path)) from None
    except pd.errors.EmptyDataError:
        raise InputError("empty file (no header)", str(path)) from None
    except pd.errors.ParserError as e:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(e))
        if m:
            raise InputError(f"{m.group(3)} fields, the header has {m.group(1)}", f"{path}:{m.group(2)}") from None
        raise InputError(f"malformed CSV ({one_line(str(e))})", str(path)) from None
    except (gzip.BadGzipFile, EOFError, zlib.error, OSError) as e:
        kind = "gzip" if str(path).endswith(".gz") else "file"
        raise InputError(f"unreadable {kind} ({type(e).__name__}: {e})", str(path)) from None
    except UnicodeDecodeError as e:
        line = _bad_utf8_line(path)
        where = f"{path}:{line.split(':')[0]}" if line else str(path)
        what = f" ({line.split(': ', 1)[1]})" if line else ""
        raise InputError(f"not UTF-8 text{what}: {e.reason}", where) from None
    except MemoryError:
        raise InputError("file too large to read into memory", str(path)) from None
    except Exception as e:  # pyarrow raises ArrowInvalid and friends for corrupt Parquet
        raise InputError(f"unreadable Parquet ({type(e).__name__}: {e})", str(path)) from None


def _check_parquet_size(path: Path) -> None:
    """A Parquet table holds at most :data:`MAX_PARQUET_CELLS` cells (rows × columns, from its footer, before
    any data is decoded: a few KB of run-length-encoded constants can decode to GBs)."""
    import pyarrow.parquet as pq

    md = pq.ParquetFile(path).metadata
    if md.num_rows * max(md.num_columns, 1) > MAX_PARQUET_CELLS:
        raise InputError(f"{md.num_rows:,} rows x {md.num_columns} columns: at most {MAX_PARQUET_CELLS:,} cells in "
                         "a Parquet input table (split it into several files of the table)", str(path))


def _as_stored(df: pd.DataFrame) -> pd.DataFrame:
    """A table kept as given (truth tables): columns of mixed or oversized values (e.g. an integer beyond
    64 bits) become text, so that the workspace can store them."""
    for c in df.columns:
        if df[c].dtype == object:
            df[c] = df[c].map(lambda v: v if isinstance(v, str) or v is None else str(v))
    return df


def check_columns(loc: _Located, required: dict[str, str], optional: dict[str, str]) -> None:
    cols = [str(c) for c in loc.df.columns]
    known = list(required) + list(optional)
    for c in cols:
        if c not in known:
            near = difflib.get_close_matches(c, known, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else f" (known: {', '.join(known)})"
            raise InputError(f"unknown column {c[:80]!r}{hint}", f"{loc.path}:1" if loc.csv else str(loc.path))
    for c in required:
        if c not in cols:
            near = difflib.get_close_matches(c, cols, n=1)
            hint = f" (found {near[0]!r}: misspelt?)" if near else f" (found: {', '.join(cols)[:200] or 'none'})"
            raise InputError(f"missing required column {c!r}{hint}", f"{loc.path}:1" if loc.csv else str(loc.path))
    if len(loc.df) == 0:
        raise InputError("no data rows", str(loc.path))


def _numbers(s: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """A column as float64 and a mask of the cells that are not numbers; integers beyond the float range
    (a 400-digit cell) become +-inf, missing values NaN."""
    if pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
        try:
            return s.to_numpy(dtype=np.float64), np.zeros(len(s), bool)
        except OverflowError:
            pass
    else:
        try:
            num = pd.to_numeric(s, errors="coerce")
            return num.to_numpy(dtype=np.float64), (num.isna() & s.notna()).to_numpy()
        except (OverflowError, ValueError, TypeError):
            pass
    pairs = [_one_number(v) for v in s]
    return np.array([p[0] for p in pairs], dtype=np.float64), np.array([p[1] for p in pairs], dtype=bool)


def _one_number(v: object) -> tuple[float, bool]:
    """(value, not a number) of one cell."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return math.nan, False
    if isinstance(v, bool):
        return math.nan, True
    try:
        return float(v), False  # type: ignore[arg-type]
    except OverflowError:  # an int beyond the float range
        return (math.inf if v > 0 else -math.inf), False  # type: ignore[operator]
    except (ValueError, TypeError):
        return math.nan, True


def coerce(loc: _Located, columns: dict[str, str]) -> None:
    """Check types and finiteness column by column; convert in place."""
    df = loc.df
    for c, kind in columns.items():
        if c not in df.columns:
            continue
        s = df[c]
        if kind == "str":
            # Parquet may hold None; ids given as numbers in a typed file become their text ("1")
            text = s.where(~s.isna(), "").astype(str) if s.hasnans or s.dtype != "str" else s
            if c in ("walk_id", "bssid"):
                bad = (text.str.strip() == "").to_numpy()
                if bad.any():
                    raise InputError(f"empty {c}", loc.where(int(np.argmax(bad))))
            if text is not s:
                df[c] = text
            continue
        v, bad = _numbers(s)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"column {c}: not a number: {str(s.iloc[i])[:60]!r}", loc.where(i))
        nan = np.isnan(v)
        if nan.any() and c not in NULLABLE:
            raise InputError(f"column {c}: empty or NaN value", loc.where(int(np.argmax(nan))))
        inf = np.isinf(v)
        if inf.any():
            raise InputError(f"column {c}: infinite value", loc.where(int(np.argmax(inf))))
        if s.dtype != np.float64:
            df[c] = v


def _concat(parts: list[_Located]) -> tuple[pd.DataFrame, Callable[[int], str]]:
    """Concatenate located tables; the returned function maps a row of the result to its source."""
    df = pd.concat([p.df for p in parts], ignore_index=True)
    offsets = np.cumsum([0] + [len(p.df) for p in parts])

    def where(i: int) -> str:
        k = int(np.searchsorted(offsets, i, side="right") - 1)
        return parts[k].where(i - int(offsets[k]))

    return df, where


def _integrate_increments(df: pd.DataFrame) -> pd.DataFrame:
    """Per-step increments -> poses. Row 0 of a walk is the start (0, 0, 0); its increments are ignored.

    Row k >= 1: heading_k = heading_{k-1} + dheading_k, then a step of step_length_m along heading_k.
    """
    out = df.copy()
    g = out.groupby("walk_id", sort=False)
    first = g.cumcount().to_numpy() == 0
    dth = np.where(first, 0.0, out["dheading_rad"].to_numpy())
    length = np.where(first, 0.0, out["step_length_m"].to_numpy())
    walk = out["walk_id"].to_numpy()
    heading = pd.Series(dth).groupby(walk, sort=False).cumsum().to_numpy()
    dx = length * np.cos(heading)
    dy = length * np.sin(heading)
    out["x_m"] = pd.Series(dx).groupby(walk, sort=False).cumsum().to_numpy()
    out["y_m"] = pd.Series(dy).groupby(walk, sort=False).cumsum().to_numpy()
    out["heading_rad"] = heading
    return out.drop(columns=["step_length_m", "dheading_rad"])


def _column(df: pd.DataFrame, name: str, rows: np.ndarray) -> np.ndarray:
    """float column ``name`` at ``rows``; NaN when the optional column is absent."""
    return df[name].to_numpy(float)[rows] if name in df.columns else np.full(len(rows), np.nan)


def _pressure(df: pd.DataFrame, pressure: dict[str, tuple[np.ndarray, np.ndarray]],
              where: Callable[[int], str]) -> pd.DataFrame:
    """Move the table's :data:`PRESSURE` readings (non-empty cells) into ``pressure`` (walk -> times, hPa);
    the table without the column. A reading outside :data:`PRESSURE_RANGE_HPA` is an input error."""
    if PRESSURE not in df:
        return df
    p = df[PRESSURE].to_numpy(float)
    ok = np.isfinite(p)
    bad = np.flatnonzero(ok & ((p < PRESSURE_RANGE_HPA[0]) | (p > PRESSURE_RANGE_HPA[1])))
    if len(bad):
        raise InputError(f"{PRESSURE} {p[bad[0]]:g} outside {PRESSURE_RANGE_HPA} hPa (a barometer's reading "
                         "in hPa = mbar?)", where(int(bad[0])))
    for wid, rows in df[ok].groupby("walk_id", sort=False).indices.items():
        part = df[ok].iloc[rows]
        pressure[str(wid)] = (part["t_s"].to_numpy(float), part[PRESSURE].to_numpy(float))
    return df.drop(columns=[PRESSURE])


def _read_imu(files: list[Path], pressure: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, RawImu]:
    """Each walk's raw phone IMU from the ``imu`` files (times must increase within a walk)."""
    out: dict[str, RawImu] = {}
    for f in files:
        loc = read_located(f, IMU_REQ, IMU_OPT)
        check_columns(loc, IMU_REQ, IMU_OPT)
        coerce(loc, {**IMU_REQ, **IMU_OPT})
        df = loc.df
        _pressure(df, pressure, loc.where)
        first = 2 if loc.csv else 1   # CSV line of row 0 (after the header) / Parquet row number
        for wid, rows in df.groupby("walk_id", sort=False).indices.items():
            if wid in out:
                raise InputError(f"imu: walk {wid!r} also in {out[wid].source}", loc.where(int(rows[0])))
            t = df["t_s"].to_numpy(float)[rows]
            back = np.flatnonzero(np.diff(t) <= 0)
            if len(back):
                raise InputError(f"imu: time not increasing in walk {wid!r}", loc.where(int(rows[back[0] + 1])))
            acc = np.column_stack([_column(df, f"acc_{c}_mps2", rows) for c in "xyz"])
            gyro = np.column_stack([_column(df, f"gyro_{c}_radps", rows) for c in "xyz"])
            g_ok = np.isfinite(gyro).all(axis=1)
            yaw = _column(df, "yaw_abs_rad", rows)
            y_ok = np.isfinite(yaw)
            flag = _column(df, "yaw_accuracy", rows)
            signals = ImuSignals(
                t_acc_s=t, acc_mps2=acc, t_yaw_s=t[y_ok], yaw_abs_rad=yaw[y_ok],
                yaw_accuracy=np.nan_to_num(flag[y_ok], nan=-1.0).astype(np.int64),
                t_gyro_s=t[g_ok], gyro_radps=gyro[g_ok],
            )
            lines = rows + first
            out[str(wid)] = RawImu(signals, str(f), {"acc": lines, "gyro": lines[g_ok], "yaw": lines[y_ok]},
                                   "line" if loc.csv else "row")
    return out


@register
class RmbuildSchemaReader(Reader):
    name = "rmbuild"
    description = "rmbuild's own CSV/Parquet schema (walks, poses, wifi, ble, fixes + optional truth/)"

    @classmethod
    def sniff(cls, files: list[Path]) -> bool:
        tables = {_table_of(f) for f in files}
        return "poses" in tables or "wifi" in tables

    def read(self, files: list[Path], cfg: IngestConfig) -> RawInput:
        by_table: dict[str, list[Path]] = {}
        skipped = 0
        for f in files:
            t = _table_of(f)
            if t is None:
                skipped += 1
                continue
            by_table.setdefault(t, []).append(f)
        inputs = _common_dir(files)
        if "wifi" not in by_table:
            raise InputError("no wifi file among the inputs (expected a file named wifi*.csv or .parquet)", inputs)
        if "poses" not in by_table and "imu" not in by_table:
            raise InputError("no poses file among the inputs (expected poses*.csv or .parquet, or raw phone "
                             "IMU in imu*.csv or .parquet)", inputs)
        where: dict[str, Callable[[int], str]] = {}

        # poses: absolute or increments, one mode per file
        parts = []
        for f in by_table.get("poses", []):
            loc = read_located(f, {**POSE_ABS, **POSE_INC, **POSE_OPT})
            cols = set(map(str, loc.df.columns))
            mode = POSE_INC if ("step_length_m" in cols or "dheading_rad" in cols) else POSE_ABS
            check_columns(loc, mode, POSE_OPT)
            coerce(loc, {**mode, **POSE_OPT})
            if mode is POSE_INC:
                loc.df = _integrate_increments(loc.df)
            parts.append(loc)
        pressure: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        imu = _read_imu(by_table.get("imu", []), pressure)
        if parts:
            poses, where["poses"] = _concat(parts)
            poses = _pressure(poses, pressure, where["poses"])
        else:
            poses = pd.DataFrame({c: pd.Series(dtype=object if c == "walk_id" else np.float64) for c in POSE_ABS})

        tables: dict[str, pd.DataFrame] = {}
        for t in ("wifi", "ble", "fixes", "walks", "truth/poses"):
            if t not in by_table:
                continue
            req, opt = SCHEMAS[t]
            parts = []
            for f in by_table[t]:
                loc = read_located(f, req, opt)
                check_columns(loc, req, opt)
                coerce(loc, {**req, **opt})
                parts.append(loc)
            tables[t], where[t] = _concat(parts)

        wifi = tables["wifi"]
        fixes = tables.get("fixes", pd.DataFrame({c: [] for c in ("walk_id", "t_s", "x_m", "y_m", "label")}))
        walks = tables.get("walks")
        if walks is None:
            ids = pd.unique(np.r_[poses["walk_id"].to_numpy(dtype=object), np.array(list(imu), dtype=object)])
            walks = pd.DataFrame({"walk_id": ids, "device_id": "", "user_id": "", "role": ""})
        else:
            bad_role = ~walks.get("role", pd.Series("", index=walks.index)).isin(ROLES)
            if bad_role.any():
                i = int(np.argmax(bad_role.to_numpy()))
                raise InputError(
                    f"role must be one of {list(ROLES)}, got {walks['role'].iloc[i]!r}", where["walks"](i)
                )
        raw = RawInput(
            walks=walks,
            poses=poses,
            wifi=wifi,
            fixes=fixes,
            truth_poses=tables.get("truth/poses"),
            imu=imu,
            where=where,
            pressure=pressure,
            ble=tables.get("ble"),
        )
        if skipped:
            raw.skipped["unrecognised file"] = skipped
        for t, fs in by_table.items():
            if t == "truth/provenance":
                continue
            if t == "truth/venue":
                raw.venue = read_json_file(fs[0], MAX_VENUE_BYTES, "venue.json")
            elif t.startswith("truth/") and t != "truth/poses":
                name = t.removeprefix("truth/")
                df = pd.concat([_as_stored(_read_file(f)) for f in fs], ignore_index=True)
                if name == "aps":
                    raw.truth_aps = df
                else:
                    raw.truth_extra[name] = df
        return raw
