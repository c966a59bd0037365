"""Floor changes from a phone barometer (rmbuild/pdr/baro.py): found on a storey, never on noise or drift."""

from __future__ import annotations

import gzip

import numpy as np
import pandas as pd
import pytest

from rmbuild.ingest.floors import split_floors
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


def _two_floor_input(seed: int = 0) -> tuple[RawInput, dict[str, float]]:
    """Four 120 s walks (a step each 0.5 s, a scan each 2 s) in a building of two floors, each hearing its
    own 6 APs at -45..-70 dBm and the other floor's 15 dB weaker: walk0 climbs from A to B at 50-62 s, walk3
    goes down from B to A at 70-78 s (3.5 m storeys), walk1 stays on B, walk2 on A. No floor columns; the
    second value is each changing walk's true midpoint of the change."""
    rng = np.random.default_rng(seed)
    mids = {"walk0": 56.0, "walk3": 74.0}
    climbs = {"walk0": (50.0, 12.0, 3.5), "walk3": (70.0, 8.0, -3.5)}
    floor_at = {"walk0": lambda t: t >= 56.0, "walk1": lambda t: t >= 0.0, "walk2": lambda t: t < 0.0,
                "walk3": lambda t: t < 74.0}
    poses, wifi, pressure = [], [], {}
    for w in ("walk0", "walk1", "walk2", "walk3"):
        t = np.arange(0.0, 120.0, 0.5)
        poses.append(pd.DataFrame({"walk_id": w, "t_s": t, "x_m": 0.7 * np.arange(len(t)), "y_m": 0.0,
                                   "heading_rad": 0.0}))
        for ts in np.arange(1.0, 120.0, 2.0):
            on_b = bool(floor_at[w](ts))
            for k in range(12):
                own = (k >= 6) == on_b
                wifi.append((w, ts, f"ap{k:02d}", -45.0 - 4.0 * (k % 6) - (0.0 if own else 15.0)
                             + rng.normal(0.0, 4.0)))
        tp, p = _pressure(seconds=120.0, seed=seed + len(pressure))
        if w in climbs:
            p = p - _climb(tp, *climbs[w])
        pressure[w] = (tp, p + (3.5 / M_PER_HPA if w in ("walk3",) else 0.0) + rng.normal(0.0, 1.0))
    raw = RawInput(walks=pd.DataFrame({"walk_id": ["walk0", "walk1", "walk2", "walk3"], "device_id": "d",
                                       "user_id": "u", "role": ""}),
                   poses=pd.concat(poses, ignore_index=True),
                   wifi=pd.DataFrame(wifi, columns=["walk_id", "t_s", "bssid", "rssi_dbm"]),
                   fixes=pd.DataFrame({c: [] for c in ("walk_id", "t_s", "x_m", "y_m", "label")}),
                   pressure=pressure)
    return raw, mids


def test_a_walk_is_cut_at_its_floor_changes_and_the_parts_named_by_wifi() -> None:
    """No floor columns: the barometer cuts walk0 and walk3 within a step of the change's midpoint, and the
    Wi-Fi puts walk1 on walk0's upper part's floor, walk2 on its lower, walk3's parts on both."""
    raw, mids = _two_floor_input()
    floors = split_floors(raw)
    assert floors is not None and set(floors) == {"+0", "+1"}
    walks = {f: sorted(set(r.poses["walk_id"])) for f, r in floors.items()}
    assert walks == {"+0": ["walk0@+0", "walk2", "walk3@+0"], "+1": ["walk0@+1", "walk1", "walk3@+1"]}
    for tr in raw.transitions:
        assert abs(tr["t_s"] - mids[tr["walk"]]) <= 1.0, tr  # a step is 0.5 s
    assert {(tr["walk"], tr["from"]["floor"], tr["to"]["floor"]) for tr in raw.transitions} == {
        ("walk0", "+0", "+1"), ("walk3", "+1", "+0")}
    wifi_b = floors["+1"].wifi
    assert (wifi_b[wifi_b["walk_id"] == "walk0@+1"]["t_s"] >= 56.0).all()
    assert any("walk0" in n and "+0 → +1" in n for n in raw.notes)


