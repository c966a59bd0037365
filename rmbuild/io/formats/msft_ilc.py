"""Reader for Microsoft Indoor Location Competition 2.0 traces (``.txt`` / ``.txt.gz``, tab-separated).

One trace = one walk (walk_id = file name without ``.txt``/``.txt.gz``). TYPE_ACCELEROMETER, TYPE_GYROSCOPE
and TYPE_ROTATION_VECTOR are the walk's raw IMU (ingest turns them into per-step poses); TYPE_WIFI rows become
readings after the stale-row filter; TYPE_BEACON rows become BLE readings (beacon id = MAC); TYPE_WAYPOINT rows
are ground-truth fixes in the floor's frame (never fed to the optimiser as such). Every other line type is skipped
with a count. docs/formats-real.md describes the format and the choices made here.
"""

from __future__ import annotations

import csv
import gzip
import io
import re
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig, MsftIlcConfig
from rmbuild.errors import InputError
from rmbuild.io.compressed import read_bytes
from rmbuild.io.floor_image import attach_image, read_image
from rmbuild.io.formats.base import RawImu, RawInput, Reader, register
from rmbuild.io.jsonfile import read_json_file
from rmbuild.limits import MAX_FLOOR_INFO_BYTES, MAX_PLAN_BYTES, MAX_PLAN_SIZE_M, MAX_TRACE_BYTES
from rmbuild.limits import MAX_TRACE_LINE_BYTES as MAX_LINE_BYTES
from rmbuild.pdr import ImuSignals, accuracy_flags, rotation_vector_quat, yaw_from_quat

FORMAT_NAME = "msft-ilc"
#: files that sit beside the traces in the published layout; ignored (with a note) when passed in
COMPANION_FILES = ("floor_info.json", "floor_image.png", "geojson_map.json")
_DATA_LINE = re.compile(r"^\d{10,16}\tTYPE_[A-Z0-9_]+(\t|$)")
#: digits of a time field: unix milliseconds have 13 (16 reach the year 318857); more overflow int64
MAX_TIME_DIGITS = 16

#: line type -> number of tab-separated fields (time, type, values...)
_USED = {
    "TYPE_ACCELEROMETER": 6,    # x y z (m/s²) accuracy
    "TYPE_GYROSCOPE": 6,        # x y z (rad/s) accuracy
    "TYPE_ROTATION_VECTOR": 6,  # x y z (quaternion vector part) accuracy
    "TYPE_WIFI": 7,             # ssid bssid rssi_dBm freq_MHz last_seen_unix_ms
    "TYPE_BEACON": 10,          # uuid major minor tx_power_dBm rssi_dBm distance_m mac unix_ms
    "TYPE_WAYPOINT": 4,         # x y (m)
}


def _is_trace_name(p: Path) -> bool:
    n = p.name.lower()
    return n.endswith(".txt") or n.endswith(".txt.gz")


def _walk_id(p: Path) -> str:
    n = p.name
    for suf in (".txt.gz", ".TXT.GZ", ".txt", ".TXT"):
        if n.endswith(suf):
            return n[: -len(suf)]
    return p.stem


def _read_bytes(p: Path) -> bytes:
    """The whole file (gunzipped when the name ends in .gz), at most MAX_TRACE_BYTES; problems -> InputError."""
    return read_bytes(p, MAX_TRACE_BYTES, "trace")


def _first_lines(p: Path, n: int = 3) -> list[str]:
    """Up to ``n`` first non-empty lines, cheaply (empty list when unreadable)."""
    try:
        opener = gzip.open if p.name.lower().endswith(".gz") else open
        out: list[str] = []
        with opener(p, "rt", encoding="utf-8", errors="replace") as fh:  # type: ignore[operator]
            for _ in range(50):
                line = fh.readline(MAX_LINE_BYTES + 1)
                if not line:
                    break
                if line.strip():
                    out.append(line.rstrip("\r\n"))
                    if len(out) >= n:
                        break
        return out
    except (OSError, EOFError, zlib.error):
        return []


def _looks_like_trace(lines: list[str]) -> bool:
    if not lines:
        return False
    first = lines[0]
    return first.startswith("#\tstartTime:") or bool(_DATA_LINE.match(first))


@dataclass
class _Stream:
    """Rows of one line type, sorted by time: t_s (n,), values (n, k) float, accuracy (n,), line (n,)."""

    t_s: np.ndarray
    values: np.ndarray
    accuracy: np.ndarray
    line: np.ndarray


