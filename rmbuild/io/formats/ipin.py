"""Reader for IPIN competition / GetSensorData logfiles (semicolon-separated text, optionally gzip'd).

One logfile = one walk (walk_id = file name without extension). ``%`` lines are comments/header; every other
line is ``TAG;AppTimestamp;...`` with the app timestamp (s) as the common clock. Used tags:
ACCE, GYRO, AHRS (the walk's raw phone IMU: ingest runs the PDR on it), IMUI (foot-mounted MIMU22BT step
increments, integrated here and preferred when present), WIFI, BLE4 (BLE beacons: id = MAC),
POSI (ground-truth WGS84 fixes, converted to a local ENU frame in metres). MAGN lines are checked but not
used. Every other tag is skipped with a count. docs/formats-real.md describes the format and the choices.
"""

from __future__ import annotations

import gzip
import io
import math
import re
import zlib
from array import array
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig, IpinConfig
from rmbuild.errors import InputError
from rmbuild.io.compressed import read_bytes
from rmbuild.io.formats.base import RawImu, RawInput, Reader, register
from rmbuild.limits import MAX_TRACE_BYTES
from rmbuild.pdr import (
    ImuSignals,
    accuracy_flags,
    poses_from_increments,
    rotation_vector_quat,
    yaw_from_azimuth_deg,
    yaw_from_quat,
)

FORMAT_NAME = "ipin"
#: tag -> number of ';'-separated fields including the tag (WIFI: at least; the SSID may contain ';')
_FIELDS = {"ACCE": 7, "GYRO": 7, "MAGN": 7, "AHRS": 10, "WIFI": 7, "POSI": 7, "IMUI": 18, "PRES": 5, "BLE4": 5}
#: values kept per row of the tags whose rows are not all numbers (WIFI: t, sensor t, freq, rss; BLE4: t, rss)
_KEPT = {"WIFI": 4, "BLE4": 2}
#: BLE4 fields after the tag, per beacon kind: iBeacon t;kind;MAC;RSSI;Power;Major;Minor;UUID, Eddystone
#: t;kind;MAC;RSSI;instanceID[;telemetry...] (at least)
_BLE4_FIELDS = {"iBeacon": 9, "Eddystone": 6}
#: tags of the GetSensorData app that rmbuild does not use (skipped with a count, like any other tag)
KNOWN_UNUSED = (
    "LIGH", "PROX", "HUMI", "TEMP", "SOUN", "GNSS", "BLUE", "RFID", "IMUX", "IMUL",
)
_TAG_LINE = re.compile(r"^[A-Z][A-Z0-9]{3};")
#: characters; a longer line is an error (the IPIN 2023 logfiles' longest line, a header line, has 340)
MAX_LINE_CHARS = 4096
_NAME_SUFFIXES = (".txt", ".txt.gz", ".log", ".log.gz", ".csv", ".csv.gz")
#: our own schema's file names; never a logfile
_SCHEMA_NAMES = re.compile(
    r"^(walks|poses|wifi|ble|fixes|aps|devices|users|landmarks)[^/]*\.(csv|csv\.gz|parquet)$")

def wgs84_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, lat0_deg: float, lon0_deg: float,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """East/north in m of WGS84 points (ellipsoid height 0) in the local ENU frame at (lat0, lon0) (PROJ's
    geodesy through pyproj, :func:`rmbuild.floorplan.lonlat_to_enu`)."""
    from rmbuild.floorplan import lonlat_to_enu

    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    en = lonlat_to_enu(lon0_deg, lat0_deg)(np.c_[lon.ravel(), lat.ravel()])
    return en[:, 0].reshape(lat.shape), en[:, 1].reshape(lat.shape)


def _walk_id(p: Path) -> str:
    n = p.name
    for suf in sorted(_NAME_SUFFIXES, key=len, reverse=True):
        if n.lower().endswith(suf):
            return n[: -len(suf)]
    return p.stem


