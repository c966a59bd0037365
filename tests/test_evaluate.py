"""`evaluate`: split by walk, the three maps, the single SE(2) gauge, statistics, the no-truth path."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from rmbuild.config.evaluate import EvaluateConfig, KnnConfig
from rmbuild.config.radiomap import MapConfig
from rmbuild.errors import InputError
from rmbuild.evaluate.localization import STAT_KEYS, error_stats, evaluate, split_walks
from rmbuild.types import FIX_COLUMNS, Dataset, Fingerprints


def make_dataset(n_walks=6, seed=0, roles=None) -> Dataset:
    """Walks back and forth along two crossing 40 m corridors through a path-loss field of 10 APs.

    Raw poses are the true ones in each walk's own frame (start at the origin, heading 0) plus a slow
    heading drift; one scan every 2 steps (node attached), fixes every 20 steps.
    """
    rng = np.random.default_rng(seed)
    aps = rng.uniform([0, 0], [40, 40], (10, 2))
    bss = np.array([f"02:00:00:00:00:{j:02x}" for j in range(len(aps))], dtype=object)
    poses, truth, wifi, fixes, walks = [], [], [], [], []
    node0 = 0
    for w in range(n_walks):
        wid = f"w{w}"
        n = 80
        horizontal = w % 2 == 0
        s = np.abs(((np.arange(n) * 0.7 + rng.uniform(0, 40)) % 80) - 40)  # bounce along the corridor
        off = 20 + rng.normal(0, 0.3, n)
        xy = np.c_[s, off] if horizontal else np.c_[off, s]
        t = 1000.0 * w + 0.5 * np.arange(n)
        hd = np.r_[np.arctan2(*np.diff(xy, axis=0).T[::-1]), 0.0]
        hd[-1] = hd[-2]
        # own frame: rotate so the first heading is 0, start at the origin, plus drift
        th0 = hd[0]
        c, si = np.cos(-th0), np.sin(-th0)
        own = (xy - xy[0]) @ np.array([[c, -si], [si, c]]).T
        own = own * 1.02 + np.cumsum(rng.normal(0, 0.02, (n, 2)), axis=0)
        poses.append(pd.DataFrame({"walk_id": wid, "step": np.arange(n), "t_s": t, "x_m": own[:, 0],
                                   "y_m": own[:, 1], "heading_rad": hd - th0, "yaw_abs_rad": np.nan,
                                   "yaw_abs_sigma_rad": np.nan, "step_freq_hz": 1.8}))
        truth.append(pd.DataFrame({"walk_id": wid, "step": np.arange(n), "t_s": t, "x_m": xy[:, 0],
                                   "y_m": xy[:, 1], "heading_rad": hd}))
        for k in range(0, n, 2):
            d = np.hypot(*(aps - xy[k]).T)
            rss = -35 - 25 * np.log10(np.maximum(d, 1)) + rng.normal(0, 3, len(aps))
            seen = rss > -88
            for j in np.flatnonzero(seen):
                wifi.append((wid, t[k] + 0.1, bss[j], float(np.round(rss[j])), 2437.0, "x", node0 + k))
        for k in range(0, n, 20):
            fixes.append((wid, t[k], xy[k, 0], xy[k, 1], f"L{k}"))
        role = "" if roles is None else roles[w]
        walks.append((wid, "d0", "u0", role, "toy"))
        node0 += n
    return Dataset(
        walks=pd.DataFrame(walks, columns=["walk_id", "device_id", "user_id", "role", "source"]),
        poses=pd.concat(poses, ignore_index=True),
        wifi=pd.DataFrame(wifi, columns=["walk_id", "t_s", "bssid", "rssi_dbm", "freq_mhz", "ssid", "node"]),
        fixes=pd.DataFrame(fixes, columns=list(FIX_COLUMNS)),
        truth_poses=pd.concat(truth, ignore_index=True),
    )


def _fp(ds):
    return Fingerprints.from_readings(ds.wifi)


def _rot(th):
    return np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])


CFG = EvaluateConfig(knn=KnnConfig(k=3))


def test_error_stats_by_hand():
    s = error_stats(np.array([1.0, 2.0, 3.0, 4.0, 12.0, np.nan]))
    assert tuple(s) == STAT_KEYS
    assert s["n"] == 5 and s["mean"] == pytest.approx(4.4) and s["median"] == 3.0 and s["max"] == 12.0
    assert s["rmse"] == pytest.approx(np.sqrt((1 + 4 + 9 + 16 + 144) / 5))
    assert s["p_lt_5m"] == pytest.approx(0.8) and s["p_lt_10m"] == pytest.approx(0.8)
    assert s["p75"] == 4.0 and s["p90"] == pytest.approx(4 + 0.6 * 8)
    assert error_stats(np.array([]))["n"] == 0


@pytest.mark.parametrize("n_walks", [2, 3, 7, 11])
def test_split_is_by_walk(n_walks):
    rng = np.random.default_rng(n_walks)
    ds = make_dataset(n_walks=2)
    ids = [f"w{i}" for i in range(n_walks)]
    ds.walks = pd.DataFrame({"walk_id": ids, "role": [""] * n_walks})
    for every, off in [(2, 0), (3, 2), (5, 4)]:
        cfg = EvaluateConfig(split_every=every, split_offset=off)
        maps, test, _ = split_walks(ds, cfg)
        assert set(maps).isdisjoint(test) and set(maps) | set(test) == set(ids)
        assert maps and test
        assert split_walks(ds, cfg) == split_walks(ds, cfg)  # deterministic
    roles = rng.choice(["", "map", "test"], n_walks)
    roles[0] = "map"
    roles[-1] = "test"
    ds.walks["role"] = roles
    maps, test, rule = split_walks(ds, EvaluateConfig())
    assert rule == "role" and set(test) == {w for w, r in zip(ids, roles, strict=True) if r == "test"}
    maps, test, rule = split_walks(ds, EvaluateConfig(), [ids[0]])
    assert test == [ids[0]] and rule == "given"
    with pytest.raises(InputError):
        split_walks(ds, EvaluateConfig(), ["nope"])
    with pytest.raises(InputError):
        split_walks(ds, EvaluateConfig(), ids)


def test_queries_never_come_from_map_walks():
    ds = make_dataset()
    res = evaluate(ds, _fp(ds), ds.truth_poses[["x_m", "y_m"]].to_numpy(), CFG, None, "anchors")
    assert set(res.query.walk_id) == set(res.test_walks)
    for rm in res.maps.values():
        walks = set(rm.node_walk)
        assert walks == set(res.map_walks) and walks.isdisjoint(res.test_walks)


def test_se2_gauge_is_one_transform():
    ds = make_dataset()
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    fp = _fp(ds)
    built = truth @ _rot(0.7).T + [30.0, -12.0]  # the whole map in another frame: one SE(2) undoes it
    res = evaluate(ds, fp, built, CFG, None, "se2")
    assert res.alignment["built_se2"]["residual_rms_m"] < 1e-6
    for loc in CFG.localizers:
        np.testing.assert_allclose(res.errors["built"][loc], res.errors["surveyed"][loc], atol=1e-6)
    # with the anchors gauge the same positions are taken as they are: far off
    res_a = evaluate(ds, fp, built, CFG, None, "anchors")
    assert res_a.stats["built"]["knn"]["median"] > 10
    assert "built_se2" not in res_a.alignment
    # one walk moved on its own cannot be undone by the single transform (never per-walk)
    sl = ds.walk_slices()["w1"]
    built2 = truth.copy()
    built2[sl] += [15.0, 0.0]
    res2 = evaluate(ds, fp, built2, CFG, None, "se2")
    assert res2.alignment["built_se2"]["residual_rms_m"] > 3
    assert res2.stats["built"]["knn"]["median"] > res.stats["surveyed"]["knn"]["median"]


def test_full_result_json_table_and_cdf():
    from matplotlib.figure import Figure

    from rmbuild.viz.figures import cdf_figure

    ds = make_dataset(n_walks=6)
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    rng = np.random.default_rng(1)
    built = truth + rng.normal(0, 0.7, truth.shape)
    res = evaluate(ds, _fp(ds), built, CFG, ["w2", "w5"], "se2", map_cfg=MapConfig(cell_size_m=2.0))
    j = res.to_json()
    json.dumps(j, allow_nan=False)
    assert j["gauge"] == "se2" and j["test_walks"] == ["w2", "w5"]
    assert set(j["maps"]) == {"built", "surveyed", "raw"}
    for m in j["maps"].values():
        assert set(m) == {"knn", "wknn"}
        for s in m.values():
            assert tuple(s) == STAT_KEYS and s["n"] == len(res.query)
    sv, bt, raw = (j["maps"][m]["knn"]["median"] for m in ("surveyed", "built", "raw"))
    assert sv < 4.0 and bt < 2.0 * sv + 1 and raw > sv
    # the three maps share one grid
    origins = {tuple(rm.origin_xy) for rm in res.maps.values()}
    assert len(origins) == 1
    assert "knn" in j["consistency"]["built"]
    assert "surveyed" in res.table() and "raw" in res.table()
    fig = cdf_figure(res.errors_by_label())
    assert isinstance(fig, Figure)
    lines = fig.axes[0].get_lines()  # ecdf curves (+ the 5 m / 10 m marks): one per map and localizer
    assert sum(ln.get_label().startswith(("built", "surveyed", "raw")) for ln in lines) == 6
    assert list(res.errors_by_label())[:2] == ["built / knn", "built / wknn"]


def test_no_truth_path():
    ds = make_dataset()
    ds.truth_poses = None
    ds.fixes = ds.fixes.iloc[:0]
    built = ds.poses[["x_m", "y_m"]].to_numpy()
    res = evaluate(ds, _fp(ds), built, CFG, None, "se2")
    j = res.to_json()
    json.dumps(j, allow_nan=False)
    assert j["maps"] == {} and j["reference"] is None
    assert "errors" in j["unavailable"] and "maps.surveyed" in j["unavailable"] and "gauge" in j["unavailable"]
    assert set(res.maps) == {"built", "raw"}
    assert j["consistency"]["built"]["knn"]["n"] == len(res.query) > 0
    assert "not computed" in res.table()


def test_fixes_only_reference_is_interpolated_within_span():
    ds = make_dataset()
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    ds.truth_poses = None
    res = evaluate(ds, _fp(ds), truth, CFG, None, "se2")
    assert res.reference_source == "fixes"
    j = res.to_json()
    # scans after a walk's last fix (step 60) are not scored
    assert 0 < j["n_scored"] < j["n_queries"]
    assert j["maps"]["surveyed"]["knn"]["n"] == j["n_scored"]
    assert res.maps["surveyed"].nodes.node.size < res.maps["built"].nodes.node.size


def test_bad_input():
    ds = make_dataset()
    fp = _fp(ds)
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    with pytest.raises(InputError, match="shape"):
        evaluate(ds, fp, truth[:-1], CFG)
    with pytest.raises(InputError, match="gauge"):
        evaluate(ds, fp, truth, CFG, gauge="nope")
    with pytest.raises(InputError, match="unknown localizer"):
        evaluate(ds, fp, truth, EvaluateConfig(localizers=("knn", "slacx")))
    with pytest.raises(InputError, match="cell_size_m"):
        evaluate(ds, fp, truth, CFG, map_cfg=MapConfig(cell_size_m=-1.0))
    ds2 = make_dataset()
    ds2.wifi = ds2.wifi.iloc[:0]
    with pytest.raises(InputError, match="no Wi-Fi"):
        evaluate(ds2, fp, truth, CFG)


def test_on_simulated_tiny_venue():
    sim = pytest.importorskip("rmbuild.synthetic")
    from rmbuild.config.ingest import IngestConfig
    from rmbuild.ingest.core import build_dataset
    from rmbuild.io.formats.base import RawInput

    sd = sim.simulate(sim.preset_config("tiny", 3))
    raw = RawInput(walks=sd.walks, poses=sd.poses, wifi=sd.wifi, fixes=sd.fixes, truth_poses=sd.truth_poses)
    ds, fp, _ = build_dataset(raw, IngestConfig(), "sim")
    truth = ds.truth_poses[["x_m", "y_m"]].to_numpy()
    res = evaluate(ds, fp, truth, EvaluateConfig(), None, "se2")
    j = res.to_json()
    assert j["test_walks"] == [w for w, r in zip(ds.walks.walk_id, ds.walks.role, strict=True) if r == "test"]
    s, b = j["maps"]["surveyed"]["knn"], j["maps"]["built"]["knn"]
    assert s["median"] == pytest.approx(b["median"], abs=1e-6)
    assert s["median"] < j["maps"]["raw"]["knn"]["median"]


def test_a_map_with_no_reference_positions_cannot_be_aligned_and_says_why():
    # fixes only on the test walk: the map walks carry nothing a rigid fit could use
    ds = make_dataset()
    ds.truth_poses = None
    ds.fixes = ds.fixes[ds.fixes["walk_id"] == "w2"]
    built = ds.poses[["x_m", "y_m"]].to_numpy()
    with pytest.raises(InputError, match="cannot align the map to score it: the map's walks have 0 node"):
        evaluate(ds, _fp(ds), built, CFG, ["w2"], "se2")
