"""The reader interface: every input format is one :class:`Reader` subclass in the registry.

A reader turns user files into a :class:`RawInput` — tables in the *input schema* documented in
``docs/data-format.md`` — and nothing more. Validation of values that every format shares, integration of
step increments and attachment of Wi-Fi readings to pose nodes happen afterwards in
:mod:`rmbuild.ingest.core`, so all formats get the same checks.

Contract for ``Reader.read``:
- ``poses``: walk_id (str), t_s (float s), x_m, y_m, heading_rad — per-step poses in the walk's own frame;
  optional yaw_abs_rad, yaw_abs_sigma_rad, step_freq_hz. (Step increments, e.g. a foot IMU's, are
  integrated by the reader.)
- ``imu``: walk_id -> :class:`RawImu`, the raw phone IMU of the walks that come without poses (a walk has
  poses or IMU, never both). Readers only read: :mod:`rmbuild.ingest.core` runs the PDR on them, once, for
  every format.
- ``wifi``: walk_id, t_s, bssid (str), rssi_dbm (float); optional freq_mhz, ssid.
- ``ble``: BLE beacon readings in the ``wifi`` columns (bssid = the beacon's id, its MAC; ssid = its
  iBeacon ``uuid:major:minor`` or ""); None or empty when the format or file has none.
- ``fixes``: walk_id, t_s, x_m, y_m, label — ground truth / landmark fixes (may be empty).
- ``walks``: walk_id, device_id, user_id, role, source.
- ``floor`` (optional str column on ``walks`` or ``poses``): the floor the data is on; an input with
  several floors is split into one workspace per floor (:mod:`rmbuild.ingest.floors`).
- ``pressure``: walk_id -> the barometer's (times s, hPa), when the format has one: without floor columns,
  its floor changes split the walk (:mod:`rmbuild.ingest.barometer`).
- A problem in a file raises :class:`rmbuild.errors.InputError` naming file and line/row. Lines of a
  known-but-unused kind are counted in ``skipped`` (kind -> count), not errors.
- ``where`` maps each table to a callable giving "file:row" for a row position, so shared validation can
  name the source of a bad value.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from rmbuild.config.ingest import IngestConfig
from rmbuild.pdr import ImuSignals


@dataclass
class RawImu:
    """One walk's raw phone IMU as read: the ``signals``, the ``source`` file, and per stream ("acc", "gyro",
    "yaw") the line (CSV: line, Parquet: row) of each sample in the signals' order, for messages."""

    signals: ImuSignals
    source: str
    lines: dict[str, np.ndarray] = field(default_factory=dict)
    #: "line" for text formats (messages say file:N), "row" for Parquet (file:row N)
    unit: str = "line"

    def where(self, stream: str, index: int) -> str:
        """"file:line" of sample ``index`` of ``stream`` (the file alone when lines are unknown)."""
        ln = self.lines.get(stream)
        if ln is None or not 0 <= index < len(ln):
            return self.source
        return f"{self.source}:{int(ln[index])}" if self.unit == "line" else f"{self.source}:row {int(ln[index])}"


@dataclass
class RawInput:
    """Tables read from user files, before shared validation and attachment."""

    walks: pd.DataFrame
    poses: pd.DataFrame
    wifi: pd.DataFrame
    fixes: pd.DataFrame
    truth_poses: pd.DataFrame | None = None
    truth_aps: pd.DataFrame | None = None
    venue: dict | None = None
    #: other truth tables (name -> DataFrame), kept in the workspace's truth/ folder as they are
    truth_extra: dict[str, pd.DataFrame] = field(default_factory=dict)
    #: line/record kind -> count of skipped items (reported as a warning, not an error)
    skipped: dict[str, int] = field(default_factory=dict)
    #: walk_id -> raw phone IMU of a walk without poses (ingest runs the PDR on it)
    imu: dict[str, RawImu] = field(default_factory=dict)
    #: human-readable notes for the ingest report (e.g. "dropped 1,234 stale Wi-Fi rows")
    notes: list[str] = field(default_factory=list)
    #: the counts behind the reader's summary notes (the last of ``notes``: :meth:`Reader.tally_notes`), summed
    #: when a building's floor folders are read apart
    tallies: dict[str, int] = field(default_factory=dict)
    #: table name -> function(row position) -> "file:line" for error messages
    where: dict[str, Callable[[int], str]] = field(default_factory=dict)
    #: true for formats where one scan may list a BSSID twice (heard on two channels): such repeats of
    #: (walk, t_s, bssid) are merged (first kept) with a note; false (our schema): they are an input error
    merge_duplicate_readings: bool = False
    #: the floor plan that came with the data (GeoJSON in local metres, :func:`rmbuild.floorplan.to_geojson`)
    floorplan: dict | None = None
    #: floor name -> its plan, for an input of several floors (``floor`` columns, rmbuild/ingest/floors.py)
    floorplans: dict[str, dict] = field(default_factory=dict)
    #: walk_id -> (times s, pressure hPa) of its barometer, when the format has one (floor changes)
    pressure: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    #: where a walk was cut between floors (:mod:`rmbuild.ingest.floors`): walk, t_s, the segments either side
    transitions: list[dict] = field(default_factory=list)
    #: the name of the one floor a single-floor input's floor columns give (set when they are consumed)
    floor_name: str | None = None
    #: BLE beacon readings (the ``wifi`` columns; ``where`` key "ble"); None: the input has none
    ble: pd.DataFrame | None = None
    #: (lat, lon) degrees: the WGS84 origin the reader chose itself for the fixes' local frame; ingest writes
    #: it into the workspace's config so that later reads (``--append``, ``localize``) use the same frame
    enu_origin: tuple[float, float] | None = None


class Reader(ABC):
    """One input format. Subclasses set ``name`` and ``description`` and implement the two methods."""

    name: ClassVar[str]
    description: ClassVar[str]
    #: True when the files of different floor folders can be read apart and give each floor what a read of
    #: them all gives it (no state across files but the summary notes' tallies): `build` then reads a
    #: building's floor folders as one task each
    reads_folders_apart: ClassVar[bool] = False

    def __init__(self) -> None:
        #: called with each input file once it is read (progress); set by the caller, None: nobody counts
        self.on_file: Callable[[Path], None] | None = None

    def file_done(self, f: Path) -> None:
        """Report that ``f`` has been read (readers call it once per input file they parse)."""
        if self.on_file is not None:
            self.on_file(f)

    @classmethod
    @abstractmethod
    def sniff(cls, files: list[Path]) -> bool:
        """True when ``files`` (regular files, already expanded from directories) look like this format.

        Must be cheap: look at names and at most the first few lines.
        """

    def tally_notes(self, tallies: dict[str, int], cfg: IngestConfig) -> list[str]:
        """The summary notes a read ends its ``notes`` with, from its ``tallies`` (none by default)."""
        return []

    @abstractmethod
    def read(self, files: list[Path], cfg: IngestConfig) -> RawInput:
        """Read ``files`` into a :class:`RawInput`; raise InputError (file + line) on malformed input.
        ``cfg``: the ``[ingest]`` config, whose ``[ingest.<format>]`` table holds this reader's options."""


#: format name -> reader class; filled by :mod:`rmbuild.io.formats`
REGISTRY: dict[str, type[Reader]] = {}


def register(cls: type[Reader]) -> type[Reader]:
    """Class decorator adding a reader to :data:`REGISTRY` under ``cls.name``."""
    if cls.name in REGISTRY:
        raise RuntimeError(f"duplicate reader name {cls.name!r}")
    REGISTRY[cls.name] = cls
    return cls
