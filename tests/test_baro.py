"""Floor changes from a phone barometer (rmbuild/pdr/baro.py): found on a storey, never on noise or drift."""

from __future__ import annotations

import gzip

import numpy as np
import pandas as pd
import pytest
from conftest import make_input_tables

from rmbuild.ingest_floors import barometer_warnings
from rmbuild.io.formats.base import RawInput
from rmbuild.pdr.baro import M_PER_HPA, floor_changes


def _pressure(seconds: float = 300.0, seed: int = 0, drift_hpa_per_h: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A 10 Hz phone barometer standing on one floor: 0.02 hPa white noise and a weather drift."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 0.1)
    return t, 1000.0 + drift_hpa_per_h * t / 3600.0 + rng.normal(0.0, 0.02, len(t))


def _climb(t: np.ndarray, t0: float, dur: float, dh_m: float) -> np.ndarray:
    return np.clip((t - t0) / dur, 0.0, 1.0) * dh_m / M_PER_HPA


@pytest.mark.parametrize(("dh", "dur"), [(3.5, 15.0), (-3.5, 8.0), (4.5, 25.0), (7.0, 30.0)])
def test_a_storey_is_found(dh: float, dur: float) -> None:
    t, p = _pressure(seed=int(10 * dur))
    ch = floor_changes(t, p - _climb(t, 120.0, dur, dh))
    assert len(ch) == 1
    assert ch[0].dh_m == pytest.approx(dh, abs=0.5)
    assert 110.0 < ch[0].t_start_s < 124.0 and abs(ch[0].t_end_s - (120.0 + dur)) < 6.0


def test_noise_drift_and_small_steps_are_not_floor_changes() -> None:
    t, p = _pressure(seconds=1800.0, drift_hpa_per_h=2.0)  # a fast weather change: ~17 m/h of "height"
    assert floor_changes(t, p) == []
    assert floor_changes(t, p - _climb(t, 600.0, 5.0, 1.0)) == []  # a 1 m ramp, not a storey
    assert floor_changes(t[:5], p[:5]) == []


def test_ipin_2023_walks_stay_on_their_floor(shared_datasets) -> None:
    """The IPIN 2023 Track 3 walks are all on floor -2: no change in any; a storey added to each is found."""
    files = sorted((shared_datasets / "ipin2023" / "logs").glob("*.txt.gz"))
    assert len(files) == 28
    found = 0
    for f in files:
        rows = [ln.split(";") for ln in gzip.open(f, "rt", errors="replace") if ln.startswith("PRES;")]
        t = np.array([float(r[1]) for r in rows])
        p = np.array([float(r[3]) for r in rows])
        assert floor_changes(t, p) == [], f.name
        t0 = t[0] + 0.4 * (t[-1] - t[0])
        ch = floor_changes(t, p - _climb(t, t0, 15.0, 3.5))
        found += len(ch) == 1 and abs(ch[0].dh_m - 3.5) < 1.0
    assert found >= 27


def test_ingest_warns_of_a_floor_change_it_cannot_split() -> None:
    tab = make_input_tables(n_walks=2)
    t, p = _pressure(seconds=200.0)
    raw = RawInput(walks=tab["walks"], poses=tab["poses"], wifi=tab["wifi"], fixes=tab["fixes"],
                   pressure={"walk0": (t, p - _climb(t, 100.0, 15.0, 3.5)), "walk1": (t, p)})
    msgs = barometer_warnings(raw)
    assert len(msgs) == 1 and "walk0" in msgs[0] and "+3." in msgs[0]
    raw.walks = raw.walks.assign(floor=pd.Series(["F1", "F2"]))
    assert barometer_warnings(raw) == []  # the input says where the walks are