@dataclass
class _Rows:
    """One used line type in file order: unix ms, numeric fields, text fields, 1-based line numbers."""

    t_ms: np.ndarray
    num: np.ndarray          # (n, k) float64, the type's numeric value fields (see _NUM_COLS)
    text: np.ndarray         # (n, j) object (str), the type's text fields (Wi-Fi: ssid, bssid)
    line: np.ndarray


@dataclass
class _Trace:
    walk_id: str
    device_id: str
    floor: str
    acc: _Stream
    gyro: _Stream
    rot: _Stream
    wifi: pd.DataFrame
    wifi_lines: np.ndarray
    waypoints: pd.DataFrame
    waypoint_lines: np.ndarray
    skipped: Counter
    n_wifi_stale: int
    n_wifi_dup: int = 0
    site: str = ""  # the header's SiteID (one building)
    ble: pd.DataFrame = field(default_factory=pd.DataFrame)   # BLE readings (TYPE_BEACON)
    ble_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    n_ble_dup: int = 0


#: per used type: field positions of the numeric values and of the text values
_NUM_COLS = {
    "TYPE_ACCELEROMETER": [2, 3, 4, 5],
    "TYPE_GYROSCOPE": [2, 3, 4, 5],
    "TYPE_ROTATION_VECTOR": [2, 3, 4, 5],
    "TYPE_WIFI": [4, 5, 6],
    "TYPE_BEACON": [3, 4, 6, 9],   # major, minor, rssi, time (its NaN tells a short line in the fast path)
    "TYPE_WAYPOINT": [2, 3],
}
_TEXT_COLS = {"TYPE_WIFI": [2, 3], "TYPE_BEACON": [2, 8]}
_HEADER_RE = re.compile(rb"^#[^\n]*", re.M)


def _numeric(table: np.ndarray, linenos: np.ndarray, path: Path, what: str, dtype: type = np.float64,
             ) -> np.ndarray:
    """``table`` (n, k) of strings as numbers; a non-numeric / non-finite value -> InputError at its line."""
    try:
        arr: np.ndarray = table.astype(dtype)
        if dtype is np.float64 and not np.isfinite(arr).all():
            raise ValueError
        return arr
    except ValueError:
        for row, ln in zip(table, linenos):
            for v in row:
                try:
                    x = dtype(v)
                    if dtype is np.float64 and not np.isfinite(x):
                        raise ValueError
                except ValueError:
                    raise InputError(f"{what}: non-numeric or non-finite value {str(v)!r}",
                                     f"{path}:{ln}") from None
        raise  # pragma: no cover - the loop always finds the culprit


#: lines the fast parser classifies at once, and lines whose bytes it gathers at once: bounds its temporary
#: arrays (~600 bytes a line) whatever the trace's length
_FAST_BLOCK_LINES = 1 << 15