def _read_text(p: Path) -> str:
    raw = read_bytes(p, MAX_TRACE_BYTES, "logfile")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        try:
            return raw.decode("latin-1")
        except UnicodeDecodeError as e:  # pragma: no cover - latin-1 decodes anything
            raise InputError(f"not text (byte {e.start})", str(p)) from None


def _first_lines(p: Path, n: int = 40) -> list[str]:
    try:
        opener = gzip.open if p.name.lower().endswith(".gz") else open
        out: list[str] = []
        with opener(p, "rt", encoding="utf-8", errors="replace") as fh:  # type: ignore[operator]
            for _ in range(n):
                line = fh.readline(MAX_LINE_CHARS + 1)
                if not line:
                    break
                if line.strip():
                    out.append(line.rstrip("\r\n"))
        return out
    except (OSError, EOFError, zlib.error):
        return []


def _looks_like_logfile(lines: list[str]) -> bool:
    if not lines:
        return False
    if _TAG_LINE.match(lines[0]):
        return True
    if not lines[0].startswith("%"):
        return False
    return any("GetSensorData" in ln or _TAG_LINE.match(ln) for ln in lines)


@dataclass
class _Log:
    """One parsed logfile: per-tag float arrays (rows sorted by app time) and their line numbers."""

    path: Path
    walk_id: str
    device_id: str
    num: dict[str, np.ndarray] = field(default_factory=dict)
    line: dict[str, np.ndarray] = field(default_factory=dict)
    wifi_text: list[tuple[str, str]] = field(default_factory=list)  # (ssid, bssid) per WIFI row, sorted
    ble_text: list[tuple[str, str]] = field(default_factory=list)   # (identity, MAC) per BLE4 row, sorted
    skipped: Counter = field(default_factory=Counter)
    t_first: float = math.nan


def _float(v: str, what: str, where: str) -> float:
    try:
        x = float(v)
    except ValueError:
        raise InputError(f"{what}: non-numeric value {v!r}", where) from None
    if not math.isfinite(x):
        raise InputError(f"{what}: non-finite value {v!r}", where)
    return x


