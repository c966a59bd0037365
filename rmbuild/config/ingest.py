"""Config of `rmbuild ingest`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from rmbuild.config.base import bounded, check_ranges


@dataclass(frozen=True)
class IngestConfig:
    # How Wi-Fi readings attach to pose nodes (docs/data-format.md): "interval" gives node k the readings with
    # t_k <= t < t_{k+1}; "nearest" gives each reading to the node nearest in time.
    attach: Literal["interval", "nearest"] = "interval"
    # s; readings farther than this (in time) from the walk's first/last pose are dropped, not attached.
    max_attach_gap_s: float = bounded(2.0, 0.0, 3600.0)
    # dBm; the valid RSSI range. Readings outside it are an input error.
    rssi_min_dbm: float = bounded(-120.0, -200.0, 30.0)
    rssi_max_dbm: float = bounded(0.0, -200.0, 30.0)

    def validate(self) -> None:
        check_ranges(self)
        if not self.rssi_min_dbm < self.rssi_max_dbm:
            raise ValueError("rssi_min_dbm must be < rssi_max_dbm")