def _gather(buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> bytes:
    """The bytes ``buf[start[i]:end[i]]`` of every i, concatenated (gathered a block of lines at a time)."""
    n = end - start
    out = np.empty(int(n.sum()), dtype=np.uint8)
    pos = 0
    for b in range(0, len(start), _FAST_BLOCK_LINES):
        s, k = start[b:b + _FAST_BLOCK_LINES], n[b:b + _FAST_BLOCK_LINES]
        m = int(k.sum())
        idx = np.arange(m, dtype=np.int64) + np.repeat(s - (np.cumsum(k) - k), k)
        out[pos:pos + m] = buf[idx]
        pos += m
    return out.tobytes()


def _line_types(buf: np.ndarray, ds: np.ndarray, de: np.ndarray) -> tuple[np.ndarray, list[str], Counter] | None:
    """Each data line's type (index into the returned names, -1 for a type not in :data:`_USED`) and the
    count of the skipped types, from lines ``buf[ds[i]:de[i]]``; None when a line is not
    ``<1-16 digits><TAB>TYPE_...<TAB or end>`` (the slow path then reports it). Works a block of lines at
    a time."""
    used = list(_USED)
    code = np.full(len(ds), -1, dtype=np.int8)
    skipped: Counter = Counter()
    width = 64
    for b in range(0, len(ds), _FAST_BLOCK_LINES):
        s, e = ds[b:b + _FAST_BLOCK_LINES], de[b:b + _FAST_BLOCK_LINES]
        # "<digits>\tTYPE_..." : a tab inside the line, 1-16 digits before it, "TYPE_" after it
        at = s[:, None] + np.arange(MAX_TIME_DIGITS + 1)[None, :]
        head = np.where(at < e[:, None], buf[np.minimum(at, len(buf) - 1)], 10)
        del at
        n_dig = np.argmax(head == 9, axis=1)
        if not ((head[np.arange(len(s)), n_dig] == 9) & (n_dig > 0)).all():
            return None
        if not ((head >= 48) & (head <= 57) | (np.arange(MAX_TIME_DIGITS + 1)[None, :] >= n_dig[:, None])).all():
            return None
        tab1 = s + n_dig
        pos = np.minimum(tab1[:, None] + 1 + np.arange(width)[None, :], len(buf) - 1)
        key = buf[pos]
        key = np.where(pos < e[:, None], key, 9)     # pad past the line end with a tab
        del pos
        is_tab = key == 9
        if not is_tab.any(axis=1).all():
            return None
        key = np.where(np.arange(width)[None, :] > np.argmax(is_tab, axis=1)[:, None], 0, key)  # the type only
        if not (key[:, :5] == np.frombuffer(b"TYPE_", np.uint8)).all():
            return None
        kv = np.ascontiguousarray(key.astype(np.uint8)).view(np.dtype((np.void, width))).ravel()
        uniq, inv, counts = np.unique(kv, return_inverse=True, return_counts=True)
        for j, u in enumerate(uniq):
            raw = bytes(u)
            name = raw[: raw.index(b"\t")].decode("ascii", "replace")
            if name in _USED:
                code[b + np.flatnonzero(inv == j)] = used.index(name)
            else:
                skipped[name] += int(counts[j])
    return code, used, skipped


def _rows_fast(data: bytes) -> tuple[dict[str, _Rows], Counter] | None:
    """Vectorised parse of a well-formed trace; None when anything looks off (the slow path then finds and
    reports the problem with its line number).

    Lines are located and classified with numpy on the raw bytes, a block of lines at a time; the lines of
    each used type are cut out and handed to pandas' C parser in one block.
    """
    text = data.replace(b"\r\n", b"\n") if b"\r" in data else data
    if not text.endswith(b"\n"):
        text += b"\n"
    buf = np.frombuffer(text, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate(([0], nl[:-1] + 1))
    ends = nl                                     # exclusive end (the newline)
    del nl
    if (ends - starts).max(initial=0) > MAX_LINE_BYTES:
        return None
    first = buf[starts]
    is_data = (first != ord("#")) & (starts < ends)
    blank = np.flatnonzero(is_data & np.isin(first, (9, 13, 32)))  # a line of blanks is a blank line
    if len(blank):
        is_data[blank[[not bytes(buf[starts[i]:ends[i]]).strip() for i in blank]]] = False
    if not is_data.any():
        return None
    ds, de = starts[is_data], ends[is_data]
    line_no = np.flatnonzero(is_data) + 1
    del starts, ends, first, is_data
    typed = _line_types(buf, ds, de)
    if typed is None:
        return None
    code, used, skipped = typed
    out: dict[str, _Rows] = {}
    for typ in _USED:
        sel = np.flatnonzero(code == used.index(typ))
        parts = [_parse_block(typ, buf, ds[sel[b:b + _FAST_BLOCK_LINES]], de[sel[b:b + _FAST_BLOCK_LINES]])
                 for b in range(0, len(sel), _FAST_BLOCK_LINES)]
        if any(p is None for p in parts):
            return None
        text_cols = _TEXT_COLS.get(typ, [])
        if not parts:
            out[typ] = _Rows(np.zeros(0, dtype=np.int64), np.zeros((0, len(_NUM_COLS[typ]))),
                             np.zeros((0, len(text_cols)), dtype=object), line_no[sel])
            continue
        t_ms, num, txt = (np.concatenate([p[k] for p in parts if p is not None]) for k in range(3))
        out[typ] = _Rows(t_ms, num, txt, line_no[sel])
    return out, skipped


def _parse_block(typ: str, buf: np.ndarray, ds: np.ndarray, de: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Lines ``buf[ds[i]:de[i]]`` of one used type through pandas' C parser: (unix ms, numeric fields, text
    fields), None when a line does not parse cleanly."""
    nfields = _USED[typ]
    text_cols = _TEXT_COLS.get(typ, [])
    block = _gather(buf, ds, de + 1)
    try:
        df = pd.read_csv(io.BytesIO(block), sep="\t", header=None, names=list(range(nfields)),
                         dtype={c: "category" for c in text_cols}, keep_default_na=False, na_values={},
                         quoting=csv.QUOTE_NONE, engine="c", encoding="utf-8", skip_blank_lines=False)
        if len(df) != len(ds):
            return None
        t_ms = df[0].to_numpy(dtype=np.int64)
        num = df[_NUM_COLS[typ]].to_numpy(dtype=np.float64)
    except (ValueError, TypeError, OverflowError, pd.errors.ParserError):
        return None
    if not np.isfinite(num).all():
        return None
    # too few fields: pandas fills the missing ones with "" (text) or NaN (numbers, caught above)
    if text_cols and nfields - 1 in text_cols and (df[text_cols[-1]] == "").any():
        return None
    # text as Python strings (a fixed-width numpy string array would be as wide as the longest cell), one
    # object per distinct value (read as categories: a scan's SSIDs and BSSIDs repeat in every scan)
    txt = np.column_stack([_shared_text(df[c]) for c in text_cols]) if text_cols else \
        np.zeros((len(df), 0), dtype=object)
    return t_ms, num, txt


def _shared_text(col: pd.Series) -> np.ndarray:
    """A categorical column as an object array holding one str per category (not one per row)."""
    cats = np.array([str(v) for v in col.cat.categories], dtype=object)
    codes = col.cat.codes.to_numpy()
    return cats[codes] if len(cats) else np.full(len(col), "", dtype=object)


def _rows_slow(text: str, path: Path) -> tuple[dict[str, _Rows], Counter]:
    """Line-by-line parse with exact error messages (file:line). Keeps each used line as it is (one string)
    and splits them a block at a time at the end: memory of the order of the text's."""
    rows: dict[str, list[str]] = {k: [] for k in _USED}
    lnos: dict[str, list[int]] = {k: [] for k in _USED}
    skipped: Counter = Counter()
    for i, line in enumerate(io.StringIO(text, newline="\n"), 1):
        line = line.rstrip("\n").rstrip("\r")
        if len(line) > MAX_LINE_BYTES:
            raise InputError(f"line of {len(line):,} characters (a trace line has at most a few hundred; the "
                             f"limit is {MAX_LINE_BYTES:,})", f"{path}:{i}")
        if not line or line.isspace() or line[0] == "#":
            continue
        parts = line.split("\t")
        if not (len(parts) >= 2 and parts[0].isdigit() and parts[1].startswith("TYPE_")):
            if parts[0].isdigit() and (len(parts) < 2 or "TYPE_".startswith(parts[1])):
                raise InputError("truncated line: expected '<unix_ms><TAB>TYPE_...<TAB><values>'",
                                 f"{path}:{i}")
            raise InputError("not a Microsoft ILC trace line (expected '<unix_ms><TAB>TYPE_...'; "
                             "mixed formats?)", f"{path}:{i}")
        if len(parts[0]) > MAX_TIME_DIGITS:
            raise InputError(f"time {parts[0][:24]!r} has {len(parts[0])} digits (unix milliseconds have 13; at "
                             f"most {MAX_TIME_DIGITS})", f"{path}:{i}")
        typ = parts[1]
        bucket = rows.get(typ)
        if bucket is None:
            skipped[typ] += 1
            continue
        if len(parts) != _USED[typ]:
            raise InputError(f"{typ}: expected {_USED[typ]} tab-separated fields, got {len(parts)}",
                             f"{path}:{i}")
        bucket.append(line)
        lnos[typ].append(i)
    if not any(rows.values()) and not skipped:
        raise InputError("no data lines (empty or header-only trace)", str(path))
    out: dict[str, _Rows] = {}
    for typ in _USED:
        ln = np.asarray(lnos[typ], dtype=np.int64)
        text_cols = _TEXT_COLS.get(typ, [])
        if not rows[typ]:
            out[typ] = _Rows(np.zeros(0, dtype=np.int64), np.zeros((0, len(_NUM_COLS[typ]))),
                             np.zeros((0, len(text_cols)), dtype=object), ln)
            continue
        blocks = []
        for b in range(0, len(ln), _FAST_BLOCK_LINES):
            tab = np.array([r.split("\t") for r in rows[typ][b:b + _FAST_BLOCK_LINES]], dtype=object)
            blocks.append((_numeric(tab[:, :1], ln[b:], path, typ, np.int64)[:, 0],
                          _numeric(tab[:, _NUM_COLS[typ]], ln[b:], path, typ), tab[:, text_cols]))
        rows[typ] = []
        t_ms, num, txt = (np.concatenate([p[k] for p in blocks]) for k in range(3))
        out[typ] = _Rows(t_ms, num, txt, ln)
    return out, skipped


def _stream(r: _Rows, ncols: int, has_accuracy: bool) -> _Stream:
    o = np.argsort(r.t_ms, kind="stable")
    acc = accuracy_flags(r.num[o, ncols]) if has_accuracy else np.full(len(o), -1, dtype=np.int64)
    return _Stream(r.t_ms[o] / 1000.0, r.num[o, :ncols], acc, r.line[o])


def parse_trace(path: Path, opts: MsftIlcConfig) -> _Trace:
    """Parse one trace file into time-sorted series and tables (no PDR yet)."""
    raw = _read_bytes(path)
    try:
        raw.decode("utf-8")  # checked once; the slow path decodes again
    except UnicodeDecodeError as e:
        line_start = raw.rfind(b"\n", 0, e.start) + 1
        line_no = raw.count(b"\n", 0, e.start) + 1
        raise InputError(f"not UTF-8 text (byte {e.start - line_start + 1} of the line: {e.reason})",
                         f"{path}:{line_no}") from None
    device = floor = site = ""
    for h in _HEADER_RE.findall(raw[:20000]):
        hs = h.decode("utf-8", "replace")
        m = re.search(r"\tSiteID:([^\t]*)", hs)
        if m:
            site = m.group(1).strip()
        m = re.search(r"\tModel:([^\t]*)", hs)
        if m:
            device = m.group(1).strip()
        m = re.search(r"\tFloorName:([^\t]*)", hs)
        if m:
            floor = m.group(1).strip()
    fast = _rows_fast(raw)
    rows, skipped = fast if fast is not None else _rows_slow(raw.decode("utf-8"), path)
    del raw, fast
    wid = _walk_id(path)

    acc = _stream(rows["TYPE_ACCELEROMETER"], 3, True)
    gyr = _stream(rows["TYPE_GYROSCOPE"], 3, True)
    rot = _stream(rows["TYPE_ROTATION_VECTOR"], 3, True)
    bad = np.flatnonzero(np.sum(rot.values**2, axis=1) > 1.0 + 1e-3)
    if len(bad):
        raise InputError("TYPE_ROTATION_VECTOR: |(x, y, z)| > 1 is not a rotation vector",
                         f"{path}:{rot.line[bad[0]]}")

    w = rows["TYPE_WIFI"]
    n_stale = 0
    bssid = _normalised(w.text[:, 1])
    empty = np.flatnonzero(bssid == "")
    if len(empty):
        raise InputError("TYPE_WIFI: empty BSSID", f"{path}:{w.line[empty[0]]}")
    fresh = (w.t_ms - w.num[:, 2]) <= opts.max_wifi_age_s * 1000.0
    n_stale = int((~fresh).sum())
    idx = np.flatnonzero(fresh)
    # one reading per (scan time, BSSID): phones list a BSSID twice when it is heard on two channels;
    # keep the row seen most recently
    if len(idx):
        order = np.lexsort((-w.num[idx, 2], pd.factorize(bssid[idx])[0], w.t_ms[idx]))
        idx = idx[order]
        key_t, key_b = w.t_ms[idx], bssid[idx]
        first = np.r_[True, (key_t[1:] != key_t[:-1]) | (key_b[1:] != key_b[:-1])]
        n_dup = int((~first).sum())
        idx = idx[first]
    else:
        n_dup = 0
    idx = idx[np.argsort(w.t_ms[idx], kind="stable")]
    wifi = pd.DataFrame({
        "walk_id": pd.Series([wid] * len(idx), dtype=object), "t_s": w.t_ms[idx] / 1000.0,
        "bssid": pd.Series(bssid[idx], dtype=object), "rssi_dbm": w.num[idx, 0], "freq_mhz": w.num[idx, 1],
        "ssid": pd.Series(w.text[idx, 0] if len(idx) else [], dtype=object),
    })

    ble, ble_lines, n_ble_dup = _beacons(rows["TYPE_BEACON"], wid, path)
    wp = _stream(rows["TYPE_WAYPOINT"], 2, False)
    waypoints = pd.DataFrame({
        "walk_id": pd.Series([wid] * len(wp.t_s), dtype=object), "t_s": wp.t_s,
        "x_m": wp.values[:, 0], "y_m": wp.values[:, 1],
        "label": pd.Series([f"wp{k}" for k in range(len(wp.t_s))], dtype=object),
        "floor": pd.Series([floor] * len(wp.t_s), dtype=object),
    })
    return _Trace(wid, device, floor, acc, gyr, rot, wifi, w.line[idx], waypoints, wp.line, skipped, n_stale,
                  n_dup, site, ble, ble_lines, n_ble_dup)


def _normalised(ids: np.ndarray) -> np.ndarray:
    """MAC addresses as text, stripped and in lower case: one string per distinct value (object array)."""
    codes, uniq = pd.factorize(ids, use_na_sentinel=False)
    norm = np.array([str(v).strip().lower() for v in uniq], dtype=object)
    return norm[codes] if len(norm) else np.zeros(len(ids), dtype=object)


def _beacons(b: _Rows, wid: str, path: Path) -> tuple[pd.DataFrame, np.ndarray, int]:
    """TYPE_BEACON rows as BLE readings in time order: bssid = the beacon's MAC (lower case), ssid = its
    iBeacon ``uuid:major:minor``; a repeated (time, MAC) keeps its first row. Returns the readings, their
    lines and the number of repeats dropped."""
    mac = _normalised(b.text[:, 1])
    empty = np.flatnonzero(mac == "")
    if len(empty):
        raise InputError("TYPE_BEACON: empty MAC address", f"{path}:{b.line[empty[0]]}")
    code = pd.factorize(mac)[0]
    order = np.lexsort((code, b.t_ms))  # stable: file order among equal (time, MAC)
    keep = np.r_[True, (b.t_ms[order][1:] != b.t_ms[order][:-1]) | (code[order][1:] != code[order][:-1])]
    idx = order[keep[: len(order)]]
    ident = [f"{str(u).strip()}:{int(j)}:{int(n)}" for u, j, n in zip(b.text[idx, 0], b.num[idx, 0], b.num[idx, 1],
                                                                        strict=True)]
    ble = pd.DataFrame({
        "walk_id": pd.Series([wid] * len(idx), dtype=object), "t_s": b.t_ms[idx] / 1000.0,
        "bssid": pd.Series(mac[idx], dtype=object), "rssi_dbm": b.num[idx, 2], "freq_mhz": np.nan,
        "ssid": pd.Series(ident, dtype=object),
    })
    return ble, b.line[idx], len(mac) - len(idx)


def _floor_plans(files: list[Path]) -> dict[str, dict]:
    """Each floor folder's plan (``geojson_map.json`` scaled by ``floor_info.json``'s width and height, the
    frame of the waypoints) as local-metre GeoJSON, by folder name, when both files are among the inputs;
    with ``floor_image.png``, which spans that width and height, when it is there too."""
    from rmbuild.floorplan import from_ilc, to_geojson

    folders: dict[Path, dict[str, Path]] = {}
    for f in files:
        if f.name in COMPANION_FILES:
            folders.setdefault(f.parent, {})[f.name] = f
    out: dict[str, dict] = {}
    for folder, byname in folders.items():
        if not {"geojson_map.json", "floor_info.json"} <= set(byname):
            continue
        w, h = _floor_size(byname["floor_info.json"])
        doc = read_json_file(byname["geojson_map.json"], MAX_PLAN_BYTES, "floor plan")
        try:
            out[folder.name] = to_geojson(from_ilc(doc, w, h, folder.name))
        except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
            raise InputError(f"unreadable floor plan: {str(e)[:200]}", str(byname["geojson_map.json"])) from None
        if "floor_image.png" in byname:
            out[folder.name] = attach_image(out[folder.name], read_image(byname["floor_image.png"]), [0.0, 0.0, w, h])
    return out


def _floor_size(path: Path) -> tuple[float, float]:
    """``floor_info.json``'s ``map_info`` width and height (m): numbers in (0, MAX_PLAN_SIZE_M]."""
    info = read_json_file(path, MAX_FLOOR_INFO_BYTES, "floor_info.json")
    m = info.get("map_info") if isinstance(info, dict) else None
    if not isinstance(m, dict):
        raise InputError('no "map_info" object with "width" and "height"', str(path))
    out = []
    for k in ("width", "height"):
        v = m.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= MAX_PLAN_SIZE_M:
            raise InputError(f'map_info "{k}" must be a number of metres in (0, {MAX_PLAN_SIZE_M:g}], got '
                             f"{str(v)[:40]}", str(path))
        out.append(float(v))
    return out[0], out[1]


def _trace_floor(tr: _Trace, path: Path) -> str:
    """The trace header's FloorName, else the floor folder holding ``path_data_files/`` (the ILC layout)."""
    if tr.floor:
        return tr.floor
    return path.parent.parent.name if path.parent.name == "path_data_files" else ""


#: tally key prefix of the traces of one SiteID (:meth:`MsftIlcReader.tally_notes`)
SITE_TALLY = "site:"


@register
class MsftIlcReader(Reader):
    name = FORMAT_NAME
    description = "Microsoft Indoor Location Competition 2.0 traces (.txt/.txt.gz): phone IMU + Wi-Fi + BLE, PDR"

    reads_folders_apart = True  # a trace file is parsed on its own; its floor is its header's or its folder's

    def tally_notes(self, tallies: dict[str, int], cfg: IngestConfig) -> list[str]:
        """The traces' sites when more than one, the stale and repeated rows dropped or merged."""
        notes = []
        sites = Counter({k[len(SITE_TALLY):]: n for k, n in tallies.items() if k.startswith(SITE_TALLY)})
        if len(set(sites) - {""}) > 1:
            notes.append(f"the traces come from {len(set(sites) - {''})} sites (SiteID "
                         + ", ".join(f"{k}: {n} trace(s)" for k, n in sites.most_common() if k)
                         + "): floors of different buildings in one workspace; ingest one site at a time")
        if tallies.get("wifi_rows"):
            notes.append(f"dropped {tallies['wifi_stale']:,} of {tallies['wifi_rows']:,} Wi-Fi rows last seen more "
                         f"than {cfg.msft_ilc.max_wifi_age_s:g} s before their scan (stale cache entries)")
        if tallies.get("ble_dup"):
            notes.append(f"merged {tallies['ble_dup']:,} TYPE_BEACON rows repeating a MAC at one time (first kept)")
        if tallies.get("wifi_dup"):
            notes.append(f"merged {tallies['wifi_dup']:,} Wi-Fi rows repeating a BSSID within one scan (heard on "
                         "two channels; the most recently seen row kept)")
        return notes

    @classmethod
    def sniff(cls, files: list[Path]) -> bool:
        traces = [f for f in files if f.name not in COMPANION_FILES]
        if not traces or not all(_is_trace_name(f) for f in traces):
            return False
        return all(_looks_like_trace(_first_lines(f, 1)) for f in traces)

    def read(self, files: list[Path], cfg: IngestConfig) -> RawInput:
        opts = cfg.msft_ilc
        traces = [f for f in files if f.name not in COMPANION_FILES]
        notes: list[str] = []
        plans = _floor_plans(files)
        plan = next(iter(plans.values())) if len(plans) == 1 else None
        for p in plans.values():
            notes.append(f"floor plan: {p['name'] or 'geojson_map.json'} with its extent from floor_info.json"
                         + (" and its image floor_image.png" if "image" in p else ""))
        used = {"geojson_map.json", "floor_info.json"} if plans else set()
        if any("image" in p for p in plans.values()):
            used.add("floor_image.png")
        unused = sorted({f.name for f in files if f.name in COMPANION_FILES} - used)
        if unused:
            notes.append(f"companion files not used: {', '.join(unused)}")
        if not traces:
            raise InputError("no trace files (*.txt, *.txt.gz) among the inputs", str(files[0]))
        for f in traces:
            if not _is_trace_name(f):
                raise InputError("not a Microsoft ILC trace (expected *.txt or *.txt.gz; mixed formats?)",
                                 str(f))
        seen: dict[str, Path] = {}
        walks, wifi, fixes = [], [], []
        imu: dict[str, RawImu] = {}
        wifi_lines, fix_lines = [], []
        ble: list[pd.DataFrame] = []
        ble_lines: list[np.ndarray] = []
        skipped: Counter = Counter()
        n_stale = n_wifi = n_dup = n_ble_dup = 0
        sites: Counter = Counter()
        for f in traces:
            tr = parse_trace(f, opts)
            sites[tr.site] += 1
            if tr.walk_id in seen:
                raise InputError(f"duplicate trace id {tr.walk_id!r} (also {seen[tr.walk_id]})", str(f))
            seen[tr.walk_id] = f
            if len(tr.acc.t_s) < 2:
                raise InputError("no TYPE_ACCELEROMETER lines: cannot derive steps (no IMU data)", str(f))
            if len(tr.wifi) == 0:  # kept: a walk without radio evidence (ingest warns, naming it)
                why = "every TYPE_WIFI row stale" if tr.n_wifi_stale else "no TYPE_WIFI lines"
                notes.append(f"{f}: no usable Wi-Fi readings ({why})")
            imu[tr.walk_id] = raw_imu(tr, f)
            wifi.append(tr.wifi)
            wifi_lines.append(tr.wifi_lines)
            if len(tr.ble):
                ble.append(tr.ble)
                ble_lines.append(tr.ble_lines)
                n_ble_dup += tr.n_ble_dup
            fixes.append(tr.waypoints)
            fix_lines.append(tr.waypoint_lines)
            walks.append({"walk_id": tr.walk_id, "device_id": tr.device_id, "user_id": "", "role": "",
                          "source": FORMAT_NAME, "floor": _trace_floor(tr, f)})
            skipped.update(tr.skipped)
            n_stale += tr.n_wifi_stale
            n_dup += tr.n_wifi_dup
            n_wifi += tr.n_wifi_stale + tr.n_wifi_dup + len(tr.wifi)
            self.file_done(f)
        tallies = {"wifi_rows": n_wifi, "wifi_stale": n_stale, "wifi_dup": n_dup, "ble_dup": n_ble_dup,
                   **{f"{SITE_TALLY}{k}": n for k, n in sites.items()}}
        notes += self.tally_notes(tallies, cfg)
        return RawInput(
            walks=pd.DataFrame(walks, columns=["walk_id", "device_id", "user_id", "role", "source", "floor"]),
            poses=pd.DataFrame({c: pd.Series(dtype=object if c == "walk_id" else np.float64)
                                for c in ("walk_id", "t_s", "x_m", "y_m", "heading_rad")}),
            wifi=pd.concat(wifi, ignore_index=True),
            fixes=pd.concat(fixes, ignore_index=True),
            imu=imu,
            skipped=dict(sorted(skipped.items())),
            notes=notes,
            where=where_functions(seen, walks, wifi, wifi_lines, fixes, fix_lines, ble, ble_lines),
            tallies=tallies,
            floorplan=plan,
            ble=pd.concat(ble, ignore_index=True) if ble else None,
            floorplans=plans if len(plans) > 1 else {},
        )


def raw_imu(tr: _Trace, path: Path) -> RawImu:
    """The raw IMU of a parsed trace, with the line of every sample."""
    q = rotation_vector_quat(tr.rot.values)
    signals = ImuSignals(
        t_acc_s=tr.acc.t_s, acc_mps2=tr.acc.values, t_yaw_s=tr.rot.t_s, yaw_abs_rad=yaw_from_quat(q),
        yaw_accuracy=tr.rot.accuracy, t_gyro_s=tr.gyro.t_s, gyro_radps=tr.gyro.values, quat_xyzw=q,
    )
    return RawImu(signals, str(path), {"acc": tr.acc.line, "gyro": tr.gyro.line, "yaw": tr.rot.line})


def where_functions(paths: dict[str, Path], walks: list[dict], wifi: list[pd.DataFrame],
                    wifi_lines: list[np.ndarray], fixes: list[pd.DataFrame], fix_lines: list[np.ndarray],
                    ble: list[pd.DataFrame] | None = None, ble_lines: list[np.ndarray] | None = None) -> dict:
    """``RawInput.where``: row position -> "file:line"."""
    bfile = np.concatenate([np.full(len(d), str(paths[d["walk_id"].iat[0]]), dtype=object)
                            for d in ble]) if ble else np.zeros(0, dtype=object)
    bline = np.concatenate(ble_lines) if ble_lines else np.zeros(0, dtype=np.int64)
    wfile = np.concatenate([np.full(len(d), str(paths[d["walk_id"].iat[0]]) if len(d) else "", dtype=object)
                            for d in wifi]) if wifi else np.zeros(0, dtype=object)
    wline = np.concatenate(wifi_lines) if wifi_lines else np.zeros(0, dtype=np.int64)
    ffile = np.concatenate([np.full(len(d), str(paths[d["walk_id"].iat[0]]) if len(d) else "", dtype=object)
                            for d in fixes]) if fixes else np.zeros(0, dtype=object)
    fline = np.concatenate(fix_lines) if fix_lines else np.zeros(0, dtype=np.int64)
    return {
        "walks": lambda i: str(paths[walks[i]["walk_id"]]),
        "wifi": lambda i: f"{wfile[i]}:{wline[i]}",
        "fixes": lambda i: f"{ffile[i]}:{fline[i]}",
        "ble": lambda i: f"{bfile[i]}:{bline[i]}",
    }