def parse_logfile(path: Path) -> _Log:
    """Parse one GetSensorData logfile (no PDR yet). Malformed lines -> InputError naming file:line."""
    text = _read_text(path)
    log = _Log(path, _walk_id(path), "")
    # compact while reading (a logfile may hold a million lines): values flat as doubles, one text pair per
    # distinct (name, MAC) shared by every row that has it
    rows: dict[str, array] = {t: array("d") for t in _FIELDS}
    lnos: dict[str, array] = {t: array("q") for t in _FIELDS}
    wifi_text: list[tuple[str, str]] = []
    ble_text: list[tuple[str, str]] = []
    pairs: dict[tuple[str, str], tuple[str, str]] = {}
    manufacturer = model = ""
    created = math.nan
    seen_data = False
    for i, raw in enumerate(io.StringIO(text, newline="\n"), 1):
        line = raw.rstrip("\n").rstrip("\r")
        if len(line) > MAX_LINE_CHARS:
            raise InputError(f"line of {len(line):,} characters (a logfile line has at most a few hundred; the "
                             f"limit is {MAX_LINE_CHARS:,})", f"{path}:{i}")
        if not line.strip():
            continue
        if line[0] == "%":
            m = re.match(r"^%\s*Model:\s*(.*?)\s*$", line)
            if m:
                model = m.group(1)
            m = re.match(r"^%\s*Manufacturer:\s*(.*?)\s*$", line)
            if m:
                manufacturer = m.group(1)
            m = re.match(r"^%\s*Date of creation:\s*(.*?)\s*$", line)
            if m:
                created = _creation_epoch(m.group(1))
            continue
        where = f"{path}:{i}"
        if not _TAG_LINE.match(line):
            what = "mixed formats?" if not seen_data else "expected 'TAG;AppTimestamp;...'"
            raise InputError(f"not a GetSensorData line ({what})", where)
        seen_data = True
        parts = line.split(";")
        tag = parts[0]
        if tag not in _FIELDS:
            log.skipped[tag] += 1
            continue
        if tag == "BLE4":
            vals = _ble4(parts, where, ble_text, pairs)
            rows[tag].extend(vals)
            lnos[tag].append(i)
            continue
        if len(parts) > _FIELDS[tag] and parts[-1] == "" and tag != "WIFI":
            parts = parts[:-1]   # a trailing ';'
        n = _FIELDS[tag]
        if tag == "WIFI":
            if parts[-1] == "" and len(parts) > n:
                parts = parts[:-1]
            if len(parts) < n:
                raise InputError(f"WIFI: expected {n} ';'-separated fields, got {len(parts)}", where)
            # WIFI;t;ts;SSID;BSSID;freq;rss - the SSID may itself contain ';'
            ssid = ";".join(parts[3:-3])
            bssid = parts[-3].strip().lower()
            if not re.fullmatch(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}", bssid):
                raise InputError(f"WIFI: BSSID {parts[-3]!r} is not a MAC address", where)
            vals = [_float(parts[1], tag, where), _float(parts[2], tag, where), _float(parts[-2], tag, where),
                    _float(parts[-1], tag, where)]
            wifi_text.append(pairs.setdefault((ssid, bssid), (ssid, bssid)))
        else:
            if len(parts) != n:
                raise InputError(f"{tag}: expected {n} ';'-separated fields, got {len(parts)}", where)
            vals = [_float(v, tag, where) for v in parts[1:]]
            if tag == "POSI":
                lat, lon = vals[2], vals[3]
                if not -90.0 <= lat <= 90.0:
                    raise InputError(f"POSI: latitude {lat} outside [-90, 90]", where)
                if not -180.0 <= lon <= 180.0:
                    raise InputError(f"POSI: longitude {lon} outside [-180, 180]", where)
        rows[tag].extend(vals)
        lnos[tag].append(i)
        if not math.isfinite(log.t_first) or vals[0] < log.t_first:
            log.t_first = vals[0]
    if not seen_data:
        raise InputError("no data lines (empty or header-only logfile)", str(path))
    log.device_id = " ".join(x for x in (manufacturer, model) if x)
    # app times count from the recording's start; the header's creation time (1 s) makes them absolute, so
    # one device's consecutive logfiles line up in time (session continuity)
    epoch = created if math.isfinite(created) else 0.0
    log.t_first += epoch
    for tag in _FIELDS:
        width = _KEPT.get(tag, _FIELDS[tag] - 1)
        arr = np.frombuffer(rows[tag], dtype=np.float64).reshape(-1, width).copy()
        rows[tag] = array("d")
        if len(arr):
            arr[:, 0] += epoch
        ln = np.asarray(lnos[tag], dtype=np.int64)
        o = np.argsort(arr[:, 0], kind="stable") if len(arr) else np.zeros(0, dtype=np.int64)
        log.num[tag], log.line[tag] = arr[o], ln[o]
        if tag == "WIFI":
            log.wifi_text = [wifi_text[j] for j in o]
        if tag == "BLE4":
            log.ble_text = [ble_text[j] for j in o]
    log.skipped.update({"MAGN": len(log.num["MAGN"])} if len(log.num["MAGN"]) else {})
    return log


def _ble4(parts: list[str], where: str, text: list[tuple[str, str]],
          pairs: dict[tuple[str, str], tuple[str, str]]) -> list[float]:
    """One BLE4 line's (app time, RSSI), its (identity, MAC) appended to ``text``: the identity is an iBeacon's
    ``uuid:major:minor``, "" for an Eddystone. A malformed line -> InputError at ``where``."""
    if parts[-1] == "" and len(parts) > 5:
        parts = parts[:-1]   # a trailing ';'
    kind = parts[2] if len(parts) > 2 else ""
    need = _BLE4_FIELDS.get(kind)
    if need is None:
        raise InputError(f"BLE4: unknown beacon kind {kind!r} (expected iBeacon or Eddystone)", where)
    if len(parts) < need or (kind == "iBeacon" and len(parts) != need):
        raise InputError(f"BLE4: an {kind} line has "
                         f"{'' if kind == 'iBeacon' else 'at least '}{need} ';'-separated fields, got {len(parts)}",
                         where)
    mac = parts[3].strip().lower()
    if not re.fullmatch(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}", mac):
        raise InputError(f"BLE4: MAC {parts[3]!r} is not a MAC address", where)
    ident = ""
    if kind == "iBeacon":
        major, minor = (int(_float(v, "BLE4", where)) for v in parts[6:8])
        ident = f"{parts[8].strip()}:{major}:{minor}"
    text.append(pairs.setdefault((ident, mac), (ident, mac)))
    return [_float(parts[1], "BLE4", where), _float(parts[4], "BLE4", where)]


