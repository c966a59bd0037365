"""Phones' RSS offsets applied to readings: a radio map in one reference phone's scale.

``optimize`` estimates each device's offset against the device with the most fingerprints
(``vicinity.device_offsets_db`` of its report; :mod:`rmbuild.slam.devices`). A map built from readings as
heard mixes the phones' scales, and a query from one phone is compared with cells measured by another; with
each reading minus its device's offset, map and queries share the reference phone's scale (IPIN −2, two
phones 5.3 dB apart: kNN median on the built map 7.15 → 6.25 m). Devices without an offset (unknown to the
map, or no ``device_id``) are left as heard.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from rmbuild.types import Dataset


def nonzero(offsets: dict | None) -> dict[str, float]:
    """The offsets (dB) that change anything: device -> offset, zeros and non-numbers left out."""
    out = {}
    for dev, v in (offsets or {}).items():
        try:
            f = float(v)
        except (TypeError, ValueError):
            continue
        if np.isfinite(f) and f != 0.0:
            out[str(dev)] = f
    return out


def reading_offsets(readings: pd.DataFrame, walks: pd.DataFrame, offsets: dict[str, float]) -> np.ndarray:
    """(len(readings),) each reading's device offset (dB; 0 where its walk's device has none)."""
    if "device_id" not in walks or not len(readings):
        return np.zeros(len(readings))
    device = pd.Series(walks["device_id"].fillna("").astype(str).to_numpy(),
                       index=walks["walk_id"].astype(str).to_numpy())
    dev = readings["walk_id"].astype(str).map(device)
    return dev.map(offsets).fillna(0.0).to_numpy(dtype=np.float64)


def corrected(dataset: Dataset, offsets: dict | None) -> Dataset:
    """``dataset`` with each Wi-Fi reading's RSS minus its device's offset (the same object when no offset
    is non-zero); BLE readings are left as heard (the offsets are the Wi-Fi radios')."""
    offs = nonzero(offsets)
    if not offs:
        return dataset
    o = reading_offsets(dataset.wifi, dataset.walks, offs)
    if not o.any():
        return dataset
    return dataclasses.replace(dataset, wifi=dataset.wifi.assign(rssi_dbm=dataset.wifi["rssi_dbm"] - o))
