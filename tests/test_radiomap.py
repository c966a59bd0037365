"""Radio map rasterisation: statistics against hand-computed values, rules, tables, fill, figures."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from rmbuild.config.radiomap import FillConfig, MapConfig
from rmbuild.errors import InputError
from rmbuild.radiomap import build_radio_map, grid_origin


def _hand_data():
    """Three nodes in cell (0, 0), one node in cell (1, 0); two walks; APs a, b, c."""
    node_xy = np.array([[0.5, 0.5], [1.0, 1.5], [1.9, 0.1], [2.5, 0.5]])
    node_walk = np.array(["w0", "w0", "w1", "w1"])
    wifi = pd.DataFrame([
        # node, t_s, bssid, rssi
        (0, 0.0, "a", -50.0), (0, 0.0, "b", -70.0),
        (1, 1.0, "a", -54.0), (1, 1.0, "c", -80.0),
        (1, 1.5, "a", -58.0),                        # second scan of node 1
        (2, 5.0, "a", -51.0), (2, 5.0, "b", -72.0),
        (3, 6.0, "a", -60.0),
    ], columns=["node", "t_s", "bssid", "rssi_dbm"])
    return wifi, node_xy, node_walk


def test_stats_match_hand_computed():
    wifi, xy, walk = _hand_data()
    rm = build_radio_map(wifi, xy, walk, MapConfig(cell_size_m=2.0), origin_xy=np.zeros(2))
    assert list(rm.bssids) == ["a", "b", "c"]
    assert rm.n_cells == 2
    c0 = int(np.flatnonzero((rm.cells.ix == 0) & (rm.cells.iy == 0))[0])
    c1 = int(np.flatnonzero((rm.cells.ix == 1) & (rm.cells.iy == 0))[0])
    a = np.array([-50.0, -54.0, -58.0, -51.0])
    assert rm.count[c0].tolist() == [4, 2, 1]
    np.testing.assert_allclose(rm.mean_dbm[c0, 0], a.mean(), rtol=1e-6)
    np.testing.assert_allclose(rm.std_db[c0, 0], a.std(ddof=1), rtol=1e-6)  # unbiased, T-1
    np.testing.assert_allclose(rm.std_db[c0, 1], np.std([-70.0, -72.0], ddof=1), rtol=1e-6)
    assert np.isnan(rm.std_db[c0, 2])  # T = 1: undefined
    # 4 scans in cell 0: (0,0.0) (1,1.0) (1,1.5) (2,5.0); a seen in all, b in 2, c in 1
    assert rm.cells.loc[c0, "n_scans"] == 4
    np.testing.assert_allclose(rm.detect_ratio[c0], [1.0, 0.5, 0.25])
    assert rm.n_walks[c0].tolist() == [2, 2, 1]
    assert rm.cells.loc[c0, "n_walks"] == 2 and rm.cells.loc[c0, "n_nodes"] == 3
    assert rm.count[c1].tolist() == [1, 0, 0]
    assert np.isnan(rm.mean_dbm[c1, 1]) and rm.detect_ratio[c1, 1] == 0
    np.testing.assert_allclose(rm.cell_xy[c1], [3.0, 1.0])
    # node database: per-node means
    assert rm.nodes.node.tolist() == [0, 1, 2, 3]
    np.testing.assert_allclose(rm.nodes.rss_dbm[1, 0], -56.0)
    np.testing.assert_allclose(rm.node_xy, xy)


def test_min_count_and_min_scans():
    wifi, xy, walk = _hand_data()
    rm = build_radio_map(wifi, xy, walk, MapConfig(min_count=2), origin_xy=np.zeros(2))
    c0 = int(np.flatnonzero(rm.cells.ix == 0)[0])
    assert np.isnan(rm.mean_dbm[c0, 2]) and rm.count[c0, 2] == 0 and rm.detect_ratio[c0, 2] == 0
    assert rm.count[c0, 1] == 2
    c1 = int(np.flatnonzero(rm.cells.ix == 1)[0])
    assert np.isnan(rm.mean_dbm[c1]).all()  # its single reading of a is below min_count; the cell stays
    rm2 = build_radio_map(wifi, xy, walk, MapConfig(min_scans=2), origin_xy=np.zeros(2))
    assert rm2.n_cells == 1 and rm2.cells.ix.tolist() == [0]


def test_long_wide_sidecar():
    wifi, xy, walk = _hand_data()
    rm = build_radio_map(wifi, xy, walk, MapConfig(), origin_xy=np.zeros(2), frame="walk:w0")
    long = rm.long_table()
    assert len(long) == int((rm.count > 0).sum()) == 4
    assert set(long.columns) >= {"cell", "bssid", "count", "rssi_mean_dbm", "rssi_std_db", "detect_ratio",
                                 "n_walks", "interpolated"}
    wide = rm.wide_table()
    assert list(wide.columns) == ["WAP001", "WAP002", "WAP003", "LONGITUDE", "LATITUDE", "FLOOR",
                                  "BUILDINGID", "SPACEID", "RELATIVEPOSITION", "USERID", "PHONEID",
                                  "TIMESTAMP"]
    c1 = int(np.flatnonzero(rm.cells.ix == 1)[0])
    assert wide.loc[c1, "WAP001"] == -60 and wide.loc[c1, "WAP002"] == 100 and wide.loc[c1, "WAP003"] == 100
    assert wide.loc[c1, "LONGITUDE"] == 3.0 and wide.loc[c1, "LATITUDE"] == 1.0
    assert wide["WAP001"].dtype.kind == "i"
    xyw = rm.wide_table("xy")
    assert list(xyw.columns) == ["a", "b", "c", "x_m", "y_m"]
    side = rm.sidecar()
    json.dumps(side, allow_nan=False)
    assert side["grid"]["origin_xy_m"] == [0.0, 0.0] and side["grid"]["cell_size_m"] == 2.0
    assert side["frame"] == "walk:w0" and side["aps"] == ["a", "b", "c"]
    assert side["ap_columns"]["WAP002"] == "b"
    assert side["config"]["cell_size_m"] == 2.0


def test_uji_columns_have_three_digits_as_uji_indoorloc_and_go_on_past_999():
    wifi = pd.DataFrame({"node": 0, "bssid": [f"ap{j:04d}" for j in range(1001)], "rssi_dbm": -70.0})
    rm = build_radio_map(wifi, np.array([[1.0, 1.0]]), np.array(["w0"]), MapConfig(cell_size_m=2.0))
    names = rm.wap_names()
    assert names[:2] == ["WAP001", "WAP002"] and names[519] == "WAP520" and names[998] == "WAP999"
    assert names[999:] == ["WAP1000", "WAP1001"]
    cols = [c for c in rm.wide_table("uji").columns if c.startswith("WAP")]
    assert cols == names and rm.sidecar()["ap_columns"]["WAP1001"] == "ap1000"


def test_bad_input():
    wifi, xy, walk = _hand_data()
    with pytest.raises(InputError, match="cell_size_m"):
        build_radio_map(wifi, xy, walk, MapConfig(cell_size_m=0.0))
    with pytest.raises(InputError, match="no Wi-Fi"):
        build_radio_map(wifi.iloc[:0], xy, walk, MapConfig())
    xy_nan = np.full_like(xy, np.nan)
    with pytest.raises(InputError):
        build_radio_map(wifi, xy_nan, walk, MapConfig())


def test_unknown_positions_are_left_out_and_origin_snaps():
    wifi, xy, walk = _hand_data()
    xy = xy.copy()
    xy[3] = np.nan
    rm = build_radio_map(wifi, xy + 10.0, walk, MapConfig(cell_size_m=2.0))
    np.testing.assert_allclose(rm.origin_xy, [10.0, 10.0])
    assert rm.n_cells == 1 and len(rm.nodes) == 3
    np.testing.assert_allclose(grid_origin(np.array([[-0.1, 3.9]]), 2.0), [-2.0, 2.0])


def _field_data(n_side=12, seed=0):
    """A walked 'plus' shape through a path-loss field of 5 APs (1 m spaced nodes, 2 scans each)."""
    rng = np.random.default_rng(seed)
    line = np.arange(n_side, dtype=float)
    xy = np.vstack([np.c_[line, np.full(n_side, n_side / 2)], np.c_[np.full(n_side, n_side / 2), line]])
    aps = rng.uniform(0, n_side, (5, 2))
    rows = []
    for i, p in enumerate(xy):
        for s in range(2):
            d = np.hypot(*(aps - p).T)
            rss = -40 - 20 * np.log10(np.maximum(d, 1)) + rng.normal(0, 2, len(aps))
            for j in range(len(aps)):
                rows.append((i, float(i * 10 + s), f"ap{j}", float(rss[j])))
    wifi = pd.DataFrame(rows, columns=["node", "t_s", "bssid", "rssi_dbm"])
    return wifi, xy, np.repeat(["w0", "w1"], n_side)


@pytest.mark.parametrize("method", ["idw", "gp"])
def test_fill_flags_interpolated_cells(method):
    wifi, xy, walk = _field_data()
    cfg = MapConfig(cell_size_m=1.0, fill=FillConfig(method=method, max_distance_m=2.0))
    base = build_radio_map(wifi, xy, walk, dataclasses.replace(cfg, fill=FillConfig()))
    rm = build_radio_map(wifi, xy, walk, cfg)
    interp = rm.cells["interpolated"].to_numpy()
    assert interp.sum() > 0 and (~interp).sum() == base.n_cells
    np.testing.assert_allclose(rm.mean_dbm[~interp], base.mean_dbm, equal_nan=True)
    assert (rm.count[interp] == 0).all() and (rm.cells.n_scans[interp] == 0).all()
    det = ~np.isnan(rm.mean_dbm[interp])
    assert det.any() and np.isfinite(rm.std_db[interp][det]).all() and (rm.std_db[interp][det] > 0).all()
    # filled cells lie within max_distance_m of a visited cell
    vis = rm.cell_xy[~interp]
    d = np.hypot(*(rm.cell_xy[interp][:, None, :] - vis[None]).transpose(2, 0, 1)).min(axis=1)
    assert d.max() <= 2.0 + 1e-9
    # interpolated means stay within the range of the visited ones (no wild extrapolation)
    lo, hi = np.nanmin(base.mean_dbm) - 10, np.nanmax(base.mean_dbm) + 10
    assert np.nanmin(rm.mean_dbm) >= lo and np.nanmax(rm.mean_dbm) <= hi
    assert rm.long_table()["interpolated"].any()


def test_figures():
    from matplotlib.figure import Figure

    from rmbuild.viz.figures import coverage_figure, heatmaps_figure

    wifi, xy, walk = _field_data()
    rm = build_radio_map(wifi, xy, walk, MapConfig(cell_size_m=1.0, heatmap_top_n=4))
    walls = np.array([[0, 0, 12, 0], [0, 0, 0, 12]], dtype=float)
    assert isinstance(coverage_figure(rm.cells, rm.cell_size_m, walls), Figure)
    long = rm.long_table()
    long.loc[long.index[0], "rssi_mean_dbm"] = -13.0  # a strong peak: the colour scale reaches it, unclipped
    fig = heatmaps_figure(long, 4, walls={"walls": walls.tolist()}, cell_size_m=rm.cell_size_m)
    assert isinstance(fig, Figure)
    panels = [ax for ax in fig.axes if ax.images]
    assert len(panels) == 4 and all(ax.get_xlabel() in ("x (m)", "") for ax in panels)
    lo, hi = panels[0].images[0].get_clim()
    assert hi == -13.0 and lo == pytest.approx(long[long["bssid"].isin(
        long.groupby("bssid")["rssi_mean_dbm"].max().nlargest(4).index)]["rssi_mean_dbm"].min())
    assert rm.strongest_aps(2) == rm.strongest_aps(5)[:2]


def test_built_positions_leave_out_walks_neither_linked_nor_anchored():
    """export-map / evaluate keep walks placed by Wi-Fi links or by anchors; the rest only on request."""
    from types import SimpleNamespace

    from rmbuild.stages.mapping import built_positions

    poses = pd.DataFrame({"walk_id": ["a", "a", "b", "b", "c", "c"], "step": [0, 1] * 3,
                          "x_m": np.arange(6.0), "y_m": np.zeros(6)})
    from rmbuild.types import OptimizeState

    # optimize's typed state: a linked by Wi-Fi, b by its anchors, c neither
    state = OptimizeState(("a", "b", "c"), 6, ("a", "b"), "a", "anchors", "anchors", {"p": -3.0, "q": 0.0}, 1.0,
                          (5.0, 2.0, 12.0, 3.0), {"a": 1.0})
    ws = SimpleNamespace(require=lambda stage: None, read_table={"optimize.poses": poses}.__getitem__,
                         stale_inputs=lambda stage: [], read_optimize_state=lambda: state, path=str)
    ds = SimpleNamespace(n_nodes=6, poses=poses)
    xy, info = built_positions(ws, ds, MapConfig())
    assert info["left_out_walks"] == ["c"] and info["frame"] == "building" and info["device_offsets_db"] == {"p": -3.0}
    assert np.isfinite(xy[:4]).all() and np.isnan(xy[4:]).all()
    xy, info = built_positions(ws, ds, dataclasses.replace(MapConfig(), include_unlinked_walks=True))
    assert info["left_out_walks"] == [] and np.isfinite(xy).all()


def test_histogram_layer_counts_bins_and_directions():
    from rmbuild.config.radiomap import HistogramConfig
    from rmbuild.radiomap.histogram import HISTOGRAM_COLUMNS, direction_sector, motion_directions

    wifi, xy, walk = _hand_data()
    rm = build_radio_map(wifi, xy, walk, MapConfig(cell_size_m=2.0), origin_xy=np.zeros(2))
    h = rm.histograms
    assert h is not None and h.bin_db == 2.0 and h.n_directions == 4
    assert int(h.count.sum()) == len(wifi)  # every reading counted once
    # w0 moves from (0.5, 0.5) to (1.0, 1.5): 63 deg -> sector 1 (90 ± 45); w1 along +x -> sector 0
    np.testing.assert_allclose(np.degrees(motion_directions(xy, walk)), [63.43, 63.43, 33.69, 33.69], atol=0.01)
    c0 = int(np.flatnonzero((rm.cells.ix == 0) & (rm.cells.iy == 0))[0])
    a = rm.bssids.tolist().index("a")
    sel = (h.cell == c0) & (h.ap == a)
    got = sorted(zip(h.sector[sel].tolist(), (h.bin[sel] * 2).tolist(), h.count[sel].tolist(), strict=True))
    # a in cell 0: -50, -54, -58 (w0, sector 1) and -51 (w1, sector 0); bins of 2 dB floor(rssi / 2)
    assert got == [(0, -52, 1), (1, -58, 1), (1, -54, 1), (1, -50, 1)]
    assert direction_sector(np.radians([0, 44, 46, 179, -91, np.nan]), 4).tolist() == [0, 0, 1, 2, 3, -1]
    assert direction_sector(np.radians([10.0]), 1).tolist() == [0]
    t = h.long_table(rm.bssids, rm.cells)
    assert tuple(t.columns) == HISTOGRAM_COLUMNS and (t["rssi_hi_dbm"] - t["rssi_lo_dbm"] == 2.0).all()
    assert set(t["direction_deg"].dropna()) <= {0.0, 90.0, 180.0, 270.0}
    none = build_radio_map(wifi, xy, walk, MapConfig(histogram=HistogramConfig(n_directions=0, bin_db=5.0)))
    assert (none.histograms.sector == -1).all() and none.histograms.bin_db == 5.0
    # standing still: no direction
    assert np.isnan(motion_directions(np.zeros((3, 2)), np.array(["w"] * 3))).all()
    from rmbuild.config.base import from_dict
    from rmbuild.errors import ConfigError

    with pytest.raises(ConfigError):
        from_dict(MapConfig, {"histogram": {"n_directions": -1}})