def _creation_epoch(text: str) -> float:
    """Epoch seconds of a header date like 'Wed Jun 14 14:46:22 GMT+02:00 2023' (NaN when unreadable)."""
    from datetime import datetime

    m = re.match(r"^\w{3} (\w{3} \d{1,2} \d{2}:\d{2}:\d{2}) (?:GMT|UTC)([+-]\d{2}):?(\d{2}) (\d{4})$", text)
    if not m:
        return math.nan
    try:
        dt = datetime.strptime(f"{m.group(1)} {m.group(4)} {m.group(2)}{m.group(3)}", "%b %d %H:%M:%S %Y %z")
    except ValueError:
        return math.nan
    return dt.timestamp()


def raw_imu(log: _Log) -> RawImu:
    """The phone's raw IMU of a parsed logfile (ACCE, GYRO, AHRS), with the line of every sample."""
    acc, gyr, ahrs = log.num["ACCE"], log.num["GYRO"], log.num["AHRS"]
    quat = np.zeros((0, 4))
    if len(ahrs):
        rv = ahrs[:, 5:8]
        if np.any(np.sum(rv**2, axis=1) > 1.0 + 1e-3):
            j = int(np.flatnonzero(np.sum(rv**2, axis=1) > 1.0 + 1e-3)[0])
            raise InputError("AHRS: |RotVec| > 1 is not a rotation vector",
                             f"{log.path}:{log.line['AHRS'][j]}")
        if np.any(np.abs(rv) > 0):
            quat = rotation_vector_quat(rv)
            yaw = yaw_from_quat(quat)
        else:   # no rotation vector recorded: the app's yaw, a compass azimuth in degrees
            yaw = yaw_from_azimuth_deg(ahrs[:, 4])
        accuracy = accuracy_flags(ahrs[:, 8])
    else:
        yaw, accuracy = np.zeros(0), np.zeros(0, dtype=np.int64)
    signals = ImuSignals(
        t_acc_s=acc[:, 0], acc_mps2=acc[:, 2:5], t_yaw_s=ahrs[:, 0] if len(ahrs) else np.zeros(0),
        yaw_abs_rad=yaw, yaw_accuracy=accuracy, t_gyro_s=gyr[:, 0], gyro_radps=gyr[:, 2:5], quat_xyzw=quat,
    )
    return RawImu(signals, str(log.path), {"acc": log.line["ACCE"], "gyro": log.line["GYRO"],
                                           "yaw": log.line["AHRS"]})


def _enu_origin(logs: list[_Log], opts: IpinConfig, notes: list[str]) -> tuple[float, float]:
    """The WGS84 origin (lat, lon) of the local ENU frame of the POSI fixes: the configured one, else the
    first fix of the first logfile that has one (said in ``notes``), else (0, 0)."""
    if opts.origin_lat_deg is not None and opts.origin_lon_deg is not None:
        return opts.origin_lat_deg, opts.origin_lon_deg
    first = next((lg for lg in logs if len(lg.num["POSI"])), None)
    if first is None:
        return 0.0, 0.0
    lat0, lon0 = float(first.num["POSI"][0, 2]), float(first.num["POSI"][0, 3])
    notes.append(f"POSI fixes in a local ENU frame at the first fix of {first.path.name}: lat {lat0:.9f}, "
                 f"lon {lon0:.9f} (ingest.ipin.origin_lat_deg / origin_lon_deg set it)")
    return lat0, lon0


