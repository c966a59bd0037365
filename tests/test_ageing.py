"""A map that ages: point maps, AP change detection with evidence, the update rule, the UJI reader."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from rmbuild.errors import InputError
from rmbuild.radiomap.ageing import classify_aps, drop_aps, heard, point_map, refresh

BSS = np.array(["A", "B", "C", "D", "E", "F"], dtype=object)
#: AP positions (x, y, floor); E sits between the floors (heard alike on both); F replaces B (new BSSID)
AP = {"A": (0.0, 0.0, 3), "B": (20.0, 0.0, 3), "C": (0.0, 20.0, 3), "D": (20.0, 20.0, 3), "F": (20.0, 0.0, 3)}


def _month(month: int, rng: np.random.Generator, n_per: int = 4) -> tuple:
    """Samples on a 5 x 5 grid of points (5 m apart) of floor 3 and the same grid on floor 5; B is gone from
    month 3 and F replaces it, C appears in month 2, D moves 15 m in month 2; log-distance RSSI, 1 dB noise."""
    g = np.array([(x, y) for x in range(0, 25, 5) for y in range(0, 25, 5)], float)
    xy = np.repeat(np.vstack([g, g]), n_per, axis=0)
    fl = np.repeat(np.r_[np.full(len(g), 3), np.full(len(g), 5)], n_per)
    rss = np.full((len(xy), len(BSS)), np.nan, np.float32)
    for j, b in enumerate(BSS):
        if (b == "B" and month >= 3) or (b == "C" and month < 2) or (b == "F" and month < 3):
            continue
        if b == "E":
            ax, ay, af = 10.0, 10.0, 4
        else:
            ax, ay, af = AP[b]
            if b == "D" and month >= 2:
                ax -= 15.0
        d = np.sqrt((xy[:, 0] - ax) ** 2 + (xy[:, 1] - ay) ** 2 + (4.0 * (fl - af)) ** 2) + 1.0
        v = -40 - 25 * np.log10(d) + rng.normal(0, 1.0, len(xy))
        rss[:, j] = np.where(v > -90, v, np.nan)
    return rss, xy + rng.normal(0, 0.05, xy.shape), fl


def _maps(n_months: int = 6) -> dict:
    rng = np.random.default_rng(3)
    return {m: point_map(*_month(m, rng), BSS, m) for m in range(1, n_months + 1)}


def test_point_map_merges_samples_of_a_spot_per_floor() -> None:
    pm = _maps(1)[1]
    assert len(pm) == 50 and set(pm.floor) == {3, 5}
    assert (pm.n_samples == 4).all()
    np.testing.assert_allclose(np.sort(pm.xy[pm.floor == 3, 0]), np.repeat(np.arange(0, 25, 5), 5), atol=0.1)


def test_classify_aps_finds_gone_appeared_moved_with_evidence() -> None:
    aps = classify_aps(_maps(), gone_after=3, move_m=5.0, min_months=3).set_index("bssid")
    assert aps.loc["A", "status"] == "stable" and abs(aps.loc["A", "rss_shift_db"]) < 1.0
    assert aps.loc["B", "status"] == "gone" and aps.loc["B", "months_heard"] == "1-2"
    assert aps.loc["F", "status"] == "appeared" and aps.loc["B", "replaced_by"] == "F"
    assert aps.loc["C", "replaced_by"] == "" and np.hypot(aps.loc["B", "first_x_m"] - 20, aps.loc["B", "first_y_m"]) < 4
    assert aps.loc["C", "status"] == "appeared" and aps.loc["C", "first_month"] == 2
    assert aps.loc["D", "status"] == "moved" and 10.0 < aps.loc["D", "location_shift_m"] < 20.0
    assert aps.loc["E", "status"] == "stable"  # between the floors: its strongest floor may flip, its RSSI not


def test_refresh_replaces_rps_seen_again_and_adds_new_ones() -> None:
    maps = _maps(3)
    old, new = maps[1], maps[3]
    part = new.rows(np.arange(10))
    extra = point_map(np.full((1, len(BSS)), -50, np.float32), np.array([[100.0, 100.0]]), np.array([3]), BSS, 3)
    upd = refresh(old, part)
    hit = [int(np.argmin(np.hypot(*(old.xy - xy).T) + 1e3 * (old.floor != f))) for xy, f in zip(part.xy, part.floor)]
    rest = np.setdiff1d(np.arange(len(old)), hit)
    assert len(upd) == len(old) and (upd.month[hit] == 3).all() and (upd.month[rest] == 1).all()
    np.testing.assert_array_equal(upd.rss_dbm[hit], part.rss_dbm)
    np.testing.assert_array_equal(upd.rss_dbm[rest], old.rss_dbm[rest])
    assert len(refresh(old, extra)) == len(old) + 1
    assert not heard(drop_aps(upd, BSS == "B"))[1] and heard(upd)[1]


def test_the_update_rule_brings_the_error_back() -> None:
    """A map from month 1 localizes month 6 worse than the map refreshed with half of each month's spots."""
    from rmbuild.config.evaluate import KnnConfig
    from rmbuild.localize.knn import KnnLocalizer

    maps = _maps()
    rng = np.random.default_rng(9)
    rss, xy, fl = _month(6, rng, n_per=1)
    state = maps[1]
    for m in range(2, 6):
        state = refresh(state, maps[m].rows(rng.choice(len(maps[m]), len(maps[m]) // 2, replace=False)))

    def err(pm) -> float:
        e = []
        for f in (3, 5):
            q = fl == f
            p = KnnLocalizer(KnnConfig(k=3)).fit(pm.reference_set(f)).predict_rss(rss[q])
            e.append(np.hypot(*(p - xy[q]).T))
        return float(np.mean(np.concatenate(e)))

    assert err(state) < 0.8 * err(maps[1]), (err(state), err(maps[1]))


def test_uji_reader_reads_a_month(shared_datasets: Path) -> None:
    from rmbuild.io.uji_longterm import read_set, set_names

    db = shared_datasets / "uji-longterm" / "db"
    if not db.is_dir():
        pytest.skip("uji-longterm not present")
    assert set_names(db, 2) == ["trn01", "tst01", "tst02", "tst03", "tst04", "tst05"]
    s = read_set(db, 2, "trn01")
    assert s.rss_dbm.shape == (576, 620) and set(s.floor) == {3, 5}
    assert np.nanmax(s.rss_dbm) < 0 and np.isnan(s.rss_dbm).mean() > 0.5  # 100 = not detected -> NaN
    assert s.bssids[0] == "WAP001" and 1.46e9 < s.t_s.min() < 1.47e9  # July 2016


def test_uji_reader_bad_value_names_file_and_line(tmp_path: Path, shared_datasets: Path) -> None:
    from rmbuild.io.uji_longterm import read_set

    src = shared_datasets / "uji-longterm" / "db" / "02"
    if not src.is_dir():
        pytest.skip("uji-longterm not present")
    d = tmp_path / "db" / "02"
    d.mkdir(parents=True)
    for part in ("crd", "tms", "ids"):
        shutil.copy(src / f"trn01{part}.csv.gz", d)
    lines = gzip.decompress((src / "trn01rss.csv.gz").read_bytes()).decode().splitlines()
    cells = lines[6].split(",")
    cells[cells.index("100")] = "17"  # a positive RSSI that is not the "not detected" 100
    lines[6] = ",".join(cells)
    (d / "trn01rss.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"trn01rss\.csv:7"):
        read_set(tmp_path / "db", 2, "trn01")
    (d / "trn01rss.csv").write_text("\n".join(lines[:10]) + "\n")
    with pytest.raises(InputError, match="the rss file has 10"):
        read_set(tmp_path / "db", 2, "trn01")


def test_diff_maps_reports_per_ap_changes_between_two_radio_maps() -> None:
    import pandas as pd

    from rmbuild.config import MapConfig
    from rmbuild.radiomap import build_radio_map
    from rmbuild.stages.diff_map import diff_maps

    rng = np.random.default_rng(4)

    def radio_map(month: int, frame: str = "building"):
        rss, xy, fl = _month(month, rng)
        keep = fl == 3
        rss, xy = rss[keep], xy[keep]
        r, c = np.nonzero(~np.isnan(rss))
        wifi = pd.DataFrame({"node": r, "t_s": 0.0, "bssid": BSS[c], "rssi_dbm": rss[r, c].astype(float)})
        return build_radio_map(wifi, xy, np.array(["w"] * len(xy)), MapConfig(cell_size_m=2.0), np.zeros(2),
                               frame=frame)

    a, b = radio_map(1), radio_map(6)
    table, summary = diff_maps(a, b)
    t = table.set_index("bssid")
    assert t.loc["B", "status"] == "gone" and t.loc["B", "replaced_by"] == "F"
    assert t.loc["C", "status"] == "appeared" and t.loc["F", "status"] == "appeared"
    assert t.loc["D", "status"] == "moved" and 10 < t.loc["D", "location_shift_m"] < 20
    assert t.loc["A", "status"] == "both" and abs(t.loc["A", "rss_shift_db"]) < 1.5
    assert summary["positions_compared"] and summary["counts"]["gone"] == 1
    _, other = diff_maps(a, radio_map(6, frame="walk:x"))
    assert not other["positions_compared"] and "different frames" in other["note"]
