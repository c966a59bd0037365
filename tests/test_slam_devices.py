"""Per-device RSS offsets (rmbuild/slam/devices.py) and their use by the Wi-Fi evidence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rmbuild.slam.devices import calibrated, device_offsets
from rmbuild.types import Fingerprints


def _fields(rng, n: int, n_ap: int, shift: float, covered: slice) -> np.ndarray:
    """n fingerprints over n_ap APs: per-AP levels + noise + ``shift``; only APs in ``covered`` heard."""
    level = np.linspace(-85, -45, n_ap)
    rss = level[None] + rng.normal(0, 6, (n, n_ap)) + shift
    out = np.full_like(rss, np.nan)
    out[:, covered] = rss[:, covered]
    return out


def test_offset_recovered_from_partly_shared_aps():
    rng = np.random.default_rng(1)
    a = _fields(rng, 300, 40, 0.0, slice(0, 30))  # the reference device (most rows)
    b = _fields(rng, 120, 40, 6.0, slice(10, 40))  # reads 6 dB higher, shares APs 10-29
    dev = np.r_[np.full(300, "a"), np.full(120, "b")]
    off = device_offsets(np.r_[a, b], dev)
    assert off["a"] == 0.0 and abs(off["b"] - 6.0) < 0.7
    fp = Fingerprints(np.arange(420), np.array([f"ap{i}" for i in range(40)]), np.r_[a, b].astype(np.float32),
                      np.ones((420, 40), np.int32))
    fixed, off2 = calibrated(fp, dev)
    assert off2.keys() == off.keys() and abs(off2["b"] - off["b"]) < 1e-4
    assert np.allclose(fixed.rss_dbm[300:], fp.rss_dbm[300:] - off["b"], equal_nan=True)
    assert np.array_equal(fixed.rss_dbm[:300], fp.rss_dbm[:300], equal_nan=True)


def test_no_offset_without_enough_shared_aps_or_a_second_device():
    rng = np.random.default_rng(2)
    a = _fields(rng, 300, 40, 0.0, slice(0, 22))
    b = _fields(rng, 120, 40, 6.0, slice(18, 40))  # 4 shared APs < MIN_SHARED_APS
    assert device_offsets(np.r_[a, b], np.r_[np.full(300, "a"), np.full(120, "b")]) == {"a": 0.0, "b": 0.0}
    fp = Fingerprints(np.arange(300), np.array([f"ap{i}" for i in range(40)]), a.astype(np.float32),
                      np.ones((300, 40), np.int32))
    same, off = calibrated(fp, np.full(300, "a"))
    assert same is fp and off == {"a": 0.0}


def test_no_offset_when_aps_differ_both_ways():
    """Two phones alike that walked different parts of a venue: per-AP medians differ by ±3 dB either way."""
    rng = np.random.default_rng(3)
    a = _fields(rng, 300, 40, 0.0, slice(0, 40))
    b = _fields(rng, 300, 40, 0.0, slice(0, 40)) + rng.choice([-3.0, 3.0], 40)[None]
    b[:, :25] += 2.0  # a 2 dB median, but 40 % of the APs the other way
    off = device_offsets(np.r_[a, b], np.r_[np.full(300, "a"), np.full(300, "b")])
    assert off == {"a": 0.0, "b": 0.0}


@pytest.fixture(scope="module")
def two_phones():
    """A venue whose last three walks were recorded by a second phone reading 10 dB higher."""
    pytest.importorskip("gtsam")
    from slam_venue import make_venue

    ds, fp = make_venue(n_walks=6, steps_per_walk=260, seed=4)
    walks = ds.walks.assign(device_id=["d0"] * 3 + ["d1"] * 3)
    second = np.isin(ds.poses["walk_id"].to_numpy()[fp.node], ["w003", "w004", "w005"])
    rss = fp.rss_dbm.copy()
    rss[second] += 10.0
    return replace(ds, walks=walks), Fingerprints(fp.node, fp.bssids, rss, fp.count)


def _cross_device_pairs(res) -> int:
    p = res.pairs
    return int(((p["walk_k"] < "w003") != (p["walk_q"] < "w003")).sum())


def test_second_phone_is_linked_after_calibration(two_phones):
    from rmbuild.config.optimize import OptimizeConfig
    from rmbuild.slam import optimize

    ds, fp = two_phones
    on = optimize(ds, fp, OptimizeConfig())
    off_cfg = OptimizeConfig()
    off = optimize(ds, fp, replace(off_cfg, wifi=replace(off_cfg.wifi, calibrate_devices=False)))
    offsets = on.stats["vicinity"]["device_offsets_db"]
    assert offsets["d0"] == 0.0 and abs(offsets["d1"] - 10.0) < 1.5
    assert off.stats["vicinity"]["device_offsets_db"] == {}
    assert _cross_device_pairs(on) > 2 * max(_cross_device_pairs(off), 1)
    assert on.walks["linked"].sum() == 6
    assert on.stats["vicinity"]["rss_exponent"] in (1.0, 1.25, 1.5, 2.0, 2.5)
    assert max(on.stats["vicinity"]["rss_exponent_auc"].values()) > 0.8