@register
class IpinReader(Reader):
    name = FORMAT_NAME
    description = "IPIN / GetSensorData logfiles (';'-separated): phone IMU or foot IMU (IMUI), Wi-Fi, BLE, POSI"

    @classmethod
    def sniff(cls, files: list[Path]) -> bool:
        if not files:
            return False
        for f in files:
            if _SCHEMA_NAMES.match(f.name.lower()) or not f.name.lower().endswith(_NAME_SUFFIXES):
                return False
        return all(_looks_like_logfile(_first_lines(f)) for f in files)

    def read(self, files: list[Path], cfg: IngestConfig) -> RawInput:
        opts = cfg.ipin
        logs: list[_Log] = []
        seen: dict[str, Path] = {}
        for f in files:
            if _SCHEMA_NAMES.match(f.name.lower()):
                raise InputError("an rmbuild schema table among GetSensorData logfiles (mixed formats)",
                                 str(f))
            log = parse_logfile(f)
            if log.walk_id in seen:
                raise InputError(f"duplicate logfile id {log.walk_id!r} (also {seen[log.walk_id]})", str(f))
            seen[log.walk_id] = f
            logs.append(log)
            self.file_done(f)
        notes: list[str] = []
        lat0, lon0 = _enu_origin(logs, opts, notes)
        walks, poses, wifi, fixes, ble = [], [], [], [], []
        wifi_where: list[str] = []
        ble_where: list[str] = []
        fix_where: list[str] = []
        imu: dict[str, RawImu] = {}
        skipped: Counter = Counter()
        pressure: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for lg in logs:
            f = lg.path
            if opts.use_imui and len(lg.num["IMUI"]) > 0:
                sp, extra = self._imui_poses(lg, opts)
                pf = sp.to_frame(lg.walk_id)
                for k, v in extra.items():
                    pf[k] = v
                poses.append(pf)
            else:
                if len(lg.num["ACCE"]) < 2:
                    raise InputError("no ACCE (or IMUI) lines: cannot derive steps (no IMU data)", str(f))
                imu[lg.walk_id] = raw_imu(lg)
            w = lg.num["WIFI"]
            if len(w) == 0:  # kept: a walk without radio evidence (ingest warns, naming it)
                notes.append(f"{f}: no WIFI lines")
            wifi.append(pd.DataFrame({
                "walk_id": pd.Series([lg.walk_id] * len(w), dtype=object), "t_s": w[:, 0] if len(w) else [],
                "bssid": pd.Series([b for _, b in lg.wifi_text], dtype=object),
                "rssi_dbm": w[:, 3] if len(w) else [], "freq_mhz": w[:, 2] if len(w) else [],
                "ssid": pd.Series([s for s, _ in lg.wifi_text], dtype=object),
            }))
            wifi_where.extend(f"{f}:{ln}" for ln in lg.line["WIFI"])
            b = lg.num["BLE4"]
            if len(b):
                ble.append(pd.DataFrame({
                    "walk_id": pd.Series([lg.walk_id] * len(b), dtype=object), "t_s": b[:, 0],
                    "bssid": pd.Series([m for _, m in lg.ble_text], dtype=object), "rssi_dbm": b[:, 1],
                    "freq_mhz": np.nan, "ssid": pd.Series([i for i, _ in lg.ble_text], dtype=object),
                }))
                ble_where.extend(f"{f}:{ln}" for ln in lg.line["BLE4"])
            p = lg.num["POSI"]
            e, n = wgs84_to_enu(p[:, 2], p[:, 3], lat0, lon0) if len(p) else (np.zeros(0), np.zeros(0))
            fixes.append(pd.DataFrame({
                "walk_id": pd.Series([lg.walk_id] * len(p), dtype=object), "t_s": p[:, 0] if len(p) else [],
                "x_m": e, "y_m": n,
                "label": pd.Series([f"posi{int(c)}" for c in p[:, 1]] if len(p) else [], dtype=object),
                "floor": pd.Series([str(int(v)) for v in p[:, 4]] if len(p) else [], dtype=object),
                "building": pd.Series([str(int(v)) for v in p[:, 5]] if len(p) else [], dtype=object),
            }))
            fix_where.extend(f"{f}:{ln}" for ln in lg.line["POSI"])
            walks.append({"walk_id": lg.walk_id, "device_id": lg.device_id, "user_id": "", "role": "",
                          "source": FORMAT_NAME})
            if len(lg.num["PRES"]):  # PRES;AppTimestamp;SensorTimestamp;pressure (mbar = hPa);accuracy
                pressure[lg.walk_id] = (lg.num["PRES"][:, 0], lg.num["PRES"][:, 2])
            skipped.update(lg.skipped)
        pose_df = pd.concat(poses, ignore_index=True) if poses else pd.DataFrame(
            {c: pd.Series(dtype=object if c == "walk_id" else np.float64)
             for c in ("walk_id", "step", "t_s", "x_m", "y_m", "heading_rad")})
        if poses:
            notes.append(f"{len(poses)} walk(s) use the foot-mounted IMU's step increments (IMUI lines)")
        pw, ps = pose_df["walk_id"].to_numpy(), pose_df["step"].to_numpy()
        return RawInput(
            walks=pd.DataFrame(walks, columns=["walk_id", "device_id", "user_id", "role", "source"]),
            poses=pose_df,
            wifi=pd.concat(wifi, ignore_index=True),
            fixes=pd.concat(fixes, ignore_index=True),
            imu=imu,
            skipped=dict(sorted(skipped.items())),
            notes=notes,
            merge_duplicate_readings=True,
            enu_origin=None if opts.origin_lat_deg is not None or not fix_where else (lat0, lon0),
            pressure=pressure,
            ble=pd.concat(ble, ignore_index=True) if ble else None,
            where={
                "walks": lambda i: str(seen[walks[i]["walk_id"]]),
                "poses": lambda i: f"{seen[pw[i]]} (step {ps[i]})",
                "wifi": lambda i: wifi_where[i],
                "fixes": lambda i: fix_where[i],
                "ble": lambda i: ble_where[i],
            },
        )

    @staticmethod
    def _imui_poses(lg: _Log, opts: IpinConfig):
        """Per-step poses from IMUI lines; duplicate packets and zero increments are skipped with counts."""
        imui, lines = lg.num["IMUI"], lg.line["IMUI"]
        # fields after the tag: t, packet, step, dx, dy, dz, dtheta_deg, cov[10]
        dup = np.r_[False, np.diff(imui[:, 1]) == 0]
        still = (imui[:, 3] == 0) & (imui[:, 4] == 0) & (imui[:, 6] == 0)
        keep = ~dup & ~still
        if dup.any():
            lg.skipped["IMUI (repeated packet)"] += int(dup.sum())
        if (still & ~dup).any():
            lg.skipped["IMUI (no motion)"] += int((still & ~dup).sum())
        m = imui[keep]
        sign = -1.0 if opts.imui_z_down else 1.0
        dx, dy = m[:, 3], sign * m[:, 4]
        dth = sign * np.deg2rad(m[:, 6])
        t0 = min(lg.t_first, float(m[0, 0]) if len(m) else lg.t_first)
        sp = poses_from_increments(t0, m[:, 0], dx, dy, dth)
        extra: dict[str, np.ndarray] = {}
        if opts.imui_covariance:
            cov = m[:, 7:17]   # upper triangle of the 4x4 covariance of (dx, dy, dz, dtheta), row by row
            var = cov[:, [0, 4, 9]]
            bad = np.flatnonzero((var < 0).any(axis=1))
            if len(bad):
                ln = lines[keep][bad[0]]
                raise InputError("IMUI: negative variance in the covariance", f"{lg.path}:{ln}")
            sd = np.sqrt(var)
            extra = {
                "odo_sigma_x_m": np.r_[np.nan, sd[:, 0]],
                "odo_sigma_y_m": np.r_[np.nan, sd[:, 1]],
                "odo_sigma_theta_rad": np.r_[np.nan, sd[:, 2]],
            }
        return sp, extra