def test_a_floor_column_wins_over_the_barometer() -> None:
    raw, _ = _two_floor_input()
    raw.walks = raw.walks.assign(floor=["F1", "F2", "F1", "F2"])
    floors = split_floors(raw)
    assert floors is not None and set(floors) == {"F1", "F2"} and raw.transitions == []


def test_a_raw_imu_walk_is_cut_by_time() -> None:
    """A walk without poses (raw phone IMU) is cut at the change: each segment keeps its own samples."""
    from rmbuild.io.formats.base import RawImu
    from rmbuild.pdr import ImuSignals

    raw, mids = _two_floor_input()
    g = raw.poses["walk_id"] == "walk0"
    raw.poses = raw.poses[~g].reset_index(drop=True)
    t = np.arange(0.0, 120.0, 0.02)
    sig = ImuSignals(t_acc_s=t, acc_mps2=np.zeros((len(t), 3)), t_yaw_s=t[::5], yaw_abs_rad=np.zeros(len(t[::5])),
                     yaw_accuracy=np.zeros(len(t[::5]), dtype=np.int64), t_gyro_s=t, gyro_radps=np.zeros((len(t), 3)))
    raw.imu = {"walk0": RawImu(sig, "imu.csv", {"acc": np.arange(len(t)) + 2})}
    floors = split_floors(raw)
    assert floors is not None
    lo, hi = floors["+0"].imu["walk0@+0"], floors["+1"].imu["walk0@+1"]
    cut = lo.signals.t_acc_s[-1]
    assert abs(cut - mids["walk0"]) < 1.0 and hi.signals.t_acc_s[0] > cut
    assert len(lo.signals.t_acc_s) + len(hi.signals.t_acc_s) == len(t)
    assert hi.where("acc", 0) == f"imu.csv:{len(lo.signals.t_acc_s) + 2}"


def test_a_mixed_ipin_call_ingests_into_per_floor_walks(shared_datasets, tmp_path) -> None:
    """Three IPIN 2023 logfiles, one given a storey's climb at 40 % of its pressure: `ingest` without options
    writes a building of two floors, that walk cut at the climb (the transition in the report)."""
    from rmbuild.config import IngestConfig
    from rmbuild.io.formats.ipin import parse_logfile
    from rmbuild.stages import ingest

    files = sorted((shared_datasets / "ipin2023" / "logs").glob("*.txt.gz"))[:3]
    src = tmp_path / "in"
    src.mkdir()
    t0, ts = 0.0, [0.0]
    for k, f in enumerate(files):
        lines = gzip.open(f, "rt", errors="replace").read().splitlines(keepends=True)
        if k == 0:
            ts = [float(ln.split(";")[1]) for ln in lines if ln.startswith("PRES;")]
            t0 = ts[0] + 0.4 * (ts[-1] - ts[0])
            for i, ln in enumerate(lines):
                if ln.startswith("PRES;"):
                    r = ln.split(";")
                    r[3] = f"{float(r[3]) - _climb(np.array([float(r[1])]), t0, 15.0, 3.5)[0]:.4f}"
                    lines[i] = ";".join(r)
        (src / f.name.removesuffix(".gz")).write_text("".join(lines))
    rep = ingest.run([src], tmp_path / "ws", IngestConfig())
    assert set(rep["floors"]) == {"+0", "+1"}
    (tr,) = rep["transitions"]
    pres = parse_logfile(src / files[0].name.removesuffix(".gz")).num["PRES"][:, 0]  # the reader's clock
    mid = pres[0] + (t0 + 7.5 - ts[0])
    assert tr["walk"] == files[0].name.removesuffix(".txt.gz") and 0.0 <= tr["t_s"] - mid < 2.0
    assert (tr["from"]["floor"], tr["to"]["floor"]) == ("+0", "+1")
    assert sum(r["walks"] for r in rep["floors"].values()) == 4
