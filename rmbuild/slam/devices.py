"""Per-device RSS offsets, estimated from the data alone.

Two phones read the same AP at the same place several dB apart (antenna, chipset, firmware): on IPIN 2023
floor −2 one Samsung reads 5.3 dB above the other. The RSS distance then makes every pair of scans of
two such phones look far apart, and walks of one phone are hardly ever linked to walks of the other.
Each device's offset against the device with the most fingerprints is the median, over the APs both
heard often, of the difference of their median readings: a venue's devices cover the same space on the
whole, so what stays of the per-AP differences is the phones' gain difference. The offsets are removed
from the fingerprints the pair search, placement and the RF check compare; the report lists them
(``vicinity.device_offsets_db``) and the radio map, ``evaluate`` and ``localize`` take the same offsets off
the readings (:mod:`rmbuild.radiomap.devices`).
"""

from __future__ import annotations

import warnings

import numpy as np

from rmbuild.slam.problem import WalkSet
from rmbuild.types import Fingerprints

# fingerprints that must hear an AP, in each of the two devices, for it to enter the median
MIN_ROWS_PER_AP = 20
# APs the two devices must share for an offset to be estimated (else 0)
MIN_SHARED_APS = 5
# share of those APs that must differ in the offset's direction: a gain difference moves every AP alike,
# where two devices that walked different parts of a venue differ both ways (IPIN −2's two phones: 40 of
# 40 APs; single walks of one simulated phone: 53-72 %)
MIN_SIGN_AGREEMENT = 0.85


def _ap_medians(rss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-AP median RSS over the rows that heard it (NaN where none) and their number."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an AP no row heard: all-NaN column
        med = np.nanmedian(rss, axis=0)
    return med, (~np.isnan(rss)).sum(axis=0)


def device_offsets(rss_dbm: np.ndarray, row_device: np.ndarray) -> dict[str, float]:
    """{device: dB its readings lie above the reference device's} for fingerprints ``rss_dbm`` (n, n_ap;
    NaN = not heard) whose rows were recorded by ``row_device`` (n,). The reference device (most rows)
    gets 0, and so does a device sharing fewer than MIN_SHARED_APS well-heard APs with it or whose APs do
    not differ from the reference's mostly one way (MIN_SIGN_AGREEMENT)."""
    devs, counts = np.unique(row_device.astype(str), return_counts=True)
    out = {str(d): 0.0 for d in devs}
    if len(devs) < 2:
        return out
    ref = devs[int(np.argmax(counts))]
    med_ref, n_ref = _ap_medians(rss_dbm[row_device == ref])
    for d in devs[devs != ref]:
        med, n = _ap_medians(rss_dbm[row_device == d])
        ok = (n >= MIN_ROWS_PER_AP) & (n_ref >= MIN_ROWS_PER_AP)
        diff = med[ok] - med_ref[ok]
        if len(diff) < MIN_SHARED_APS:
            continue
        off = float(np.median(diff))
        if np.mean(np.sign(diff) == np.sign(off)) >= MIN_SIGN_AGREEMENT:
            out[str(d)] = off
    return out


def calibrated(fp: Fingerprints, row_device: np.ndarray) -> tuple[Fingerprints, dict[str, float]]:
    """``fp`` with each device's offset (:func:`device_offsets`) removed from its rows, and the offsets."""
    row_device = row_device.astype(str)
    off = device_offsets(fp.rss_dbm, row_device)
    if not any(off.values()):
        return fp, off
    shift = np.array([off[d] for d in row_device], np.float32)
    return Fingerprints(fp.node, fp.bssids, fp.rss_dbm - shift[:, None], fp.count), off


def rf_fingerprints(walks: WalkSet, calibrate: bool) -> tuple[Fingerprints, dict[str, float]]:
    """The fingerprints the Wi-Fi evidence compares: ``walks.fingerprints``, calibrated per device when
    ``calibrate`` (and the walks' devices are known), and the offsets removed."""
    fp = walks.fingerprints
    if not calibrate or walks.device is None:
        return fp, {}
    return calibrated(fp, walks.device[walks.walk_of[fp.node]])
